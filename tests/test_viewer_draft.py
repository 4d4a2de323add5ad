"""The viewer's scene draft without a server or a browser: every typed edit validates the whole
scene before it changes anything, records what is pending, and refuses values the message
stream or the model could not take; importing it does not import viser."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from clothsim.config import SceneError, scene_from_dict
from clothsim.material import MaterialError
from clothsim.mold import MoldError
from clothsim.viewer.draft import (
    DIVISIONS_MAX,
    MAX_ITERATIONS_MAX,
    RANGE_NODES,
    ConstraintEdit,
    SceneDraft,
    as_float,
    as_int,
    parse_table_text,
    table_text,
)

ROOT = Path(__file__).resolve().parent.parent

SMALL = {
    "name": "draft",
    "fabric": {"size": [0.1, 0.1], "divisions": [10, 10],
               "warp": {"strain": [0, 1], "tension": [0, 250]},
               "weft": {"strain": [0, 1], "tension": [0, 250]}},
    "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1},
                    {"nodes": {"i": [0, 2]}, "axes": "z"}],
    "mold": {"sphere": {"center": [0.05, 0.05, -0.02], "radius": 0.04}},
    "solver": {"method": "paper", "C": 2.0, "e": 1e-6},
}


@pytest.fixture
def draft(tmp_path):
    return SceneDraft(scene_from_dict(SMALL), upload_dir=tmp_path)


def test_import_does_not_load_viser():
    """The draft (and the package's pure modules) import without viser."""
    code = ("import sys, clothsim.viewer.draft, clothsim.viewer.plot, clothsim.viewer.glb, "
            "clothsim.viewer.fields; assert 'viser' not in sys.modules, 'viser imported'")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, env={"PYTHONPATH": str(ROOT)})


def test_invalid_edits_leave_the_draft_unchanged(draft):
    """Each refused edit raises with a field-named message and changes neither the data nor the
    pending set."""
    before = yaml.safe_dump(draft.data)
    with pytest.raises(SceneError, match="at least 1"):
        draft.set_divisions(0, 10)
    with pytest.raises(ValueError, match="whole number"):
        draft.set_divisions(2.5, 10)
    with pytest.raises(MaterialError, match="strictly increasing"):
        draft.set_tables(("0, 0\n0.5, 10\n0.3, 20", "tension"), ("0,0\n1,250", "tension"), 0)
    with pytest.raises(SceneError, match="thickness"):
        draft.set_tables(("0,0\n1,250", "tension"), ("0,0\n1,1e6", "stress"), 0)
    with pytest.raises(ValueError, match="initial lift"):
        draft.set_lift(float("nan"))
    with pytest.raises(SceneError, match="index ranges"):
        draft.save_constraint(0, ConstraintEdit(nodes=RANGE_NODES, axes="xyz"))
    with pytest.raises(SceneError, match="pick a constraint"):
        draft.delete_constraint(None)
    with pytest.raises(MoldError, match="unknown mold choice"):
        draft.mold_spec("nothing", 1.0, (0, 0, 0))
    assert yaml.safe_dump(draft.data) == before and not draft.pending


def test_huge_and_non_finite_numbers_are_refused():
    """A long integer or a non-finite value typed into a numeric field is refused with a message
    (never an OverflowError, never a value the message stream cannot serialise)."""
    huge = 99999999999999999999999
    with pytest.raises(ValueError, match="between"):
        as_int(huge, "max iterations", 0, MAX_ITERATIONS_MAX)
    with pytest.raises(ValueError, match="between"):
        as_int(huge, "warp divisions", 1, DIVISIONS_MAX)
    with pytest.raises(ValueError, match="whole number"):
        as_int(float("inf"), "x", 0, 10)
    with pytest.raises(ValueError, match="finite"):
        as_float("1e400", "e")
    with pytest.raises(ValueError, match="not a number"):
        as_float("abc", "e")
    assert as_int(12.0, "n", 0, 20) == 12 and isinstance(as_int(12.0, "n", 0, 20), int)


