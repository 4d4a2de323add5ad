"""The viewer's draft takes the scan fields like every other edit (validated through the scene
model): the stocking scene (panels placed round a body, a Y-up mold) loads, keeps its mold's up
axis through the mold chooser, refuses a bad wrap_hull edit with its field, and saves as YAML
that loads again. No server, no browser."""

from __future__ import annotations

import time

import pytest
import yaml
from conftest import ROOT

from clothsim.config import SceneError, load_scene, scene_from_dict
from clothsim.mold import MoldError
from clothsim.viewer.draft import SCENE_MOLD, SceneDraft

STOCKING = ROOT / "configs" / "garments" / "stocking.yaml"


def test_stocking_draft_keeps_up_and_wrap_hull(tmp_path):
    draft = SceneDraft(load_scene(STOCKING), upload_dir=tmp_path)
    assert draft.data["mold"]["up"] == "y"
    spec = draft.mold_spec(SCENE_MOLD, 1.0, (0.0, 0.0, 0.0))
    assert spec["up"] == "y"
    assert draft.mold_spec(SCENE_MOLD, 1.0, (0.0, 0.0, 0.0), "z").get("up") is None
    assert draft.mold_spec(SCENE_MOLD, 1.0, (0.0, 0.0, 0.0), "y")["up"] == "y"
    with pytest.raises(MoldError, match="up"):
        draft.mold_spec(SCENE_MOLD, 1.0, (0.0, 0.0, 0.0), "x")
    mold = draft.set_mold(spec)
    assert mold.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-9)      # stands on z = 0
    # a wrap_hull edit is validated like any other: a bad one is refused with its field
    with pytest.raises(SceneError, match="panels.0.placement.wrap_hull.clearance"):
        draft.edit("fabric", lambda d: d["panels"][0]["placement"]["wrap_hull"].__setitem__("clearance", -1))
    scene = draft.edit("fabric", lambda d: d["panels"][0]["placement"]["wrap_hull"].__setitem__("clearance", 0.02))
    assert scene.panels[0].placement.wrap_hull.clearance == 0.02
    again = scene_from_dict(yaml.safe_load(draft.scene_yaml()))
    assert again.panels[0].placement.wrap_hull.clearance == 0.02 and again.mold.up == "y"


def test_sheet_wrap_hull_edit_through_the_draft():
    d = {"name": "band", "fabric": {"size": [0.9, 0.1], "divisions": [40, 10],
                                    "warp": {"strain": [0, 1], "tension": [0, 250]},
                                    "weft": {"strain": [0, 1], "tension": [0, 250]}},
         "mold": {"path": str(ROOT / "static" / "bodies" / "smpl_man.stl"), "up": "y"},
         "initial": {"wrap_hull": {"center": [0, 0, 1.07]}}}
    draft = SceneDraft(scene_from_dict(d))
    with pytest.raises(SceneError, match="initial: give wrap or wrap_hull"):
        draft.edit("fabric", lambda x: x["initial"].__setitem__("wrap", {"radius": 0.2}))
    scene = draft.edit("fabric", lambda x: x["initial"]["wrap_hull"].__setitem__("heights", [-0.04, 0.04]))
    assert scene.initial.wrap_hull.heights == (-0.04, 0.04)


@pytest.mark.slow
def test_viewer_opens_the_stocking_with_its_up_axis():
    """The viewer (server side, no browser) opens the stocking scene: the mold's up axis shows
    in its dropdown, and choosing z there re-reads the scan lying on its back."""
    import socket

    pytest.importorskip("viser")
    from clothsim.viewer import ViewerApp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = ViewerApp(load_scene(STOCKING), port=port)
    try:
        app.wait_idle(60)
        assert app.gui["mold_up"].value == "y"
        assert app.sim.model.node_count > 500
        app.gui["mold_up"].value = "z"
        fab = app.panels["fabric"]
        fab.set_mold()  # the file re-read Z-up is not in the mold cache: parsed off the loop
        deadline = time.monotonic() + 120
        while fab.busy() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not fab.busy()
        # the parsed mold is applied to the draft on the update loop's next pass
        while app.scene_draft.data["mold"].get("up") is not None and time.monotonic() < deadline:
            app.wait_idle(5)
            time.sleep(0.05)
        assert app.scene_draft.data["mold"].get("up") is None
        assert app.panels["fabric"].mold_preview.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-9)
    finally:
        app.close()


def test_viewer_shows_the_units_and_reach_warnings():
    """A mold 1000x the sheet warns "millimetres?" as soon as it is chosen; a mold out of reach
    warns when the edit is applied (the compile's warning, shown under the mold)."""
    import socket

    pytest.importorskip("viser")
    from clothsim.viewer import ViewerApp

    d = {"name": "cap", "fabric": {"size": [0.1, 0.1], "divisions": [10, 10],
                                   "warp": {"strain": [0, 1], "tension": [0, 250]},
                                   "weft": {"strain": [0, 1], "tension": [0, 250]}},
         "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1}],
         "initial": {"lift": 0.03},
         "mold": {"sphere": {"center": [0.05, 0.05, -0.02], "radius": 0.04}},
         "solver": {"method": "newton", "e": 1e-6}}
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = ViewerApp(scene_from_dict(d), port=port)
    try:
        app.wait_idle(60)
        fabric = app.panels["fabric"]
        g = app.gui
        with app.quiet():
            g["mold_scale"].value = 1000.0
            g["mold"].value = "file: thermoform_mold.stl"
        fabric.set_mold()  # a file not in the mold cache yet: parsed off the loop
        deadline = time.monotonic() + 120
        while fabric.busy() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert any("millimetres?" in w for w in fabric.mold_warnings)
        assert "millimetres?" in g["mold_info"].content
        # a sphere 0.5 m beside the sheet: out of reach, said on apply
        with app.quiet():
            g["mold_scale"].value = 1.0
        far = {"sphere": {"center": [0.6, 0.05, -0.02], "radius": 0.04}}
        app.scene_draft.set_mold(far)
        app.apply(wait=True)
        app.wait_idle(60)
        assert any("can reach the mold" in w for w in fabric.mold_warnings), fabric.mold_warnings
        assert "can reach the mold" in g["mold_info"].content
    finally:
        app.close()
