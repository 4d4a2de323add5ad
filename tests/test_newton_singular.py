"""Exactly singular Newton systems (scipy's ``splu``: "Factor is exactly singular") never end a
run with a traceback: the direct solve answers with no step (the Levenberg shift is raised, then
the iteration reports NO_PROGRESS and the run stalls with the reason in its message, keeping its
state), and the multigrid's coarsest solve is regularised further, then replaced by its diagonal.
(The graded stocking at 20 x 42 divisions per panel died with the RuntimeError.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clothsim.config import load_scene
from clothsim.simulation import prepare
from clothsim.solvers import newton as nw
from clothsim.solvers import solve
from clothsim.solvers.newton import iteration
from clothsim.solvers.newton.linalg import multigrid
from clothsim.kernels import forces_and_energy

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _setup(*overrides, **solver):
    scene = load_scene(CONFIGS / "sphere_cap.yaml", list(overrides))
    model, state, _ = prepare(scene)
    settings = scene.solver.model_copy(update={"method": "newton", **solver})
    return model, state, settings


def _level(model, state, **kw):
    lvl = nw.NewtonLevel(model, **kw)
    pos = state.positions
    forces_and_energy(pos, *model.spring_args(), model.external_force, lvl.F)
    nw._projectors(pos, lvl.F, model.fixed_axes, state.in_contact, lvl.has_mold, lvl.margs, lvl.Pi)
    nw._assemble(pos, *model.spring_args(), lvl.kink, lvl.slot, lvl.K)
    return lvl


def test_direct_solve_of_a_system_without_stiffness_gives_no_step():
    """Every node without stiffness (K = 0) and no shift: the projected system's free blocks are
    zero and splu finds it exactly singular. The solve returns a non-finite step (which iterate
    answers with a larger Levenberg shift) instead of raising; with a shift it solves."""
    model, state, _ = _setup("fabric.divisions=[8,8]")
    lvl = _level(model, state)
    assert lvl.direct
    lvl.K[:] = 0.0
    rhs = np.ones(3 * lvl.n)
    x, _ = lvl._solve_linear(rhs, 0.0, 1e-8)
    assert not np.isfinite(x).any() and lvl.singular == 1
    x, _ = lvl._solve_linear(rhs, 2.0, 1e-8)
    assert np.isfinite(x).all()
    free = lvl.Pi.reshape(lvl.n, 9)[:, 0] == 1.0  # a free node's x row: mu x = 1
    assert np.allclose(x.reshape(-1, 3)[free, 0], 0.5)


def test_a_run_whose_systems_are_all_singular_stalls_with_the_reason(monkeypatch):
    """Every factorisation singular (splu raising as it did on the graded stocking at 20 x 42):
    the run ends stalled, its message says why, and the state is the last good one (finite,
    no node moved by a non-finite step)."""
    model, state, settings = _setup("fabric.divisions=[9,9]")  # (odd: no grid sequencing)

    def singular(*a, **k):
        raise RuntimeError("Factor is exactly singular")

    monkeypatch.setattr(iteration.sla, "splu", singular)
    start = state.positions.copy()
    res = solve(model, state, settings)
    assert res.status == "stalled" and not res.converged
    assert "exactly singular" in res.message, res.message
    assert np.array_equal(state.positions, start)


def test_multigrid_coarsest_solve_survives_a_singular_factorisation(monkeypatch):
    """The coarsest grid's LU found exactly singular: retried with a larger diagonal shift, and
    when every shift fails the diagonal stands in; the V-cycle stays a usable preconditioner
    (PCG reaches 1e-8 on a stretched sheet's projected system)."""
    model, state, _ = _setup("fabric.divisions=[30,30]")
    lvl = _level(model, state, use_multigrid=True)
    nw._project_system(lvl.indptr, lvl.indices, lvl.K, lvl.diag, lvl.Pi, 0.0, lvl.A)
    real = multigrid.sla.splu
    calls = []

    def fail_first(A, *a, **k):
        calls.append(A.diagonal().min())
        if len(calls) < 2:
            raise RuntimeError("Factor is exactly singular")
        return real(A, *a, **k)

    def always(*a, **k):
        raise RuntimeError("Factor is exactly singular")

    rng = np.random.default_rng(1)
    b = rng.normal(size=3 * lvl.n)
    for fake in (fail_first, always):
        monkeypatch.setattr(multigrid.sla, "splu", fake)
        lvl.mg.setup(lvl.indptr, lvl.indices, lvl.A, lvl.Pi)

        def mv(v, out):
            nw._bsr_matvec(lvl.indptr, lvl.indices, lvl.A, v, out)

        x, it, rel = nw._pcg(mv, lvl.mg.vcycle, b, 1e-8, 400, None)
        assert rel <= 1e-8 and np.isfinite(x).all(), (fake.__name__, it, rel)
    assert len(calls) == 2 and calls[1] > calls[0]  # the retry had the larger shift
    assert isinstance(lvl.mg.levels[-1].lu, multigrid._DiagonalSolve)
