"""The measuring levels in the viewer (clothsim.viewer.levelview, panels/levels.py) and the
garment's reduction edited there.

Known answers: on a leg from a chart whose levels are circles a level's ring lies at the level's
radius plus the lift, at its height, and its length is 2 pi (r + lift) to the polygon's error;
B's class band under RAL-GZ 387 is the class B falls in (II: 23-32 mmHg at 27); the viewer's
levels and profile read what ``run`` reads (Result.compression()["levels"]) on the same state;
a larger reduction, edited in the viewer and run again, reads a higher pressure, the one a
``run`` of the scene with that reduction reads.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from clothsim.config import load_scene
from clothsim.viewer.levelview import (RING_LIFT, class_band, level_rings, levels_table, profile_series,
                                       ring_label)

from conftest import ROOT
from viewer_util import free_port, wait_for

TUBE = ROOT / "configs" / "tube_on_leg_cone.yaml"
CLASS2 = ROOT / "configs" / "class2_sleeve.yaml"
# circular levels (test_levels.py's): B 22 cm round at 2 cm, C 24.5 cm at 8 cm, D 23.5 cm at 14 cm
LEG = ("mold={leg: {levels: {B: {girth_cm: 22, height_cm: 2}, C: {girth_cm: 24.5, height_cm: 8},"
       " D: {girth_cm: 23.5, height_cm: 14}}}}")
LEG_SCENE = [LEG, "constraints.1.displacement=[0, 0, 0]", "levels={radius: 0.008}", "profiles=[]"]
GARMENT = "garment={hem: -0.04, levels: [{name: B, height: 0.0}], reduction: %g}"


def test_rings_lie_round_each_chart_level_at_its_girth():
    from clothsim.mold import load_mold

    sc = load_scene(TUBE, LEG_SCENE)
    rings = level_rings(sc, load_mold(sc.mold, sc.base_dir))
    assert [r["name"] for r in rings] == ["B", "C", "D"]
    for r, (girth, z) in zip(rings, ((0.22, 0.02), (0.245, 0.08), (0.235, 0.14))):
        seg = r["segments"]
        R = girth / (2 * math.pi) + RING_LIFT
        p = seg[:, 0]
        assert np.allclose(seg[:, 1], np.roll(p, -1, axis=0))  # closed: each segment ends where the next starts
        assert np.allclose(p[:, 2], z) and r["z_m"] == pytest.approx(z)
        assert np.allclose(np.linalg.norm(p[:, :2] - np.array([0.0, 0.0]), axis=1), R, rtol=1e-6)
        n = len(seg)
        length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).sum()
        assert length == pytest.approx(2 * n * R * math.sin(math.pi / n), rel=1e-6)
        assert r["girth_m"] == pytest.approx(girth, rel=1e-6)
        assert np.linalg.norm(r["label"][:2]) > R and r["label"][2] == pytest.approx(z)
    assert ring_label(rings[0]) == "B 22.0 cm"
    assert ring_label(rings[0], {"mean_mmhg": 27.06}) == "B 22.0 cm · 27.1 mmHg"


def test_a_scan_ring_is_the_section_loop_round_the_level_centre():
    """On a scan the ring is the section's loop holding the level's centre, else the one whose
    mean is nearest (clothsim.compression.levels.section_loop, shared with the scan's girths):
    two legs, cylinders of radius 5 and 8 cm at x = -0.1 and 0.1 m."""
    import trimesh

    from clothsim.viewer.levelview import _scan_loop

    legs = [trimesh.creation.cylinder(radius=r, height=0.4, sections=64).apply_translation([x, 0, 0])
            for r, x in ((0.05, -0.1), (0.08, 0.1))]
    mesh = trimesh.util.concatenate(legs)
    for centre, (x, r) in (([0.12, 0.01], (0.1, 0.08)), ([-0.1, 0.0], (-0.1, 0.05)), ([-0.05, 0.3], (-0.1, 0.05))):
        xy = _scan_loop(mesh, {"z_m": 0.0, "center": centre})
        d = np.linalg.norm(xy - [x, 0.0], axis=1)       # on the 64-gon: from r cos(pi / 64) to r
        assert len(xy) >= 64 and np.all((d > r * math.cos(math.pi / 64) - 1e-9) & (d < r + 1e-9)), centre
    assert _scan_loop(mesh, {"z_m": 0.5, "center": [0.0, 0.0]}) is None     # above the legs: no section


def test_class_band_is_the_class_b_falls_in():
    assert class_band(27.0) == {"standard": "RAL-GZ 387", "class": "II", "min": 23.0, "max": 32.0}
    assert class_band(19.5)["class"] == "I"
    assert class_band(36.0)["class"] == "III"
    top = class_band(60.0)
    assert top["class"] == "IV" and top["max"] == pytest.approx(1.25 * 49)
    assert class_band(None) is None and class_band(math.nan) is None


def test_profile_series_marks_the_levels_at_their_heights():
    view = {"floor": -0.01,
            "profile": {"slices": [{"height_m": 0.0, "mean_mmhg": 30.0}, {"height_m": 0.05, "mean_mmhg": 25.0},
                                   {"height_m": 0.10, "mean_mmhg": None}]},
            "levels": {"levels": [{"level": "B", "height_m": 0.02, "girth_m": 0.22, "mean_mmhg": 28.0,
                                   "percent_of_b": 100.0},
                                  {"level": "C", "height_m": 0.08, "girth_m": 0.245, "mean_mmhg": None,
                                   "percent_of_b": None}]}}
    x, y, m, lo, hi = profile_series(view, class_band(28.0))
    assert x.tolist() == [1.0, 2.0, 6.0]  # cm above the floor, sorted; the slice without contact left out
    assert y.tolist() == [30.0, 28.0, 25.0]
    assert np.isnan(m[[0, 2]]).all() and m[1] == 28.0
    assert (lo == 23.0).all() and (hi == 32.0).all()
    text = levels_table(view, class_band(28.0))
    assert "| B | 2.0 | 22.0 | 28.0 | 100 |" in text and "| C | 8.0 | 24.5 | – | – |" in text
    assert "RAL-GZ 387 class II, 23–32 mmHg" in text


def _converge(app, timeout=600):
    app.start(wait=True)
    assert wait_for(lambda: app.sim.status != "running", timeout), app.sim.status
    assert app.sim.status == "converged", app.sim.status


@pytest.mark.slow
def test_viewer_draws_the_levels_and_reads_what_run_reads():
    """The tube on the chart leg: three rings and labels on the body, and once converged the
    levels' girth means and the profile as ``run`` reads them, in the plot and the table."""
    import clothsim
    from clothsim.viewer import ViewerApp

    sc = load_scene(TUBE, LEG_SCENE)
    app = ViewerApp(sc, port=free_port())
    try:
        lv = app.panels["levels"]
        assert app.gui["profile_plot"].visible and app.gui["show_levels"].visible
        assert wait_for(lambda: len(lv._nodes) == 6, 60)  # a ring and a label per level, before any run
        _converge(app)
        it = app.sim.state.iteration
        assert wait_for(lambda: lv.read_at == it, 120), (lv.read_at, it)
        ref = clothsim.solve(sc).compression()["levels"]["levels"]
        got = lv.view["levels"]["levels"]
        for a, b in zip(got, ref):
            assert a["level"] == b["level"]
            assert a["mean_mmhg"] == pytest.approx(b["mean_mmhg"], rel=1e-3)
        x, y, m, lo, hi = (np.asarray(v) for v in app.gui["profile_plot"].data)
        for r in got:
            k = int(np.argmin(np.abs(x - r["height_m"] * 100)))
            assert x[k] == pytest.approx(r["height_m"] * 100) and m[k] == pytest.approx(r["mean_mmhg"])
        assert np.isfinite(lo).all() and (hi > lo).all()
        y0, y1 = app.gui["profile_plot"].scales["y"]["range"]  # set, not uPlot's (NaN between levels)
        assert y0 <= min(np.nanmin(y), lo[0]) and y1 >= max(np.nanmax(y), hi[0])
        assert np.isfinite(y).sum() > 10  # slices every 5 mm over the tube's 16 cm
        labels = [h.text for h in lv._nodes if hasattr(h, "text")]
        assert any(t.startswith("B 22.0 cm · ") and t.endswith(" mmHg") for t in labels), labels
        assert "| B | 2.0 | 22.0 |" in app.gui["levels_table"].content
        app.gui["show_levels"].value = False
        assert wait_for(lambda: not any(h.visible for h in lv._nodes), 10)
    finally:
        app.close()


def test_no_levels_no_profile():
    from clothsim.viewer import ViewerApp
    from viewer_util import small_scene

    app = ViewerApp(small_scene(), port=free_port())
    try:
        assert not app.gui["profile_plot"].visible and not app.gui["show_levels"].visible
        app.step(wait=True)
        time.sleep(0.3)
        assert app.panels["levels"]._nodes == [] and app.panels["levels"].view is None
    finally:
        app.close()


@pytest.mark.slow
def test_reduction_edited_in_the_viewer_runs_with_the_new_pressure():
    """The class II sleeve with garment levels: the Reduction [%] control shows the scene's 15 %;
    set to 25 % and started again, the sleeve reads a higher pressure at the ankle, the one
    ``run`` reads with reduction 25 %."""
    import clothsim
    from clothsim.viewer import ViewerApp

    app = ViewerApp(load_scene(CLASS2, [GARMENT % 15]), port=free_port())
    try:
        red = app.gui["reduction"]
        assert red.visible and red.value == pytest.approx(15.0)
        probes = app.panels["probes"]
        _converge(app)
        assert wait_for(lambda: probes.read_at == app.sim.state.iteration, 120)
        before = probes.readings[0]["pressure_mmhg"]
        red.value = 25.0  # as a tab's edit arrives: on_update fires, the edit is posted
        assert wait_for(lambda: "panels" in app.pending, 20), app.errors
        _converge(app)
        assert app.sim.scene.garment.reduction == pytest.approx(25.0)
        assert wait_for(lambda: probes.read_at == app.sim.state.iteration and probes.readings, 120)
        after = probes.readings[0]["pressure_mmhg"]
        ref = clothsim.solve(load_scene(CLASS2, [GARMENT % 25])).compression()["probes"][0]["pressure_mmhg"]
        assert after > before + 3.0, (before, after)
        assert after == pytest.approx(ref, abs=0.05)
    finally:
        app.close()
