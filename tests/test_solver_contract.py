"""The solver contract (clothsim.solvers): solvers built from (model, typed options), step(state, n)
returning a StepReport, the run Status enum, one driver (limits, one stall detector, one history),
the composite auto, and Controls that apply a load in steps."""

import json
import math

import numpy as np
import pytest

from clothsim.config import SolverSettings, load_scene
from clothsim.simulation import Simulation, prepare
from clothsim.solvers import (STATUSES, AutoOptions, AutoSolver, Control, History, NewtonOptions, NewtonSolver,
                              PaperOptions, PaperSolver, RunLimits, Solver, Status, StepReport, StepStatus,
                              load_steps, make_solver, options_from_settings, run, solve_load_steps)

from conftest import ROOT, make_scene


def _strip(**changes):
    return prepare(make_scene(**changes))[:2]


def test_status_values_are_todays_strings():
    """The run statuses keep their strings (summary.json, sweeps and the CLI read them): the enum's
    values are STATUSES in order, each member equals, hashes, formats and serialises as its
    string."""
    assert [s.value for s in Status] == ["converged", "max_iterations", "time_limit", "stalled", "diverged",
                                         "stopped"]
    assert STATUSES == tuple(s.value for s in Status)
    for s in Status:
        assert s == s.value and hash(s) == hash(s.value) and f"{s}" == s.value and str(s) == s.value
        assert json.dumps({"status": s}) == json.dumps({"status": s.value})
        assert Status(s.value) is s
    assert {"converged": 1}.get(Status.CONVERGED) == 1
    assert [s.value for s in StepStatus] == ["ok", "converged", "diverged", "no_progress"]


def test_result_status_is_a_status_and_summary_unchanged():
    """A run's SolveResult.status is a Status; the summary carries its plain string."""
    import clothsim

    res = clothsim.solve(make_scene())
    assert isinstance(res.solve.status, Status) and res.solve.status is Status.CONVERGED
    s = json.loads(json.dumps(res.summary()))
    assert s["status"] == "converged" and type(s["status"]) is str


@pytest.mark.parametrize("cls", [PaperSolver, NewtonSolver])
def test_step_performs_at_most_n_iterations_and_reports_them(cls):
    """step(state, n) does at most n iterations, advances state.iteration by as many, and reports
    one residual [N] (equal to the shared residual at the end) and one energy [J] per iteration."""
    from clothsim.solvers.common import energy, residual

    model, state = _strip()
    solver = cls(model)
    rep = solver.step(state, 3)
    assert isinstance(rep, StepReport)
    assert 1 <= rep.iterations <= 3 and state.iteration == rep.iterations
    assert rep.residuals.shape == rep.energies.shape == (rep.iterations,)
    assert np.all(np.isfinite(rep.residuals)) and np.all(np.isfinite(rep.energies))
    assert rep.status in (StepStatus.OK, StepStatus.CONVERGED)
    v, _ = residual(model, state)
    assert rep.residual == pytest.approx(v, rel=1e-12, abs=1e-15)
    assert rep.energies[-1] == pytest.approx(energy(model, state), rel=1e-12)
    # with a tolerance, the step stops as soon as it is reached
    for _ in range(200):
        rep = solver.step(state, 50, e=1e-8)
        if rep.status == StepStatus.CONVERGED:
            break
    assert rep.status == StepStatus.CONVERGED and rep.residual <= 1e-8


def test_options_are_typed_and_validated():
    """Each solver takes its own options type; bad values are refused with the field's name."""
    model, _ = _strip()
    with pytest.raises(ValueError, match="C"):
        PaperOptions(C=1.0)
    with pytest.raises(ValueError, match="C"):
        PaperOptions(C=math.nan)
    with pytest.raises(ValueError, match="max_retries"):
        PaperOptions(max_retries=0)
    with pytest.raises(ValueError, match="max_retries"):
        PaperOptions(max_retries=2.5)
    with pytest.raises(ValueError, match="kink"):
        NewtonOptions(kink=-1.0)
    with pytest.raises(ValueError, match="kink"):
        NewtonOptions(kink=2e3)
    with pytest.raises(ValueError, match="sequencing"):
        NewtonOptions(sequencing="yes")
    with pytest.raises(ValueError):
        AutoOptions(newton=PaperOptions())
    with pytest.raises(TypeError, match="PaperOptions"):
        PaperSolver(model, NewtonOptions())
    with pytest.raises(ValueError):
        RunLimits(e=0.0)
    assert PaperSolver(model).options == PaperOptions(C=2.0, max_retries=60)
    assert NewtonSolver(model, NewtonOptions(kink=0.5, sequencing=False)).options.kink == 0.5