def test_valid_edits_are_pending_until_reset(draft):
    """Valid edits of fabric, materials, constraints and mold change the data and mark their
    group pending; reset_to a scene clears them."""
    draft.set_divisions(12, 10)
    draft.set_tables(("0, 0\n0.2, 40\n1.0, 400", "tension"), ("0,0\n1,250", "tension"), 0)
    k = draft.save_constraint(None, ConstraintEdit(nodes="corners", axes="z"))
    draft.set_mold(draft.mold_spec("box", 1.0, (0.0, 0.0, 0.01)))
    assert draft.data["fabric"]["divisions"] == [12, 10]
    assert draft.data["fabric"]["warp"] == {"strain": [0, 0.2, 1.0], "tension": [0, 40, 400]}
    assert k == 2 and draft.data["constraints"][2] == {"nodes": "corners", "axes": "z"}
    assert "box" in draft.data["mold"]
    assert draft.pending == {"fabric", "material", "constraints", "mold"}
    draft.delete_constraint(2)
    assert len(draft.data["constraints"]) == 2
    draft.reset_to(scene_from_dict(SMALL))
    assert not draft.pending and draft.data["fabric"]["divisions"] == [10, 10]


def test_constraint_edit_keeps_index_ranges_and_writes_stretch(draft):
    """Saving over a constraint with index ranges keeps them; a uniform stretch is one number,
    a non-uniform one a pair; a zero displacement is left out."""
    draft.save_constraint(1, ConstraintEdit(nodes=RANGE_NODES, axes="xy", stretch=(1.2, 1.2)))
    assert draft.data["constraints"][1] == {"nodes": {"i": [0, 2]}, "axes": "xy", "stretch": 1.2}
    draft.save_constraint(0, ConstraintEdit(nodes="left", axes="xyz", stretch=(1.0, 1.1),
                                            displacement=(0.0, 0.0, 0.01)))
    assert draft.data["constraints"][0] == {"nodes": "left", "axes": "xyz", "stretch": [1.0, 1.1],
                                            "displacement": [0.0, 0.0, 0.01]}


def test_preset_and_material_values(draft):
    """A preset sets both directions; material_values resolves it to its table."""
    from clothsim.presets import PRESETS

    name = next(iter(PRESETS))
    draft.set_preset(name)
    assert draft.preset() == name
    s, v, kind = draft.material_values("warp")
    assert kind == "tension" and s == list(PRESETS[name].strain) and v == list(PRESETS[name].warp)
    with pytest.raises(MaterialError, match="unknown preset"):
        draft.set_preset("no such preset")


def test_upload_stored_under_own_name(draft, tmp_path):
    """An uploaded mold is parsed before it is written, stored under a name chosen here and
    offered as a choice; a broken one is refused and nothing is written."""
    import trimesh

    box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    label = draft.add_upload("../../evil name.stl", box.export(file_type="stl"), 1.0, (0.05, 0.05, -0.011))
    assert label == "upload: evil name.stl"
    assert draft.uploads[label] == {"path": str(tmp_path / "mold_upload_1.stl")}
    with pytest.raises(MoldError, match="unknown mold format"):
        draft.add_upload("notes.xyz", b"\x00\x01garbage" * 10, 1.0, (0, 0, 0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mold_upload_1.stl"]
    spec = draft.mold_spec(label, 2.0, (0.0, 0.0, 0.0))
    assert spec == {"path": str(tmp_path / "mold_upload_1.stl"), "scale": 2.0}
    draft.set_mold(spec)
    assert "the mold was uploaded" in draft.scene_yaml()


def test_scene_yaml_roundtrip(draft):
    """The saved YAML loads back into the draft's scene and says what is not yet applied."""
    draft.set_divisions(8, 8)
    text = draft.scene_yaml()
    assert "not yet applied in the viewer: fabric" in text
    assert scene_from_dict(yaml.safe_load(text)).to_dict() == scene_from_dict(draft.data).to_dict()


def test_table_text_roundtrip():
    assert parse_table_text(table_text([0, 0.5, 1], [0, 10, 30])) == ([0, 0.5, 1], [0, 10, 30])
