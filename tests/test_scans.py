"""Scanned bodies (issue 12 item 4): the up axis of a mold file, the bundled SMPL bodies, open
(not watertight) scans.

Known answers: the Y-up rotation maps the file's (x, y, z) to (x, -z, y) exactly; the bundled
man stands on z = 0 after it (feet at y = 0 in the file) and is 1.79 m tall.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clothsim.mold import MOLD_MESH, MoldError, clear_mold_cache, load_mold, load_mold_bytes

ROOT = Path(__file__).resolve().parents[1]
BODIES = ROOT / "static" / "bodies"
MAN = BODIES / "smpl_man.stl"
NEUTRAL = BODIES / "smpl_neutral.stl"


def test_up_y_turns_the_file_to_z_up():
    import trimesh

    raw = trimesh.load(MAN, force="mesh")
    z_up = load_mold({"path": str(MAN), "up": "y"})
    assert z_up.kind == MOLD_MESH
    # each vertex (x, y, z) of the file is at (x, -z, y); trimesh may merge or reorder vertices,
    # so compare the bounding boxes and the vertex sets
    lo, hi = raw.bounds
    np.testing.assert_allclose(z_up.vertices.min(axis=0), [lo[0], -hi[2], lo[1]], atol=1e-12)
    np.testing.assert_allclose(z_up.vertices.max(axis=0), [hi[0], -lo[2], hi[1]], atol=1e-12)
    assert abs(z_up.vertices[:, 2].min()) < 1e-9           # feet on z = 0
    assert 1.7 < z_up.vertices[:, 2].max() < 1.9            # 1.79 m tall
    same = load_mold({"path": str(MAN), "up": "z"})
    np.testing.assert_allclose(same.vertices.min(axis=0), lo, atol=1e-12)


def test_up_comes_before_scale_rotate_translate():
    data = MAN.read_bytes()
    a = load_mold_bytes(data, "man.stl", up="y", scale=2.0, rotate=[0, 0, 90], translate=[1, 2, 3])
    b = load_mold_bytes(data, "man.stl", up="y")
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    want = 2.0 * b.vertices @ R.T + [1, 2, 3]
    from scipy.spatial import cKDTree

    assert a.vertices.shape == want.shape
    assert cKDTree(want).query(a.vertices)[0].max() < 1e-12   # the same points (build order may differ)


def test_up_is_part_of_the_cache_key():
    clear_mold_cache()
    y = load_mold({"path": str(MAN), "up": "y"})
    z = load_mold({"path": str(MAN)})
    assert y is not z and not np.allclose(y.bounds, z.bounds)
    assert load_mold({"path": str(MAN), "up": "y"}) is y


def test_bad_up_is_refused_with_its_field(tmp_path):
    from conftest import STRIP, scene_dict

    from clothsim.config import SceneError, scene_from_dict

    d = scene_dict(STRIP)
    d["mold"] = {"path": str(MAN), "up": "x"}
    with pytest.raises(SceneError, match="mold.up"):
        scene_from_dict(d)
    with pytest.raises(MoldError, match="up"):
        load_mold_bytes(MAN.read_bytes(), "man.stl", up="w")


def test_bodies_carry_their_attribution():
    text = (BODIES / "README.md").read_text()
    for s in ("CC BY 4.0", "odedstein/meshes", "Max Planck Society", "SMPL-X", "Loper", "Pavlakos"):
        assert s in text
    assert "smpl_man" in (ROOT / "README.md").read_text()
