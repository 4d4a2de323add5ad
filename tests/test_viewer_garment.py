"""Garments in the viewer, server side (no browser): each panel's outline as an ordered loop of
its boundary nodes; a DXF/SVG pattern upload read with clothsim.patterns whose pieces are listed
and added as panels (or replace the scene's panels); placement edits of a selected panel (rigid
translate/rotate, wrap radius/axis) and the mold's surface/smoothing, each validated through the
SceneDraft like every other edit (a refused value shows on the red line and its widget shows the
last valid value again)."""

from __future__ import annotations

import io
import socket
import time

import numpy as np
import pytest
from conftest import ROOT

from clothsim.config import SceneError, load_scene
from clothsim.patterns import PatternError
from clothsim.simulation import Simulation
from clothsim.viewer.draft import PATTERN_UPLOAD_MAX_BYTES, SceneDraft
from clothsim.viewer.render import outline_loops, outline_segments
from viewer_util import BOMB_SVG, pattern_dxf  # noqa: E402

ezdxf = pytest.importorskip("ezdxf")

GARMENTS = ROOT / "configs" / "garments"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ---------------------------------------------------------------------- outlines
@pytest.mark.parametrize("name, loops", [("circle_blank", 1), ("sleeve_dxf", 2)])
def test_outline_loops_follow_each_panel_boundary(name, loops):
    """Every boundary node is on its panel's loop once, and consecutive nodes are lattice
    neighbours or diagonal ones (no jump across the panel): the loop is the outline in order."""
    sim = Simulation(load_scene(GARMENTS / f"{name}.yaml"))
    try:
        topo = sim.model.topology
        got = outline_loops(topo)
        assert len(got) == loops
        allnodes = np.concatenate(got)
        assert len(allnodes) == len(set(allnodes.tolist())) == int(topo.boundary.sum())
        for p, lp in enumerate(got):
            assert (topo.node_panel[lp] == p).all()
            ij = topo.node_ij[lp]
            step = np.abs(ij - np.roll(ij, -1, axis=0)).max(axis=1)
            assert step.max() <= 1, step.max()
        seg = outline_segments(got)
        assert seg.shape == (len(allnodes), 2)
    finally:
        sim.close()


def test_rectangle_outline_loop_is_its_perimeter():
    """A ``fabric:`` rectangle's loop runs round its 4 x 8 edge nodes (the viewer draws outlines
    only for scenes of pattern panels)."""
    sim = Simulation(load_scene(ROOT / "configs" / "thermoform.yaml", ["fabric.divisions=[8,8]"]))
    try:
        (lp,) = outline_loops(sim.model.topology)
        assert len(lp) == 32
        ij = sim.model.topology.node_ij[lp]
        assert (np.abs(ij - np.roll(ij, -1, axis=0)).sum(axis=1) == 1).all()
        assert outline_segments([]).shape == (0, 2)
    finally:
        sim.close()


# ---------------------------------------------------------------------- draft: patterns
def test_pattern_upload_pieces_added_and_replacing(tmp_path):
    draft = SceneDraft(load_scene(GARMENTS / "circle_blank.yaml"), upload_dir=tmp_path)
    label = draft.add_pattern("my pattern.dxf", pattern_dxf())
    pieces = draft.patterns[label][1]
    assert [p.name for p in pieces] == ["FRONT", "BACK"]
    assert pieces[0].area == pytest.approx(6000e-6, rel=1e-12)
    assert pieces[1].area == pytest.approx(4800e-6, rel=1e-12)
    scene = draft.add_pattern_piece(label, "BACK", at=(0.2, 0.0, 0.01))
    assert [p.name for p in scene.panels] == ["blank", "BACK"] and "panels" in draft.pending
    assert scene.panels[1].placement.transform.translate == pytest.approx((0.2 - 0.15, 0.0, 0.01))
    sim = Simulation(scene)   # the added panel builds: its node areas sum to the piece's area
    try:
        topo = sim.model.topology
        sel = topo.node_panel == topo.panel_index("BACK")
        assert sim.model.node_area[sel].sum() == pytest.approx(4800e-6, rel=1e-9)
        # placed: it starts from x = 0.2 on, its outline in z = 0.01 (the interior lifted)
        pos = sim.state.positions
        assert pos[sel, 0].min() == pytest.approx(0.2, abs=1e-12)
        assert np.allclose(pos[sel & topo.boundary, 2], 0.01)
    finally:
        sim.close()
    again = draft.add_pattern_piece(label, "BACK")     # a second copy gets a name of its own
    assert [p.name for p in again.panels] == ["blank", "BACK", "BACK_2"]
    with pytest.raises(SceneError, match="no piece 'SLEEVE'"):
        draft.add_pattern_piece(label, "SLEEVE")
    # replacing: the file's pieces are the panels, side by side, 2 cm apart
    scene = draft.replace_panels(label, at=(0.0, 0.0, 0.0))
    assert [p.name for p in scene.panels] == ["FRONT", "BACK"]
    assert scene.panels[1].placement.transform.translate[0] == pytest.approx(0.1 + 0.02 - 0.15)
    # saved: the YAML warns that the pattern is a temporary upload; the zip carries it
    assert "pattern was uploaded" in draft.scene_yaml()
    import zipfile
    names = zipfile.ZipFile(io.BytesIO(draft.scene_zip())).namelist()
    assert "files/pattern_upload_1.dxf" in names


