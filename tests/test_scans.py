"""Scanned bodies (issue 12 item 4): the up axis of a mold file, the bundled SMPL bodies, open
(not watertight) scans.

Known answers: the Y-up rotation maps the file's (x, y, z) to (x, -z, y) exactly; the bundled
man stands on z = 0 after it (feet at y = 0 in the file) and is 1.79 m tall.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clothsim.mold import MOLD_MESH, MOLD_SMOOTH, MoldError, clear_mold_cache, load_mold, load_mold_bytes

ROOT = Path(__file__).resolve().parents[1]
BODIES = ROOT / "static" / "bodies"
MAN = BODIES / "smpl_man.stl"
NEUTRAL = BODIES / "smpl_neutral.stl"


def test_up_y_turns_the_file_to_z_up():
    import trimesh

    raw = trimesh.load(MAN, force="mesh")
    z_up = load_mold({"path": str(MAN), "up": "y"})
    assert z_up.kind == MOLD_SMOOTH and "a scan" in z_up.surface_note  # a scan's default surface
    assert load_mold({"path": str(MAN), "up": "y", "surface": "faceted"}).kind == MOLD_MESH
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


# ---------------------------------------------------------------------------------------------
# open (not watertight) scans
# ---------------------------------------------------------------------------------------------


def _open_scan_band(**solver):
    from clothsim.config import scene_from_dict

    d = {"name": "waist-band-open-scan",
         "fabric": {"size": [0.72, 0.10], "divisions": [48, 8],
                    "warp": {"csv": "../static/materials/compression_knit_course.csv"},
                    "weft": {"csv": "../static/materials/compression_knit_wale.csv"}},
         "seams": [{"a": "left", "b": "right"}],
         "constraints": [{"nodes": "bottom", "axes": "z"}, {"nodes": "top", "axes": "z"},
                         {"nodes": {"i": 24}, "axes": "x"}],
         "initial": {"wrap_hull": {"center": [0, 0, 1.10], "clearance": 0.01, "start_angle": -90}},
         "mold": {"path": "../static/bodies/smpl_neutral.stl", "up": "y"},
         "solver": {"method": "newton", "e": 1e-7, "time_limit_s": 300, **solver}}
    return scene_from_dict(d, ROOT / "configs" / "x.yaml")


def test_open_scan_loads_as_an_open_skin():
    import trimesh

    assert not trimesh.load(NEUTRAL, force="mesh").is_watertight   # open at the eyes and mouth
    mold = load_mold({"path": str(NEUTRAL), "up": "y"})
    assert not mold.closed
    assert abs(mold.vertices[:, 2].min()) < 1e-9 and 1.6 < mold.vertices[:, 2].max() < 1.8
    with pytest.raises(MoldError, match="watertight|closed"):
        load_mold({"path": str(NEUTRAL), "up": "y", "closed": True})


def test_a_band_round_the_waist_of_an_open_scan_converges():
    """A knit tube (seamed band, 0.72 m round at rest) pulled round the waist of the open SMPL-X
    scan (0.87 m round the hull): Newton reaches 1e-7 N, no node behind the skin, the seam
    closed, every loaded node with a finite pressure (the band stays wide)."""
    import clothsim
    from clothsim.contact import max_penetration

    res = clothsim.solve(_open_scan_band())
    assert res.solve.converged, res.solve.message
    s = res.summary()
    assert max_penetration(res.state.positions, res.model.mold.kernel_args()) <= 1e-9
    assert s["contact_count"] > 100 and s["gathered_contact_nodes"] == 0
    assert 0 < s["max_contact_pressure_mmhg"] < 100
    assert s["max_seam_gap_m"] < 1e-5 and s["min_weft_extent_ratio"] > 0.9
    z = res.state.positions[:, 2]
    assert 1.04 < z.min() and z.max() < 1.16
