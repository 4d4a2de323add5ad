"""Coulomb friction between the fabric and the mold, checked against known answers (see
docs/method/friction.md): the capstan's tension ratio e^(mu phi) at two lattice sizes, a sheet on an
incline that sticks below tan(theta) = mu and slides above it, the scene field and its refusals,
and mu = 0 giving the frictionless result bit for bit."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from clothsim.bench.friction import end_tensions, turn_angle  # (T, d) at the strip's two ends; its wrap
from clothsim.compile import compile_model, compile_state
from clothsim.config import SceneError, load_scene, scene_from_dict
from clothsim.solvers import Control, load_steps, solve
from clothsim.solvers.friction import solve_steps

ROOT = Path(__file__).resolve().parent.parent
MU = 0.3


def _capstan(nx, pull=0.06, steps=20):
    """The cylinder wrap (configs/cylinder_wrap.yaml) solved frictionless, then with mu = 0.3
    its right end pulled down ``pull`` [m] further in ``steps`` load steps while the left end is
    held: (T_right / T_left, the wrap angle phi [rad] between the straight ends, the result)."""
    sc = load_scene(ROOT / "configs" / "cylinder_wrap.yaml",
                    [f"fabric.divisions=[{nx},{max(2, nx // 20)}]", "solver.method=newton", "solver.e=1e-7"])
    model = compile_model(sc)
    state = compile_state(sc, model)
    assert solve(model, state, sc.solver).converged
    (t0l, _), (t0r, _) = end_tensions(model, state.positions)
    assert t0r / t0l == pytest.approx(1.0, abs=1e-5)  # frictionless: the same tension both ends
    target = model.prescribed_positions.copy()
    right = model.fixed_axes[:, 2] & (model.rest_positions[:, 0] > 0.1)
    target[right, 2] -= pull
    controls = load_steps(model.prescribed_positions, target, steps)
    _, res = solve_steps(dataclasses.replace(model, friction_mu=MU), state, controls, sc.solver)
    (tl, dl), (tr, dr) = end_tensions(model, state.positions)
    # the angle the strip turns through from its left end's direction to its right end's (x-z plane)
    phi = turn_angle(dl, dr)
    return tr / tl, phi, res


def _capstan_pulled(pull, steps, **tuning):
    """The capstan (configs/cylinder_wrap.yaml, 20 divisions, e = 1e-7 N) solved frictionless,
    then with mu = 0.3 its right end pulled down ``pull`` [m] in ``steps`` load steps
    (``tuning``: solve_steps' FrictionTuning): (the positions, the pulled end's target positions,
    the pulled nodes (mask), the steps' result)."""
    sc = load_scene(ROOT / "configs" / "cylinder_wrap.yaml",
                    ["fabric.divisions=[20,2]", "solver.method=newton", "solver.e=1e-7"])
    model = compile_model(sc)
    state = compile_state(sc, model)
    assert solve(model, state, sc.solver).converged
    target = model.prescribed_positions.copy()
    right = model.fixed_axes[:, 2] & (model.rest_positions[:, 0] > 0.1)
    target[right, 2] -= pull
    _, res = solve_steps(dataclasses.replace(model, friction_mu=MU), state,
                         load_steps(model.prescribed_positions, target, steps), sc.solver, **tuning)
    return state.positions.copy(), target, right, res


def test_capstan_ratio_is_e_to_mu_phi_and_its_error_falls_with_the_lattice():
    """Euler-Eytelwein: a strip pulled past slip over a fixed cylinder carries T_high / T_low =
    e^(mu phi) across the contact arc. The frictional steps converge to e on the full residual,
    every contact node slips at the end, the cone holds, and the lattice's error falls as it
    refines (measured: 1.7e-2 at 20 divisions along the strip, 4.0e-4 at 40, 6.8e-5 at 80, 6.3e-5
    at 160)."""
    errors = []
    for nx in (20, 40):
        ratio, phi, res = _capstan(nx)
        assert res.converged, res.message
        assert res.residual <= 1e-7
        fr = res.friction
        assert fr["steps_solved"] == 20 and fr["slip"] > 0 and fr["stick"] == 0
        assert fr["cone_violation"] < 1e-5
        assert 1.9 < phi < 2.2  # the wrap this scene makes
        errors.append(abs(ratio / math.exp(MU * phi) - 1.0))
    assert errors[0] < 0.03
    assert errors[1] < 2e-3
    assert errors[1] < 0.2 * errors[0]


def test_capstan_below_slip_lies_inside_the_capstan_bounds():
    """Pulled a little (before the slip zone has crossed the arc) the left end has not yet felt
    the pull: its tension is the frictionless one, and the ratio lies between 1 and e^(mu phi)
    (path-dependent: anywhere in [e^-(mu phi), e^(mu phi)]); some nodes still stick."""
    ratio, phi, res = _capstan(20, pull=0.01, steps=5)
    assert res.converged, res.message
    assert 1.05 < ratio < math.exp(MU * phi)
    assert res.friction["stick"] > 0 and res.friction["slip"] > 0


def _incline(mu, tan_theta):
    """A 5 x 5 cm sheet lying on a plane in contact under gravity tilted by theta (the plane is
    z = 0; gravity's direction (sin, 0, -cos) is the same as a plane tilted by theta): one load
    step from rest. Returns (result, mean move down the slope [m], eps)."""
    th = math.atan(tan_theta)
    sc = scene_from_dict({
        "fabric": {"size": [0.05, 0.05], "divisions": [10, 10], "origin": [0, 0, 0.001],
                   "warp": {"preset": "powernet_est"}, "weft": {"preset": "powernet_est"}},
        "mold": {"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}, "friction": mu},
        "gravity": {"areal_density": 0.2, "direction": [math.sin(th), 0, -math.cos(th)]},
        "solver": {"method": "newton", "e": 1e-9}})
    model = compile_model(sc)
    state = compile_state(sc, model)
    state.positions[:, 2] = 0.0  # lying on the plane, in contact
    state.in_contact[:] = True
    p0 = state.positions.copy()
    _, res = solve_steps(model, state, [Control(model.prescribed_positions)], sc.solver)
    from clothsim.friction import slip_eps

    return res, float(np.mean(state.positions[:, 0] - p0[:, 0])), slip_eps(model)


def test_incline_sticks_below_tan_theta_equals_mu_and_slides_above():
    res, move, eps = _incline(MU, 0.9 * MU)
    assert res.converged, res.message
    assert res.friction["stick"] == 121 and res.friction["slip"] == 0
    assert 0.0 < move < eps  # held: it creeps less than the slip eps
    res, move, eps = _incline(MU, 1.02 * MU)
    assert not res.converged
    assert "slid away" in res.message
    assert move > 1.0  # no static equilibrium: the sheet runs away down the slope


def test_incline_frictionless_slides():
    res, move, _ = _incline(0.0, 0.1)
    assert not res.converged and move > 1.0


def test_friction_zero_is_bit_identical_and_the_scene_pays_nothing():
    """mold.friction: 0 (or absent) builds the same Model (no friction) and gives the
    frictionless equilibrium bit for bit; the scene file's field is read into Model.friction_mu."""
    from clothsim.simulation import solve as run

    base = load_scene(ROOT / "configs" / "cylinder_wrap.yaml", ["fabric.divisions=[20,2]", "solver.e=1e-7"])
    zero = load_scene(ROOT / "configs" / "cylinder_wrap.yaml", ["fabric.divisions=[20,2]", "solver.e=1e-7",
                                                                "mold.friction=0"])
    assert compile_model(zero).friction_mu == 0.0 and compile_model(zero).friction is None
    a, b = run(base), run(zero)
    assert a.solve.converged
    assert np.array_equal(a.state.positions, b.state.positions)
    assert a.summary()["residual"] == b.summary()["residual"]
    assert "friction" not in a.summary() and "friction" not in b.summary()
    mu = load_scene(ROOT / "configs" / "cylinder_wrap.yaml", ["mold.friction=0.4"])
    assert compile_model(mu).friction_mu == 0.4


def test_friction_scene_runs_in_load_steps_and_reports_the_coulomb_state(tmp_path):
    """A scene with friction runs through Simulation in solver.load_steps steps (the ends lowered
    onto the cylinder in 8 steps): converged on the full residual, the summary has the friction
    report, and the result files are written."""
    from clothsim.simulation import solve as run

    sc = load_scene(ROOT / "configs" / "cylinder_wrap.yaml",
                    ["fabric.divisions=[20,2]", "solver.e=1e-7", "mold.friction=0.3", "solver.load_steps=8"])
    r = run(sc)
    s = r.summary()
    assert r.solve.converged, r.solve.message
    assert s["residual"] <= 1e-7
    fr = s["friction"]
    assert fr["mu"] == 0.3 and fr["load_steps"] == 8 and fr["steps_solved"] == 8
    assert fr["stick"] + fr["slip"] > 0 and fr["cone_violation"] < 1e-5
    r.save(tmp_path)
    assert (tmp_path / "summary.json").exists()


def _write(tmp_path, text):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


def test_bad_friction_is_refused_with_file_and_line(tmp_path):
    head = ("fabric: {size: [0.1, 0.02], divisions: [10, 2], warp: {preset: powernet_est}, "
            "weft: {preset: powernet_est}}\n")
    p = _write(tmp_path, head + "mold:\n  cylinder: {center: [0, 0, -0.1], axis: [0, 1, 0], radius: 0.05, length: 0.2}\n"
                                "  friction: -0.2\n")
    with pytest.raises(SceneError, match=r"s\.yaml:4: mold\.friction: must be a number from 0 to 10"):
        load_scene(p)
    p = _write(tmp_path, head + "mold:\n  cylinder: {center: [0, 0, -0.1], axis: [0, 1, 0], radius: 0.05, length: 0.2}\n"
                                "  friction: 0.3\nsolver: {method: paper}\n")
    with pytest.raises(SceneError, match=r"s\.yaml:5: solver\.method: 'paper' is frictionless"):
        load_scene(p)
    # frictionless with paper is fine, as is friction with newton
    load_scene(p, ["mold.friction=0"])
    load_scene(p, ["solver.method=newton"])
    p = _write(tmp_path, head + "solver: {load_steps: 0}\n")
    with pytest.raises(SceneError, match=r"s\.yaml:2: solver\.load_steps: must be at least 1"):
        load_scene(p)


def test_a_failing_load_step_is_cut_in_half_and_the_run_goes_on(monkeypatch):
    """A load step that fails (here: any step that moves the pulled end by more than 4 mm is made
    to stall) is cut in half until its pieces pass; the run converges through them and says how
    many steps were cut. A step whose control does not move cannot be cut: it fails at once."""
    import clothsim.solvers.friction as sf
    from clothsim.solvers.base import Status

    real = sf._frictional_step

    def flaky(base, state, control, *rest):
        fixed = base.fixed_axes
        move = np.abs(control.prescribed_positions[fixed] - state.positions[fixed]).max()
        if move > 0.004:
            ok, m, res, r, rep = real(base, state, control, *rest)
            return False, m, dataclasses.replace(res, converged=False, status=Status.STALLED), r, None
        return real(base, state, control, *rest)

    monkeypatch.setattr(sf, "_frictional_step", flaky)
    pos, target, right, res = _capstan_pulled(0.01, 2)
    assert res.converged, res.message
    assert res.friction["cuts"] == 2 and res.friction["steps_solved"] == 4  # 5 mm steps cut to 2.5 mm
    assert "2 load step(s) cut in half" in res.message
    assert np.allclose(pos[right, 2], target[right, 2])


def test_stages_drape_then_pull_reach_the_capstan_and_keep_every_stage():
    """``stages:`` (the capstan as a scene: drape frictionless, then friction on and the right end
    pulled 0.06 m in 20 steps) gives the same equilibrium as the path built by hand, and the
    summary keeps both stages."""
    from clothsim.simulation import solve as run

    r = run(load_scene(ROOT / "tests" / "data" / "capstan_stages.yaml"))
    assert r.solve.converged, r.solve.message
    s = r.summary()
    st = s["friction"]["stages"]
    assert [x["name"] for x in st] == ["drape", "pull"]
    assert [x["load_steps"] for x in st] == [1, 20]
    assert st[0]["friction"]["mu"] == 0.0 and st[1]["friction"]["mu"] == 0.3
    assert s["friction"]["slip"] > 0 and s["friction"]["stick"] == 0
    # each step's iterations count all its solves (on main only the last refresh's: 97 of 304)
    assert [sum(x["iterations"] for x in t["friction"]["steps"]) for t in st] == [t["iterations"] for t in st]
    (tl, dl), (tr, dr) = end_tensions(r.model, r.state.positions)
    phi = turn_angle(dl, dr)
    assert abs(tr / tl / math.exp(MU * phi) - 1) < 2e-3
    ratio, _, _ = _capstan(40)
    assert tr / tl == pytest.approx(ratio, rel=1e-5)


def test_a_stage_that_sets_a_bad_value_or_field_is_refused_with_file_and_line(tmp_path):
    text = (ROOT / "tests" / "data" / "capstan_stages.yaml").read_text()
    p = tmp_path / "s.yaml"
    p.write_text(text.replace("mold.friction: 0.3", "mold.friction: -1"))
    with pytest.raises(SceneError, match=r"s\.yaml:\d+: stages\.1\.set: mold\.friction: must be a number"):
        load_scene(p)
    p.write_text(text.replace("mold.friction: 0.3", "fabric.divisions: [80, 4]"))
    with pytest.raises(SceneError, match=r"s\.yaml:\d+: stages\.1\.set: 'fabric\.divisions': a stage may change"):
        load_scene(p)


def _tube_on_cone(mu):
    """The knit tube on the faceted leg cone (tan(alpha) = 0.05) solved frictionless with its
    cuffs held along the leg, then released with friction mu in one load step: (result, mean move
    along the leg [m], contact nodes before, after)."""
    sc = load_scene(ROOT / "configs" / "tube_on_leg_cone.yaml",
                    ["constraints.1.displacement=[0,0,0]", "fabric.divisions=[34,16]", "solver.e=3e-6",
                     "solver.time_limit_s=300"])
    model = compile_model(sc)
    state = compile_state(sc, model)
    assert solve(model, state, sc.solver).converged
    z0 = state.positions[:, 2].copy()
    c0 = int(state.in_contact.sum())
    fixed = model.fixed_axes.copy()
    fixed[:, 2] = False  # the cuffs let go along the leg
    m = dataclasses.replace(model, fixed_axes=fixed, friction_mu=mu)
    _, res = solve_steps(m, state, [Control(m.prescribed_positions)], sc.solver)
    return res, float(np.mean(state.positions[:, 2] - z0)), c0, int(state.in_contact.sum())


def test_tube_on_a_cone_stays_above_its_slip_threshold_and_slides_off_below():
    """A tube pressed on a cone of half-angle alpha only by its own hoop tension is held while mu >=
    tan(alpha) (0.05 here) and slides towards the narrow end below it."""
    res, dz, c0, c1 = _tube_on_cone(0.1)
    assert res.converged, res.message
    assert abs(dz) < 1e-3 and c1 == c0
    assert res.friction["stick"] > res.friction["slip"]
    assert res.friction["cone_violation"] < 1e-3
    res, dz, c0, c1 = _tube_on_cone(0.03)
    assert dz < -0.05 and c1 < 0.2 * c0  # slid down and off the cone's narrow end


def test_the_schedule_is_a_record_and_no_friction_module_keeps_a_switch():
    """Issue 30: the frictional steps' switches are the fields of one frozen FrictionTuning record
    passed to ``solve_steps`` (no module-level switch to monkeypatch). The schedules compared in
    docs/method/friction.md reach the same capstan (20 divisions, 5 steps): refreshed once per
    solve, to a tenth of each solve's start residual, it needs more friction refreshes."""
    import ast

    from clothsim.solvers.tuning import FrictionTuning

    src = (ROOT / "clothsim" / "solvers" / "friction.py").read_text()
    names = [t.id for n in ast.parse(src).body if isinstance(n, ast.Assign) for t in n.targets
             if isinstance(t, ast.Name) and t.id.isupper()]
    assert not names, names
    with pytest.raises(dataclasses.FrozenInstanceError):
        FrictionTuning().max_cuts = 1  # type: ignore[misc]
    for bad in ({"max_relags": 0}, {"max_cuts": -1}, {"refresh_forcing": 1.5}):
        with pytest.raises(ValueError):
            FrictionTuning(**bad)
    out = []
    for tuning in (FrictionTuning(), FrictionTuning(refresh_every_iteration=False)):
        pos, _, _, res = _capstan_pulled(0.03, 5, tuning=tuning)
        assert res.converged and res.residual <= 1e-7, res.message
        out.append((pos, res.friction["refreshes"]))
    assert np.abs(out[0][0] - out[1][0]).max() < 1e-5
    assert out[1][1] > out[0][1]


def test_the_equilibria_check_judges_a_friction_scene_with_its_friction():
    """scripts/equilibria.py's fallback (recorded positions beyond the tolerance: are they still
    an equilibrium of the code?) judges a staged friction scene by its last stage's model with
    the full residual, friction included. The capstan's equilibrium reads at most e there; the
    frictionless residual at the same positions is the friction's share of the pull (on main the
    check used it: 0.33 N on the stocking with friction's own reference, e = 1e-7 N)."""
    import importlib.util

    from clothsim.solvers.friction import coulomb_residual
    from clothsim.simulation import solve as run
    from clothsim.solvers.common import residual

    spec = importlib.util.spec_from_file_location("equilibria", ROOT / "scripts" / "equilibria.py")
    eq = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(eq)
    scene = "tests/data/capstan_stages.yaml"
    r = run(load_scene(ROOT / scene))
    assert r.solve.converged, r.solve.message
    v, e = eq.reference_residual(scene, r.state.positions)
    assert e == 1e-7 and v <= e
    free = dataclasses.replace(r.model, friction=None, friction_mu=0.0)
    assert residual(free, r.state)[0] > 1e-3
    assert coulomb_residual(free, r.state) == residual(free, r.state)[0]  # mu = 0: the frictionless one
    pos = r.state.positions.copy()
    pos[pos.shape[0] // 2, 0] += 1e-6  # a node moved along the strip: out of balance even with friction
    assert eq.reference_residual(scene, pos)[0] > 1e-3


def test_a_load_step_past_its_iteration_budget_is_rescued_with_a_wider_slip_eps(monkeypatch):
    """A load step's first solve that runs past ``FrictionTuning.rescue_after`` iterations starts
    again from the step's start with the slip eps ``eps_continuation`` times wider, and the
    scene's eps takes over from its equilibrium: the capstan (20 divisions, 5 steps) with a budget
    of 3 iterations is rescued and reaches the equilibrium of the default schedule (the same
    Coulomb state: the wide eps only gives Newton its start); with a budget of 0 nothing is."""
    import clothsim.solvers.friction as sf
    from clothsim.solvers.tuning import FrictionTuning

    for bad in ({"rescue_after": -1}, {"eps_continuation": 0.5}):
        with pytest.raises(ValueError):
            FrictionTuning(**bad)
    calls = []
    real = sf._rescue

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(sf, "_rescue", counted)
    out = []
    for tuning in (FrictionTuning(rescue_after=0), FrictionTuning(rescue_after=3)):
        calls.clear()
        pos, _, _, res = _capstan_pulled(0.03, 5, tuning=tuning)
        assert res.converged and res.residual <= 1e-7, res.message
        out.append((pos, len(calls), res.friction["slip"], res.friction["cone_violation"]))
    assert out[0][1] == 0 and out[1][1] >= 1
    assert np.abs(out[0][0] - out[1][0]).max() < 1e-5
    assert out[1][2] == out[0][2] and out[1][3] < 1e-5