def test_pattern_replaces_a_rectangle_and_drops_old_seams(tmp_path):
    draft = SceneDraft(load_scene(ROOT / "configs" / "thermoform.yaml"), upload_dir=tmp_path)
    label = draft.add_pattern("p.dxf", pattern_dxf())
    scene = draft.add_pattern_piece(label, "FRONT")     # a rectangle has no panels: replaced
    assert [p.name for p in scene.panels] == ["FRONT"] and scene.fabric.size is None
    sleeve = SceneDraft(load_scene(GARMENTS / "sleeve_dxf.yaml"), upload_dir=tmp_path)
    label = sleeve.add_pattern("p.dxf", pattern_dxf())
    scene = sleeve.replace_panels(label)
    assert [p.name for p in scene.panels] == ["FRONT", "BACK"] and not scene.seams
    # the constraint naming the old 'front' panel goes; the unnamed ones stay
    assert all(getattr(c.nodes, "panel", None) is None for c in scene.constraints)
    assert len(scene.constraints) == 2


def test_pattern_upload_refusals_name_the_uploaded_file(tmp_path):
    draft = SceneDraft(load_scene(GARMENTS / "circle_blank.yaml"), upload_dir=tmp_path)
    before = draft.data
    with pytest.raises(PatternError, match=r"^mold\.stl: a pattern is a \.dxf or \.svg file"):
        draft.add_pattern("mold.stl", b"solid x")
    with pytest.raises(PatternError, match=r"^empty\.svg: no pattern pieces found"):
        draft.add_pattern("empty.svg", b'<svg xmlns="http://www.w3.org/2000/svg"></svg>')
    with pytest.raises(PatternError, match="over the pattern limit"):
        draft.add_pattern("big.dxf", b" " * (PATTERN_UPLOAD_MAX_BYTES + 1))
    tri = b'<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">' \
          b'<path id="bow" d="M0 0 L50 50 L50 0 L0 50 Z"/></svg>'
    with pytest.raises(PatternError) as exc:
        draft.add_pattern("bow tie.svg", tri)
    assert "bow_tie.svg" in str(exc.value) and str(tmp_path) not in str(exc.value)
    assert draft.data is before and not draft.pending and not draft.patterns
    assert list(tmp_path.iterdir()) == []   # nothing refused is kept
    with pytest.raises(PatternError, match="not accepted"):
        SceneDraft(load_scene(GARMENTS / "circle_blank.yaml")).add_pattern("p.dxf", pattern_dxf())


#: issue 28, item 1: 89 bytes that froze every tab for minutes (memory to 3.7 GB)
def test_hostile_pattern_upload_refused_by_the_bounds(tmp_path):
    """The reader's bounds refuse the file before flattening it; the message names the upload,
    never the stored copy, and nothing is kept."""
    draft = SceneDraft(load_scene(GARMENTS / "circle_blank.yaml"), upload_dir=tmp_path)
    with pytest.raises(PatternError, match=r"^bomb\.svg: piece path1, <path>: a curve's control point has a "
                                           r"coordinate of 2\.65e\+16 m, beyond the bound of 1e\+06 m"):
        draft.add_pattern("bomb.svg", BOMB_SVG)
    assert list(tmp_path.iterdir()) == [] and not draft.patterns


