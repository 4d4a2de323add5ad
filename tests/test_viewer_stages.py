"""Issue 30 item 6, without a browser: the friction coefficient editable in the viewer (a draft
edit applied with Apply), the stages listed, run stage by stage and their end states shown and
replayed, stick/slip as a categorical colour field, and the convergence plot's stage marks. The
scene is the capstan as a loading path (tests/data/capstan_stages.yaml: drape frictionless, then
pull with mu = 0.3 in 20 steps; 0.7 s)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")

from clothsim.config import load_scene  # noqa: E402
from clothsim.simulation import Simulation  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402
from clothsim.viewer.draft import SceneDraft  # noqa: E402
from clothsim.viewer.fields import node_field  # noqa: E402
from clothsim.viewer.plot import ResidualPlot, marks_label, with_marks  # noqa: E402
from clothsim.viewer.render import friction_colours, friction_legend  # noqa: E402

from viewer_util import free_port, settle, small_scene, wait_for  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CAPSTAN = ROOT / "tests" / "data" / "capstan_stages.yaml"


@pytest.fixture(scope="module")
def capstan():
    """The capstan scene run to its end by a Simulation: (sim, result)."""
    sim = Simulation(load_scene(CAPSTAN))
    res = sim.run()
    assert res.converged, res.message
    return sim, sim.result()


def test_stick_slip_field_counts_what_the_summary_counts(capstan):
    """The field's categories: 0 no contact, 1 contact without friction, 2 stick, 3 slip; at the
    capstan's end the stick and slip nodes are the summary's (every contact node slips past slip),
    the held ends (constrained) are no friction nodes, and the colours are the categories'."""
    sim, r = capstan
    v = node_field(r.model, r.state.positions, r.state.in_contact, "friction")
    fr = r.summary()["friction"]
    assert set(np.unique(v)) <= {0.0, 1.0, 2.0, 3.0}
    assert int((v == 3).sum()) == fr["slip"] > 0 and int((v == 2).sum()) == fr["stick"] == 0
    assert int((v == 0).sum()) == int((~r.state.in_contact).sum())
    # the start (frictionless model, no load step solved): contact without friction, no stick/slip
    s0 = sim.stage_ends[0]
    v0 = node_field(s0.model, s0.positions, s0.in_contact, "friction")
    assert not (v0 >= 2).any()
    cols = friction_colours(np.array([0.0, 1.0, 2.0, 3.0]))
    assert cols.shape == (4, 3) and len({tuple(c) for c in cols.round(4)}) == 4
    assert cols[3][0] > cols[3][1] and cols[2][1] > cols[2][0]  # slip red, stick green
    text = friction_legend(v)
    assert f"red = slip ({fr['slip']})" in text and "green = stick (0)" in text


def test_a_partial_pull_shows_both_stick_and_slip(tmp_path):
    """Pulled 1 cm only (the slip zone has not crossed the arc), nodes near the held end still
    stick: the field shows both categories, as many as the summary counts."""
    text = CAPSTAN.read_text().replace("[0, 0, -0.16]", "[0, 0, -0.11]").replace("steps: 20", "steps: 5")
    (tmp_path / "partial.yaml").write_text(text)
    sim = Simulation(load_scene(tmp_path / "partial.yaml"))
    res = sim.run()
    assert res.converged, res.message
    v = node_field(sim.model, sim.state.positions, sim.state.in_contact, "friction")
    fr = res.friction
    assert int((v == 2).sum()) == fr["stick"] > 0 and int((v == 3).sum()) == fr["slip"] > 0


def test_the_run_keeps_each_stage_and_pauses_at_a_stage_end():
    """run_stage pauses once the current stage is solved (drape), keeping the state at the start
    and at the stage's end and where each stage began; Start goes on with the next stage. The
    list gives each stage's changes, state and report."""
    sim = Simulation(load_scene(CAPSTAN))
    try:
        rows = sim.stage_list()
        assert [r["name"] for r in rows] == ["drape", "pull"] and [r["state"] for r in rows] == ["to do", "to do"]
        assert rows[1]["changes"] == "mold.friction = 0.3; constraints.1.displacement = [0, 0, -0.16]"
        assert rows[1]["steps"] == 20
        sim.run_stage()
        assert sim.wait(120) == "paused", sim.message
        assert "stage 'drape' done" in sim.message
        assert [e.name for e in sim.stage_ends] == ["start", "drape"]
        assert [r["state"] for r in sim.stage_list()] == ["done", "current"]
        assert sim.stage_marks == [(0, "drape")]
        drape = sim.stage_ends[1]
        assert np.array_equal(drape.positions, sim.state.positions) and drape.report["friction"]["mu"] == 0.0
        sim.start()
        assert sim.wait(120) == "converged", sim.message
        assert [e.name for e in sim.stage_ends] == ["start", "drape", "pull"]
        assert [b for b, _ in sim.stage_marks] == [0, drape.iteration]
        rows = sim.stage_list()
        assert [r["state"] for r in rows] == ["done", "done"]
        assert rows[1]["report"]["friction"]["slip"] > 0
        assert not np.array_equal(sim.stage_ends[1].positions, sim.stage_ends[2].positions)
    finally:
        sim.close()


