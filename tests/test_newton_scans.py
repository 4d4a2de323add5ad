"""Projected Newton on scanned bodies (issue 12): held-axis contact nodes projected onto a curved
surface, no penetration after any iteration, and iteration counts the campaign's traces fixed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import ROOT

import clothsim
from clothsim import bench
from clothsim.contact import max_penetration
from clothsim.mold import mold_primitive, mold_query
from clothsim.solvers.newton import PENETRATION_TOL, NewtonSolver
from clothsim.solvers.newton.active_set import _trial_positions_sd
from clothsim.solvers.newton import active_set
from clothsim.solvers.options import newton_options


def _sphere_trial(steps):
    R, z0 = 0.1, 0.05
    rho0 = math.sqrt(R * R - z0 * z0)
    margs = mold_primitive("sphere", {"center": [0, 0, 0], "radius": R}).kernel_args()
    pos = np.array([[rho0, 0.0, z0]])
    step = np.array([-0.01, 0.02, 0.0])   # into the sphere and along it
    fixed = np.array([[False, False, True]])
    out = np.empty((1, 3))
    cout = np.empty(1, bool)
    old = active_set.FIXED_PROJECTION_STEPS, active_set.FIXED_PROJECTION_EVERYWHERE
    try:
        # the rule runs on the smooth surface of meshes; on the sphere (everywhere) the answer is
        # known in closed form. The module constants are read when the kernel compiles: call the
        # pure Python function
        active_set.FIXED_PROJECTION_STEPS = steps
        active_set.FIXED_PROJECTION_EVERYWHERE = True
        pen = _trial_positions_sd.py_func(pos, np.array([True]), np.zeros(1), step, 1.0, fixed, True, margs, False,
                                          -np.ones(1, np.int64), np.zeros((1, 3)), out, cout, np.zeros(1), False)
    finally:
        active_set.FIXED_PROJECTION_STEPS, active_set.FIXED_PROJECTION_EVERYWHERE = old
    return pen, out[0], cout[0], rho0, z0, margs


def test_held_axis_contact_node_lands_on_a_curved_surface():
    """A contact node held in z, stepped partly into a sphere (R = 0.1 m) at z0 = 0.05 m: the
    projection along its free axes ends on the sphere's circle at z0 (radius sqrt(R^2 - z0^2)),
    in the direction of its trial point in the xy plane, z untouched. Moving it onto the foot
    point along x and y only (the solver before) leaves it inside, and the line search then
    rejects long steps (the smooth stocking's 420 iterations)."""
    pen, p, c, rho0, z0, margs = _sphere_trial(active_set.FIXED_PROJECTION_STEPS)
    assert c and pen <= 1e-12
    assert p[2] == z0
    trial_xy = np.array([rho0 - 0.01, 0.02])
    expect = rho0 * trial_xy / np.linalg.norm(trial_xy)
    assert np.allclose(p[:2], expect, atol=1e-12)
    q = np.empty(8)
    assert abs(mold_query(margs, p, q)) <= 1e-12
    # without the Newton steps along the free normal the node stays inside by far more than the
    # line search's tolerance
    pen0, *_ = _sphere_trial(0)
    assert pen0 > 1e3 * PENETRATION_TOL


def _run(model, state, settings, max_iterations):
    """Newton iterations on state; returns (iterations, status, deepest penetration [m] after
    any iteration)."""
    s = NewtonSolver(model, newton_options(settings))
    margs = model.mold.kernel_args()
    worst = 0.0
    for it in range(max_iterations):
        rep = s.step(state, 1, e=settings.e)
        worst = max(worst, max_penetration(state.positions, margs))
        if rep.status != "ok":
            return it + 1, str(rep.status), worst
    return max_iterations, "max_iterations", worst


def test_smooth_stocking_converges_without_penetrating():
    """The stocking on the leg's smooth surface: ~420 iterations before (a held column creeping
    at alpha = 0.25, then nodes churning in and out of contact), now about 60; no node is inside
    the leg by more than 1e-9 m after any iteration."""
    scene = clothsim.load_scene(ROOT / "configs" / "garments" / "stocking.yaml", ["mold.surface=smooth"])
    from clothsim.simulation import prepare

    model, state, _ = prepare(scene)
    its, status, worst = _run(model, state, scene.solver, 150)
    assert status == "converged", (its, status)
    assert its <= 100
    assert worst <= 1e-9


def test_torso_band_on_the_smooth_scan_converges_in_60_iterations():
    """A campaign case on smpl_man's smooth surface (y = 1.08 m: 74 iterations before) converges
    to 1e-9 N within 60 iterations, never inside the body."""
    surface = "smooth"
    case = bench.Case("t", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path("smpl_man"), 1.08, surface), ("newton",))
    model, state, settings = bench._load(case, "newton", 1e-9, None)
    its, status, worst = _run(model, state, settings, 100)
    assert status == "converged", (its, status)
    assert its <= 60
    assert worst <= 1e-9