# ---------------------------------------------------------------------- draft: placements, mold surface
def test_placement_edits_validated_through_the_draft():
    draft = SceneDraft(load_scene(GARMENTS / "sleeve_dxf.yaml"))
    assert draft.placement(1)[0] == "wrap"
    scene = draft.set_wrap(1, 0.06, (0, 0, 2))
    assert scene.panels[1].placement.wrap.radius == 0.06 and scene.panels[1].placement.wrap.axis == (0, 0, 2)
    assert scene.panels[1].placement.wrap.start_angle == pytest.approx(89.99998071)   # kept
    with pytest.raises(SceneError, match=r"panels\.1\.placement\.wrap\.axis"):
        draft.set_wrap(1, 0.06, (0, 0, 0))
    with pytest.raises(SceneError, match=r"panels\.1\.placement\.wrap\.radius"):
        draft.set_wrap(1, 0, (0, 0, 1))
    with pytest.raises(ValueError, match="wrap radius"):
        draft.set_wrap(1, "abc", (0, 0, 1))
    assert draft.data["panels"][1]["placement"]["wrap"]["radius"] == 0.06   # unchanged by refusals
    with pytest.raises(SceneError, match="pick a panel"):
        draft.set_transform(5, (0, 0, 0), (0, 0, 0))
    # a rigid placement replaces the wrap; rotation in degrees, translation in metres
    scene = draft.set_transform(0, (0.01, 0.02, 0.03), (0, 0, 90))
    assert scene.panels[0].placement.transform.rotate == (0, 0, 90)
    assert scene.panels[0].placement.wrap is None
    with pytest.raises(SceneError, match="not a wrap placement"):
        draft.set_wrap(0, 0.05, (0, 0, 1))
    with pytest.raises(ValueError, match="rotate"):
        draft.set_transform(0, (0, 0, 0), (0, float("nan"), 0))


def test_mold_surface_and_smoothing_spec():
    draft = SceneDraft(load_scene(ROOT / "configs" / "thermoform.yaml"))
    label = "scene's mold"
    spec = draft.mold_spec(label, 1.0, (0, 0, 0), None, "smooth", 0.002)
    assert spec["surface"] == "smooth" and spec["smoothing"] == 0.002
    spec = draft.mold_spec(label, 1.0, (0, 0, 0), None, "smooth", 0)
    assert spec["surface"] == "smooth" and "smoothing" not in spec
    spec = draft.mold_spec(label, 1.0, (0, 0, 0), None, "faceted", 0.002)
    assert spec["surface"] == "faceted" and "smoothing" not in spec
    spec = draft.mold_spec(label, 1.0, (0, 0, 0), None, "auto", 0.002)  # the default: left out
    assert "surface" not in spec and "smoothing" not in spec
    with pytest.raises(Exception, match="surface"):
        draft.mold_spec(label, 1.0, (0, 0, 0), None, "bumpy", 0)
    with pytest.raises(ValueError, match="smoothing"):
        draft.mold_spec(label, 1.0, (0, 0, 0), None, "smooth", -1)


# ---------------------------------------------------------------------- the app (server side)
def _wait_mold(app, timeout=120):
    fab = app.panels["fabric"]
    deadline = time.monotonic() + timeout
    while (fab.busy() or not app.wait_idle(1)) and time.monotonic() < deadline:
        time.sleep(0.05)


def test_viewer_panel_list_placement_widgets_and_pattern_upload():
    pytest.importorskip("viser")
    from clothsim.viewer import ViewerApp

    app = ViewerApp(load_scene(GARMENTS / "sleeve_dxf.yaml"), port=_free_port())
    try:
        app.wait_idle(60)
        g = app.gui
        assert g["panel_pick"].options == ("front", "back")
        assert "| front |" in g["panels"].content and "| back |" in g["panels"].content
        assert len(app.renderer.outline_ab) == int(app.sim.model.topology.boundary.sum())
        g["panel_pick"].value = "back"
        app.wait_idle(20)
        assert g["pl_radius"].visible and not g["pl_translate"].visible
        assert g["pl_radius"].value == pytest.approx(0.055)
        g["pl_radius"].value = 0.0            # refused by the scene: red line, last valid value back
        app.wait_idle(20)
        assert "radius" in app.errors["panels"]
        assert g["pl_radius"].value == pytest.approx(0.055)
        assert "panels" not in app.pending
        g["pl_radius"].value = 0.06
        app.wait_idle(20)
        assert app.errors["panels"] == "" and "panels" in app.pending
        assert app.draft["panels"][1]["placement"]["wrap"]["radius"] == 0.06
        # a pattern upload: listed, one piece added beside the sleeve, applied
        app.post(lambda: app.panels["garment"].pattern_uploaded("pieces.dxf", pattern_dxf()), "pattern")
        app.wait_idle(20)
        assert app.errors["pattern"] == ""
        assert g["pattern_piece"].options == ("FRONT", "BACK")
        assert "| BACK | 48.00 | 10.0 x 6.0 |" in g["pattern_info"].content
        g["pattern_piece"].value = "BACK"
        app.post(app.panels["garment"].add_piece, "pattern")
        app.wait_idle(20)
        assert app.errors["pattern"] == "", app.errors
        assert g["panel_pick"].options == ("front", "back", "BACK") and g["panel_pick"].value == "BACK"
        assert g["pl_translate"].visible and not g["pl_radius"].visible
        n0 = app.sim.model.node_count
        app.apply(wait=True)
        assert app.errors["run"] == "", app.errors["run"]
        model = app.sim.model
        assert model.topology.names == ("front", "back", "BACK") and model.node_count > n0
        app.wait_idle(20)
        assert len(outline_loops(model.topology)) == 3
        assert len(app.renderer.outline_ab) == int(model.topology.boundary.sum())
        assert "| BACK |" in g["panels"].content
        # a rigid placement edit of the new panel, then a refused one
        g["pl_translate"].value = (0.1, 0.0, 0.02)
        app.wait_idle(20)
        assert app.errors["panels"] == ""
        assert app.draft["panels"][2]["placement"]["transform"]["translate"] == [0.1, 0.0, 0.02]
        g["pl_rotate"].value = (0.0, 0.0, 1e9)
        app.wait_idle(20)
        assert "rotate" in app.errors["panels"] and g["pl_rotate"].value == (0.0, 0.0, 0.0)
        # a broken upload: the red line names the file
        app.post(lambda: app.panels["garment"].pattern_uploaded("broken.svg", b"<svg"), "pattern")
        app.wait_idle(20)
        assert app.errors["pattern"].startswith("broken.svg:")
        # the outline toggle hides the line set
        g["show_outlines"].value = False
        app.wait_idle(20)
        time.sleep(0.3)
        assert app.renderer.h_outlines.visible is False
    finally:
        app.close()