def test_scene_keys_map_onto_the_options():
    """The scene file's solver keys keep working: C, max_retries -> PaperOptions; newton_kink,
    newton_sequencing -> NewtonOptions; auto gets both. The kink default is 1e-3 everywhere."""
    s = SolverSettings(C=3.0, max_retries=7, newton_kink=0.5, newton_sequencing=False)
    assert options_from_settings("paper", s) == PaperOptions(C=3.0, max_retries=7)
    assert options_from_settings("newton", s) == NewtonOptions(kink=0.5, sequencing=False)
    assert options_from_settings("auto", s) == AutoOptions(NewtonOptions(0.5, False), PaperOptions(3.0, 7))
    assert NewtonOptions().kink == SolverSettings().newton_kink == 1e-3
    model, _ = _strip()
    assert isinstance(make_solver(model, SolverSettings(method="auto")), AutoSolver)
    assert isinstance(make_solver(model, SolverSettings(method="paper", C=4.0)), PaperSolver)
    assert make_solver(model, SolverSettings(method="paper", C=4.0)).options.C == 4.0


class _Flat(Solver):
    """A fake solver whose residual never improves (1 N) and whose energy is 0."""

    name = "flat"
    Options = PaperOptions

    def step(self, state, n, *, e=0.0, time_left_s=None):
        state.iteration += n
        return StepReport(n, np.ones(n), np.zeros(n))


def test_one_stall_detector_with_the_solver_window():
    """The driver's stall rule (no 1 % gain in the best residual) stops a run after the run's
    stall_iterations, or the solver's own stall_window when smaller (Newton: 100); it samples
    the residual at batch ends (batches of 1, 2, 4, ... iterations here)."""
    model, state = _strip()
    res = run(_Flat(model), state.copy(), RunLimits(e=1e-9, stall_iterations=40))
    assert res.status is Status.STALLED and 40 <= res.iterations < 80 and "40 iterations" in res.message
    flat = _Flat(model)
    flat.max_batch = 1
    flat.stall_window = 7
    res = run(flat, state.copy(), RunLimits(e=1e-9, stall_iterations=40))
    assert res.status is Status.STALLED and res.iterations == 7
    assert NewtonSolver.stall_window == 100 and PaperSolver.stall_window is None


def test_driver_limits_and_one_history():
    """max_iterations ends a run with Status.MAX_ITERATIONS; the history has one row per iteration
    with contiguous iteration numbers and non-decreasing times; runs appending to the same History
    continue it (this is what Simulation keeps: sim.history is every run's result history)."""
    model, state = _strip()
    h = History()
    r1 = run(_Flat(model), state, RunLimits(e=1e-9, max_iterations=5), history=h)
    assert r1.status is Status.MAX_ITERATIONS and r1.iterations == 5 and r1.history is h
    r2 = run(_Flat(model), state, RunLimits(e=1e-9, max_iterations=3), history=h)
    np.testing.assert_array_equal(h["iteration"], np.arange(1, 9))
    assert np.all(np.diff(h["time"]) >= 0) and h.size == 8 and r2.history is h
    assert h.elapsed_s == pytest.approx(r1.wall_time_s + r2.wall_time_s)
    sim = Simulation(make_scene(**{"solver.e": 1e-12}))
    try:
        a = sim.run(max_iterations=4)
        b = sim.run(max_iterations=3)
        assert a.history is b.history is sim.history
        np.testing.assert_array_equal(sim.hist_it, np.arange(1, 8))
        np.testing.assert_array_equal(sim.result().solve.history["residual"], sim.history["residual"])
    finally:
        sim.close()