def test_friction_is_a_draft_edit():
    """mu is the draft's mold.friction: 0 leaves the field out (the frictionless scene); a scene
    without a mold, a value out of [0, 10] and the paper's method (frictionless) are refused with
    a message; a new mold keeps the draft's mu."""
    d = SceneDraft(load_scene(CAPSTAN))
    assert d.friction() == 0.0
    scene = d.set_friction(0.45)
    assert scene.mold.friction == 0.45 and d.pending == {"friction"}
    d.set_friction(0)
    assert "friction" not in d.data["mold"]
    with pytest.raises(ValueError, match="friction mu"):
        d.set_friction(11)
    d.set_friction(0.2)
    d.set_mold({"sphere": {"center": [0.1, 0.01, -0.05], "radius": 0.05}})
    assert d.data["mold"]["friction"] == 0.2
    paper = SceneDraft(small_scene())  # method: paper
    with pytest.raises(Exception, match="paper"):
        paper.set_friction(0.3)
    bare = SceneDraft(small_scene())
    bare.data.pop("mold")
    with pytest.raises(ValueError, match="no mold"):
        bare.set_friction(0.3)


class _Handle:
    """A uPlot handle that records what is sent."""

    def __init__(self, series):
        self.series, self.data, self.axes, self.scales = series, None, None, None


class _Gui:
    def add_uplot(self, data, series, **kw):
        return _Handle(series)


def test_the_plot_marks_where_each_stage_began():
    """The convergence plot of a staged run gets a fourth series, a vertical line at each stage's
    first iteration (three points there: below the plot, above it, below), the other series
    keeping their values there; the x axis names the stages. A run without stages has three."""
    x = np.arange(1.0, 11.0)
    y = 10.0 ** -x
    xs, (ys, es), m = with_marks(x, [y, np.full_like(y, 1e-7)], [(0, "drape"), (4, "pull")], 1e-12, 1e2)
    assert len(xs) == len(x) + 6 and np.all(np.diff(xs) >= 0)
    k = np.nonzero(m == 1e2)[0]
    assert list(xs[k]) == [0.0, 4.0] and np.all(m[k - 1] == 1e-12) and np.all(m[k + 1] == 1e-12)
    assert ys[k[1]] == pytest.approx(1e-4) and np.allclose(es, 1e-7, rtol=1e-12, atol=0)
    assert marks_label([(0, "drape"), (4, "pull")]) == "iteration · stages: drape from 0, pull from 4"
    plot = ResidualPlot(_Gui(), 1e-7, 0.04)
    plot.update((x, y), (np.zeros(0), np.zeros(0)), 1e-7, lambda: 1.0, False, [(0, "drape"), (4, "pull")])
    h = plot.handle
    assert len(h.series) == 4 and h.series[3]["label"] == "stage starts" and len(h.data) == 4
    assert "pull from 4" in h.axes[0]["label"]
    plot.update((x, y * 2), (np.zeros(0), np.zeros(0)), 1e-7, lambda: 1.0, False, ())
    assert len(h.series) == 3 and len(h.data) == 3 and h.axes[0]["label"] == "iteration"


@pytest.mark.slow
def test_viewer_stages_tab_replays_and_mu_applies():
    """The app: the Stages tab lists the stages; *Run to the end of this stage* pauses after the
    drape; after the run, Previous / Next / Replay show each stage's end state in the 3D view
    (the positions sent are the stage's) and Live the run again; the stick/slip field's legend
    counts the slipping nodes; mu typed into the tab is a pending edit that Apply makes the
    model's; the convergence plot marks both stages."""
    app = ViewerApp(load_scene(CAPSTAN), port=free_port())
    try:
        settle(app)
        table = app.gui["stages_table"].content
        assert "drape" in table and "pull" in table and "to do" in table
        app.run_stage(wait=True)
        assert wait_for(lambda: app.sim.status == "paused", 120), app.sim.message
        settle(app)
        assert [e.name for e in app.sim.stage_ends] == ["start", "drape"]
        app.start(wait=True)
        assert wait_for(lambda: app.sim.status == "converged", 120), app.sim.message
        settle(app, 0.5)
        ends = app.sim.stage_ends
        assert "| done |" in app.gui["stages_table"].content
        assert app.gui["stage_show"].options == ("live", "start", "1: end of drape", "2: end of pull")
        app.panels["stages"]._ask("Previous")
        assert wait_for(lambda: app.pushed_positions is ends[2].positions, 10)
        app.panels["stages"]._ask("Previous")
        assert wait_for(lambda: app.pushed_positions is ends[1].positions, 10)
        assert app.gui["stage_show"].value == "1: end of drape"
        assert "end of stage 1 (drape)" in app.gui["stage_note"].content
        app.panels["stages"]._ask("Replay")
        seen = []
        assert wait_for(lambda: seen.append(app.panels["stages"].shown) or (
            not app.panels["stages"].replaying and app.pushed_positions is ends[2].positions), 20)
        assert {0, 1, 2} <= set(seen)
        app.panels["stages"]._ask("Live")
        assert wait_for(lambda: app.panels["stages"].shown is None
                        and app.pushed_positions is not ends[2].positions, 10)
        assert np.array_equal(app.pushed_positions, app.sim.state.positions)
        app.gui["field"].value = "stick / slip"
        assert wait_for(lambda: "red = slip" in app.panels["view"].legend, 10)
        assert f"slip ({app.sim.last_result.friction['slip']})" in app.panels["view"].legend
        assert app.plot.marked and "pull from" in app.plot.handle.axes[0]["label"]
        app.gui["mu"].value = 0.5
        assert wait_for(lambda: "friction" in app.pending, 10)
        app.apply(wait=True)
        settle(app)
        assert app.sim.scene.mold.friction == 0.5 and app.sim.model.friction_mu == 0.5
        assert app.sim.stage_ends == [] or app.sim.stage_ends[0].name == "start"
        assert app.panels["stages"].shown is None
    finally:
        app.close()