def test_viewer_reads_pattern_uploads_off_the_update_loop(monkeypatch):
    """A pattern upload is read in a worker thread: while the reader is busy (held here on an
    event), the update loop runs other edits; once read, its pieces are listed. The hostile SVG
    of issue 28 comes back as a refusal on the pattern group's red line."""
    pytest.importorskip("viser")
    import threading

    from clothsim import patterns
    from clothsim.viewer import ViewerApp

    release, entered = threading.Event(), threading.Event()
    real = patterns.read_pattern

    def held(*a, **kw):
        entered.set()
        assert release.wait(60)
        return real(*a, **kw)

    app = ViewerApp(load_scene(GARMENTS / "sleeve_dxf.yaml"), port=_free_port())
    try:
        app.wait_idle(60)
        g = app.gui
        garment = app.panels["garment"]
        monkeypatch.setattr(patterns, "read_pattern", held)
        app.post(lambda: garment.pattern_uploaded("pieces.dxf", pattern_dxf()), "pattern")
        assert entered.wait(30)
        ran = threading.Event()
        app.post(ran.set)                  # another edit, posted while the pattern is being read
        assert ran.wait(20), "the update loop waited for the pattern reader"
        assert garment.busy() and not app.wait_idle(0.2)   # not idle while a read is pending
        assert "Reading **pieces.dxf**" in g["pattern_info"].content
        release.set()
        assert app.wait_idle(30)
        assert app.errors["pattern"] == "" and g["pattern_piece"].options == ("FRONT", "BACK")
        assert not garment.busy()
        monkeypatch.setattr(patterns, "read_pattern", real)
        app.post(lambda: garment.pattern_uploaded("bomb.svg", BOMB_SVG), "pattern")
        assert app.wait_idle(30)
        assert app.errors["pattern"].startswith("bomb.svg: piece path1, <path>: "), app.errors["pattern"]
        assert "beyond the bound of 1e+06 m" in app.errors["pattern"]
        assert g["pattern_piece"].options == ("FRONT", "BACK")   # the earlier upload is still listed
    finally:
        release.set()
        app.close()


def test_viewer_mold_surface_widgets():
    pytest.importorskip("viser")
    from clothsim.viewer import ViewerApp

    app = ViewerApp(load_scene(ROOT / "configs" / "thermoform.yaml", ["fabric.divisions=[8,8]"]),
                    port=_free_port())
    try:
        app.wait_idle(60)
        g = app.gui
        assert g["mold_surface"].value == "auto"            # the scene leaves it to the default
        assert app.sim.model.mold.kind_name == "mesh"        # ... which is faceted for this CAD mold
        assert app.renderer.h_outlines is None           # a rectangle: no outline drawn
        g["mold_smoothing"].value = 0.003
        _wait_mold(app)
        assert "smoothing" not in app.draft["mold"]          # auto: no smoothing
        g["mold_surface"].value = "smooth"
        _wait_mold(app)
        assert app.errors["mold"] == "", app.errors["mold"]
        assert app.draft["mold"]["surface"] == "smooth" and app.draft["mold"]["smoothing"] == 0.003
        assert "mold" in app.pending
        g["mold_smoothing"].value = -1.0                      # refused: the last valid value again
        _wait_mold(app)
        assert "smoothing" in app.errors["mold"] and g["mold_smoothing"].value == 0.003
        app.apply(wait=True)
        assert app.errors["run"] == "", app.errors["run"]
        assert app.sim.scene.mold.surface == "smooth" and app.sim.scene.mold.smoothing == 0.003
    finally:
        app.close()
