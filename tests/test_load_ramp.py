"""A stage's loads are ramped as its displacements are (issue 30 item 2): the external force
(gravity) goes linearly from the previous stage's to the stage's over its steps, and
``solver.load_steps`` ramps it from zero (docs/method/friction.md, Stages). Known answers: a
strip hanging under its own weight from a clamped end (linear table of slope k [N/m], areal
density rho) stretches by rho g L^2 / (2 k) at its free end, at every step for that step's load;
the last step's equilibrium is the one-step one; a frictional step and its rescue see the ramped
load; a frictional load step keeps within the user's ``solver.max_iterations`` (rescue included)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import ROOT

import clothsim
from clothsim import simulation
from clothsim.compile import compile_model, compile_state
from clothsim.config import load_scene, scene_from_dict
from clothsim.solvers import load_steps, solve
from clothsim.solvers.friction import solve_steps
from clothsim.solvers.tuning import FrictionTuning

G = 9.80665
L, K, RHO = 0.10, 10.0, 0.2  # strip length [m], table slope [N/m], areal density [kg/m^2]


def _strip(**extra):
    """A 10 x 1 cm strip (20 x 1 divisions, linear tables of slope K) clamped at its left end and
    hanging along +x under its own weight (gravity along +x)."""
    d = {"fabric": {"size": [L, 0.01], "divisions": [20, 1],
                    "warp": {"strain": [0, 1], "tension": [0, K]}, "weft": {"strain": [0, 1], "tension": [0, K]}},
         "constraints": [{"nodes": "left", "axes": "xyz"}],
         "gravity": {"areal_density": RHO, "direction": [1, 0, 0]},
         "solver": {"method": "newton", "e": 1e-12}}
    d.update(extra)
    return scene_from_dict(d)


def _elongation(rho):
    """The free end's stretch [m] under the strip's own weight: rho g L^2 / (2 k) (the lattice's
    lumped loads give it exactly: each spring carries the weight below its middle)."""
    return rho * G * L ** 2 / (2 * K)


def _spy(monkeypatch):
    """Record (the Model's external force, the positions at its equilibrium) after each
    frictionless load step's solve of a Simulation."""
    seen = []
    real = simulation.make_solver

    def make(model, settings):
        solver = real(model, settings)
        inner = solver.solve

        def solve_and_record(state, *a, **k):
            res = inner(state, *a, **k)
            seen.append((model.external_force.copy(), state.positions.copy()))
            return res

        solver.solve = solve_and_record
        return solver

    monkeypatch.setattr(simulation, "make_solver", make)
    return seen


def _free_end(model, pos):
    right = np.isclose(model.rest_positions[:, 0], model.rest_positions[:, 0].max())
    return float(np.mean(pos[right, 0])) - L


def test_a_stage_that_doubles_gravity_ramps_it_and_each_step_sits_at_its_loads_elongation(monkeypatch):
    """The stage doubles rho in 4 steps: step k sees the external force (1 + k/4) f0 (the last
    exactly 2 f0), its free end sits at the analytic stretch for that load (to 1e-8 relative: e = 1e-12 N over the springs' 10 N/m),
    and the last step's equilibrium is the one-step run's (path independent without friction)."""
    one = clothsim.solve(_strip(stages=[{"name": "double", "steps": 1,
                                         "set": {"gravity.areal_density": 2 * RHO}}]))
    assert one.solve.converged, one.solve.message
    seen = _spy(monkeypatch)
    r = clothsim.solve(_strip(stages=[{"name": "double", "steps": 4, "set": {"gravity.areal_density": 2 * RHO}}]))
    assert r.solve.converged, r.solve.message
    f0 = compile_model(_strip()).external_force
    assert len(seen) == 4
    for k, (f, pos) in enumerate(seen, 1):
        np.testing.assert_allclose(f, (1 + k / 4) * f0, rtol=1e-12, atol=0)
        rho = RHO * (1 + k / 4)
        assert _free_end(r.model, pos) == pytest.approx(_elongation(rho), rel=1e-8)
    np.testing.assert_array_equal(seen[-1][0], 2 * f0)
    np.testing.assert_array_equal(r.model.external_force, one.model.external_force)
    assert np.abs(r.state.positions - one.state.positions).max() < 1e-10
    steps = r.summary()["friction"]["steps"]
    assert [s["external_force_n"][0] for s in steps] == pytest.approx(
        [(1 + k / 4) * RHO * G * L * 0.01 for k in range(1, 5)], rel=1e-12)
    assert [s["name"] for s in r.summary()["friction"]["stages"]] == ["double"]


def test_load_steps_ramp_gravity_from_zero(monkeypatch):
    """A scene without stages in solver.load_steps = 4 steps: step k carries k/4 of its gravity and
    stretches k/4 of rho g L^2 / (2 k); one step carries it all at once, as before."""
    seen = _spy(monkeypatch)
    r = clothsim.solve(_strip(solver={"method": "newton", "e": 1e-12, "load_steps": 4}))
    assert r.solve.converged, r.solve.message
    f = r.model.external_force
    assert len(seen) == 4
    for k, (fk, pos) in enumerate(seen, 1):
        np.testing.assert_allclose(fk, k / 4 * f, rtol=1e-12, atol=0)
        assert _free_end(r.model, pos) == pytest.approx(k / 4 * _elongation(RHO), rel=1e-8)
    one = clothsim.solve(_strip(solver={"method": "newton", "e": 1e-12, "load_steps": 1}))
    np.testing.assert_array_equal(one.model.external_force, f)
    assert np.abs(one.state.positions - r.state.positions).max() < 1e-10


def test_a_stage_without_gravity_changes_carries_no_force_ramp(monkeypatch):
    """A stage that leaves gravity as it is gives every step the stage's own force (no ramp, no
    per-step force in the log): such scenes solve as before."""
    seen = _spy(monkeypatch)
    r = clothsim.solve(_strip(stages=[{"name": "same", "steps": 3, "set": {"solver.e": 1e-11}}]))
    assert r.solve.converged
    f = r.model.external_force
    assert all(np.array_equal(fk, f) for fk, _ in seen) and len(seen) == 3
    assert all("external_force_n" not in s for s in r.summary()["friction"]["steps"])


def _incline_scene(mu, tan_theta, steps):
    """A 5 x 5 cm sheet 1 mm above the plane z = 0 with friction mu, without gravity; one stage switches
    on gravity tilted by theta (direction (sin, 0, -cos)) in ``steps`` load steps."""
    th = math.atan(tan_theta)
    return scene_from_dict({
        "fabric": {"size": [0.05, 0.05], "divisions": [10, 10], "origin": [0, 0, 0.001],
                   "warp": {"preset": "powernet_est"}, "weft": {"preset": "powernet_est"}},
        "mold": {"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}, "friction": mu},
        "solver": {"method": "newton", "e": 1e-9},
        "stages": [{"name": "gravity on", "steps": steps,
                    "set": {"gravity": {"areal_density": 0.2, "direction": [math.sin(th), 0, -math.cos(th)]}}}]})


def test_gravity_switched_on_in_steps_on_an_incline_with_friction(monkeypatch):
    """The incline (mu = 0.3, tan theta = 0.9 mu) with gravity switched on in one stage of 4 steps:
    every frictional step's Model carries k/4 of the final external force (the last exactly it),
    the sheet sticks (every node, creeping less than the slip eps per step) and the summary logs each
    step's total force."""
    import clothsim.solvers.friction as sf
    from clothsim.friction import slip_eps

    seen = []
    real = sf._frictional_step

    def spy(base, state, control, *a, **k):
        out = real(base, state, control, *a, **k)
        seen.append(out[1].external_force.copy())
        return out

    monkeypatch.setattr(sf, "_frictional_step", spy)
    sc = _incline_scene(0.3, 0.27, 4)
    r = clothsim.solve(sc)
    assert r.solve.converged, r.solve.message
    f1 = r.model.external_force
    assert f1.any() and len(seen) == 4
    for k, f in enumerate(seen, 1):
        np.testing.assert_allclose(f, k / 4 * f1, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(seen[-1], f1)
    fr = r.summary()["friction"]
    assert fr["stick"] == 121 and fr["slip"] == 0
    p0 = compile_state(sc, compile_model(sc)).positions
    # held: each step's creep is below the slip eps (the lagged friction's stick), 4 steps' below 4 eps
    assert 0 < float(np.mean(r.state.positions[:, 0] - p0[:, 0])) < 4 * slip_eps(r.model)
    total = 0.2 * G * 0.05 ** 2 * math.sin(math.atan(0.27))
    assert [s["external_force_n"][0] for s in fr["steps"]] == pytest.approx([k / 4 * total for k in range(1, 5)],
                                                                           rel=1e-8)


def test_the_friction_rescue_solves_the_ramped_step(monkeypatch):
    """A step rescued with the wider slip eps (rescue_after = 1) is solved again with that step's
    ramped external force, not the final one."""
    import clothsim.solvers.friction as sf

    calls = []
    real = sf._rescue

    def counted(m, *a, **k):
        calls.append(m.external_force.copy())
        return real(m, *a, **k)

    monkeypatch.setattr(sf, "_rescue", counted)
    d = _incline_scene(0.3, 0.27, 4).to_dict()
    gravity = d.pop("stages")[0]["set"]["gravity"]
    sc = scene_from_dict(d)
    full = compile_model(scene_from_dict({**d, "gravity": gravity}))
    model = compile_model(sc)
    state = compile_state(sc, model)
    f1 = full.external_force
    controls = load_steps(model.prescribed_positions, model.prescribed_positions, 4,
                          forces=(np.zeros_like(f1), f1))
    _, res = solve_steps(dataclasses.replace(model, friction_mu=0.3), state, controls, sc.solver,
                         tuning=FrictionTuning(rescue_after=1))
    assert res.converged, res.message
    assert calls, "no step was rescued"
    shares = sorted({round(float(np.sum(c) / np.sum(f1)), 12) for c in calls})
    assert set(shares) <= {0.25, 0.5, 0.75, 1.0} and shares[0] < 1.0


def test_a_frictional_load_step_keeps_within_max_iterations_rescue_included():
    """The capstan's pull (20 divisions, one step, mu = 0.3) with solver.max_iterations = 12 and
    the rescue after 3 iterations: the step's first solve, the rescue's two and any refresh's
    share the 12 (before: 3 + 12 + 12); with 2000 it converges as before."""
    sc = load_scene(ROOT / "configs" / "cylinder_wrap.yaml",
                    ["fabric.divisions=[20,2]", "solver.method=newton", "solver.e=1e-7"])
    out = []
    for budget in (12, 2000):
        model = compile_model(sc)
        state = compile_state(sc, model)
        assert solve(model, state, sc.solver).converged
        target = model.prescribed_positions.copy()
        right = model.fixed_axes[:, 2] & (model.rest_positions[:, 0] > 0.1)
        target[right, 2] -= 0.03
        lim = sc.solver.model_copy(update={"max_iterations": budget})
        it0 = state.iteration
        _, res = solve_steps(dataclasses.replace(model, friction_mu=0.3), state,
                             load_steps(model.prescribed_positions, target, 1), lim,
                             tuning=FrictionTuning(rescue_after=3, max_cuts=0))
        out.append((res, state.iteration - it0))
    res, used = out[0]
    assert not res.converged and res.status == "max_iterations", res.message
    assert used <= 12
    res, used = out[1]
    assert res.converged, res.message
    assert 12 < used <= 2000


def test_a_paused_staged_run_goes_on_at_the_load_it_was_at(monkeypatch):
    """The strip's doubling stage stopped after its second load step (as the viewer's pause stops
    it) and gone on with: the rest of the stage ramps from the second step's force (1.5 f0, what a
    halved step would start from), and the run reaches the one-go equilibrium and its loads."""
    stages = [{"name": "double", "steps": 4, "set": {"gravity.areal_density": 2 * RHO}}]
    once = clothsim.solve(_strip(stages=stages))
    real = simulation.solve_steps
    calls = []

    def two_steps_then_pause(model, state, controls, *a, **k):
        calls.append((len(controls), k.get("model_force")))
        if len(calls) > 1:
            return real(model, state, controls, *a, **k)
        m, res = real(model, state, controls[:2], *a, **k)
        res.friction["steps_solved"] = 2
        return m, dataclasses.replace(res, converged=False, status="stopped")

    monkeypatch.setattr(simulation, "solve_steps", two_steps_then_pause)
    sim = simulation.Simulation(_strip(stages=stages))
    assert not sim.run().converged and sim._steps_done == 2
    res = sim.run()
    assert res.converged and not sim._plan
    f0 = compile_model(_strip()).external_force
    assert calls[0][0] == 4 and np.array_equal(calls[0][1], f0)
    assert calls[1][0] == 2
    np.testing.assert_allclose(calls[1][1], 1.5 * f0, rtol=1e-12, atol=0)
    assert np.abs(sim.state.positions - once.state.positions).max() < 1e-10
    np.testing.assert_array_equal(sim.model.external_force, once.model.external_force)
    assert _free_end(sim.model, sim.state.positions) == pytest.approx(_elongation(2 * RHO), rel=1e-8)