def test_auto_is_newton_then_the_paper_rescue_on_a_stall(monkeypatch):
    """AutoSolver runs Newton; when Newton's step can make no progress the run is stalled and the
    paper's relaxation finishes from the same state, within the remaining iterations, on the same
    history; without a stall it is plain Newton (same result as NewtonSolver)."""
    model, state = _strip()
    limits = SolverSettings(method="auto", e=1e-9)
    ref = state.copy()
    r_newton = NewtonSolver(model).solve(ref, limits)
    plain = state.copy()
    r_auto = AutoSolver(model).solve(plain, limits)
    assert r_auto.method == "newton" and r_auto.converged and r_auto.iterations == r_newton.iterations
    np.testing.assert_array_equal(plain.positions, ref.positions)

    real_step = NewtonSolver.step

    def stalls_after_two(self, state, n, *, e=0.0, time_left_s=None):
        if state.iteration >= 2:
            return StepReport(0, np.zeros(0), np.zeros(0), StepStatus.NO_PROGRESS)
        return real_step(self, state, n, e=e, time_left_s=time_left_s)

    monkeypatch.setattr(NewtonSolver, "step", stalls_after_two)
    s = state.copy()
    auto = AutoSolver(model, AutoOptions(NewtonOptions(sequencing=False), PaperOptions(C=2.0)))
    res = auto.solve(s, limits.model_copy(update={"max_iterations": 100_000}))
    assert res.converged and res.method == "newton+paper" and "newton stalled" in res.message
    assert auto.current is auto.rescue
    it = res.history["iteration"]
    np.testing.assert_array_equal(it, np.arange(1, len(it) + 1))
    assert res.iterations == len(it) == s.iteration > 2


def test_control_applies_prescribed_positions():
    """Control.apply moves only the constrained coordinates of the state and returns the model
    with the new prescribed positions; load_steps interpolates linearly and ends exactly at the
    final positions."""
    model, state = _strip()
    p = model.prescribed_positions + 0.001
    before = state.positions.copy()
    m2 = Control(p).apply(model, state)
    fixed = model.fixed_axes
    np.testing.assert_array_equal(state.positions[fixed], p[fixed])
    np.testing.assert_array_equal(state.positions[~fixed], before[~fixed])
    np.testing.assert_array_equal(m2.prescribed_positions, p)
    assert m2.spring_nodes is model.spring_nodes
    steps = load_steps(model.rest_positions, model.prescribed_positions, 4)
    assert len(steps) == 4
    np.testing.assert_array_equal(steps[-1].prescribed_positions, model.prescribed_positions)
    mid = model.rest_positions + 0.5 * (model.prescribed_positions - model.rest_positions)
    np.testing.assert_allclose(steps[1].prescribed_positions, mid, rtol=0, atol=1e-15)
    with pytest.raises(ValueError):
        Control(np.zeros((3, 2)))
    with pytest.raises(ValueError):
        load_steps(model.rest_positions, model.prescribed_positions, 0)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["newton", "paper"])
def test_uniaxial_strip_in_four_load_steps_reaches_the_one_step_equilibrium(method):
    """The uniaxial strip (30 % stretch) applied in 4 load steps from the unstretched strip, each
    solved to 1e-10 N, ends at the same equilibrium as the stretch applied at once (within 1e-9 m)."""
    from clothsim.grid import State

    scene = load_scene(ROOT / "configs" / "uniaxial_strip.yaml",
                       [f"solver.method={method}", "solver.e=1e-10"])
    model, state, _ = prepare(scene)
    settings = scene.solver
    one = state.copy()
    r = make_solver(model, settings).solve(one, settings)
    assert r.converged, r.message
    steps = State(model.rest_positions.copy(), np.zeros(model.node_count, bool), 0)
    controls = load_steps(model.rest_positions, model.prescribed_positions, 4)
    last, results = solve_load_steps(lambda m: make_solver(m, settings), model, steps, controls, settings)
    assert len(results) == 4 and all(x.converged for x in results), [x.message for x in results]
    np.testing.assert_array_equal(last.prescribed_positions, model.prescribed_positions)
    assert np.abs(steps.positions - one.positions).max() <= 1e-9


def test_a_reused_newton_solver_notices_a_moved_state():
    """A NewtonSolver keeps the last residual between steps only while the state is where its
    last step left it: after a Control moves the constrained nodes, the next step starts from the
    residual of the moved state (one solver object can run every load step)."""
    from clothsim.solvers.common import residual

    model, state = _strip(**{"solver.method": "newton"})
    solver = NewtonSolver(model, NewtonOptions(sequencing=False))
    rep = solver.step(state, 2)
    assert solver._known_residual(state) == rep.residual
    p = model.prescribed_positions.copy()
    p[model.fixed_axes[:, 0], 0] += 1e-3
    Control(p).apply(model, state)
    assert solver._known_residual(state) is None
    moved = state.copy()
    res = solver.solve(state, RunLimits(e=1e-10))
    fresh = NewtonSolver(model, NewtonOptions(sequencing=False)).solve(moved, RunLimits(e=1e-10))
    assert res.converged and fresh.converged
    assert np.abs(state.positions - moved.positions).max() <= 1e-9
    assert residual(model, state)[0] <= 1e-10
