"""Load steps with Coulomb friction between the fabric and the mold (quasi-static and
path-dependent): each step's controls (prescribed coordinates, rest scale, external force) are
applied, the step is solved by Newton with the friction frozen at its start
(``clothsim.friction.lag_friction``: normal forces and tangent planes, every contact node
anchored at the previous step's equilibrium), and solved again with the friction refreshed at
the equilibrium found until the residual with the refreshed friction (the full residual:
springs, loads and friction) is at most e. A step's solves (its first, a rescue's, a
refresh's) share ``max_iterations``. A step that fails is cut in half (both halves solved in
turn), at most ``max_cuts`` times in a row, and the result says how many were cut.
Without friction the steps are solved as ``control.solve_load_steps`` does. The switches and
constants of the schedule are a :class:`~clothsim.solvers.tuning.FrictionTuning` record.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..contact import residual_from_forces
from ..friction import elastic_forces, friction_report, lag_friction, normal_forces
from ..records import FrictionReport
from .base import Status
from .common import SolveResult, model_mold_args, residual
from .control import Control
from .driver import History
from .newton import NewtonSolver
from .options import NewtonOptions
from .tuning import FrictionTuning


def _newton(model, limits):
    """Newton for ``model`` with a SolverSettings' newton options (defaults for RunLimits)."""
    return NewtonSolver(model, NewtonOptions(kink=float(getattr(limits, "newton_kink", NewtonOptions.kink)),
                                             sequencing=bool(getattr(limits, "newton_sequencing", True))))


def _with(limits, **kw):
    """``limits`` (SolverSettings or RunLimits) with the fields ``kw`` replaced."""
    if hasattr(limits, "model_copy"):
        return limits.model_copy(update=kw)
    return dataclasses.replace(limits, **kw)


def _with_e(limits, e):
    """``limits`` with its e replaced."""
    return _with(limits, e=e)


def _frictional_step(base, state, control, limits, callback, hist, tuning: FrictionTuning):
    """One load step with friction: (converged, model with the refreshed friction, the last
    SolveResult, refreshes, report dict). With ``tuning.refresh_every_iteration`` the Newton
    solver takes the friction refreshed at every iterate; otherwise each solve keeps one frozen
    friction and stops at ``tuning.refresh_forcing`` times the residual it starts from (or e).
    Either way the step is done when the residual with the friction refreshed at its
    equilibrium is at most e. The step's solves (the first, a rescue's two, a refresh's) share
    ``limits.max_iterations``: the whole step takes at most that many Newton iterations."""
    anchor = state.positions.copy()
    m = control.apply(base, state)
    e = limits.e
    budget = _Budget(state, limits.max_iterations)
    lag = lag_friction(m, state, anchor)
    mm = dataclasses.replace(m, friction=lag)
    solver = _newton(mm, limits)
    if tuning.refresh_every_iteration:
        def refresh(st):
            return dataclasses.replace(m, friction=lag_friction(m, st, anchor))
        solver.refresh = refresh
    # the step's first solve gets ``rescue_after`` iterations: past them (stick/slip transitions
    # thinner than Newton's steps: the line search cuts, the residual wanders) it starts again
    # from the step's start with the slip eps ``eps_continuation`` times wider, and the solve
    # with the scene's eps (which decides the step) goes on from there, in what is left of the
    # step's budget (none left: the step ends out of iterations, as a plain solve would)
    rescue = tuning.rescue_after > 0 and tuning.eps_continuation > 1.0
    snap = state.copy() if rescue else None
    res = None
    for r in range(1, tuning.max_relags + 1):
        lim = limits
        if not tuning.refresh_every_iteration:
            v0, _ = residual(mm, state)
            lim = _with_e(limits, max(e, tuning.refresh_forcing * v0))
        if budget.left() < 1:
            return False, solver.model, budget.spent(res), r - 1, None
        if rescue and r == 1:
            res = solver.solve(state, _with(lim, max_iterations=min(budget.left(), tuning.rescue_after)),
                               callback, hist)
            if res.status == Status.MAX_ITERATIONS and budget.left() >= 1:
                res = _rescue(m, state, snap, anchor, lim, callback, hist, tuning, solver, budget)
        else:
            res = solver.solve(state, _with(lim, max_iterations=budget.left()), callback, hist)
        if not res.converged:
            return False, solver.model, res, r, None
        new = lag_friction(m, state, anchor)
        m2 = dataclasses.replace(m, friction=new)
        v, _ = residual(m2, state)
        if v <= e and res.residual <= e:
            rep = friction_report(m, new, state.positions, e)
            return True, m2, dataclasses.replace(res, residual=float(v)), r, rep
        mm = m2
        solver.retarget(mm)
    return False, mm, dataclasses.replace(res, converged=False, status=Status.STALLED,
                                          message=f"friction not settled after {tuning.max_relags} refreshes"), \
        tuning.max_relags, None


class _Budget:
    """A load step's Newton iterations: ``total`` from the state's iteration count at its start."""

    def __init__(self, state, total):
        self.state, self.start, self.total = state, int(state.iteration), int(total)

    def left(self) -> int:
        return self.total - (int(self.state.iteration) - self.start)

    def spent(self, res):
        """``res`` (the step's last SolveResult) as a step that ran out of its iterations."""
        return dataclasses.replace(res, converged=False, status=Status.MAX_ITERATIONS,
                                   message=f"stopped after {self.total} iterations in the load step without converging")


def _rescue(m, state, snap, anchor, limits, callback, hist, tuning: FrictionTuning, solver, budget):
    """A load step's first solve again from the step's start ``snap``: with the slip eps
    ``tuning.eps_continuation`` times wider, then (from its equilibrium, or from the start if it
    fails) with the scene's eps on ``solver`` (its friction refreshed at the state); both within
    what is left of the step's iteration ``budget`` (a _Budget)."""
    c = float(tuning.eps_continuation)
    state.positions[:] = snap.positions
    state.in_contact[:] = snap.in_contact
    wide = _newton(dataclasses.replace(m, friction=lag_friction(m, state, anchor, c)), limits)
    if tuning.refresh_every_iteration:
        wide.refresh = lambda st: dataclasses.replace(m, friction=lag_friction(m, st, anchor, c))
    res = wide.solve(state, _with(limits, max_iterations=budget.left()), callback, hist)
    if not res.converged:
        state.positions[:] = snap.positions
        state.in_contact[:] = snap.in_contact
    if budget.left() < 1:
        return budget.spent(res)
    solver.retarget(dataclasses.replace(m, friction=lag_friction(m, state, anchor)))
    return solver.solve(state, _with(limits, max_iterations=budget.left()), callback, hist)


def solve_steps(model, state, controls, limits, callback=None, history=None, make_solver=None,
                model_scale=(1.0, 1.0), tuning: FrictionTuning = FrictionTuning(), model_force=None):
    """Solve ``state`` in place through the load steps ``controls`` (Controls, from the model's
    current prescribed positions), with friction when the model has any (``Model.has_friction``; ``limits``: a
    SolverSettings or RunLimits; the Newton solver's options from it when it is a SolverSettings);
    ``make_solver(model)`` solves the frictionless steps (default: Newton); ``model_scale``: the rest
    scale the state is at before the first control (a halved first step ramps from it); ``model_force``:
    likewise the external force [N] (N, 3) before the first control (None: the model's own); ``tuning``: the
    schedule's switches (:class:`~clothsim.solvers.tuning.FrictionTuning`). Returns (the last step's Model, a
    SolveResult over all steps whose ``friction`` holds the steps' report: load steps, cuts,
    refreshes, and at the last step the stick and slip counts and the cone violation)."""
    hist = history if history is not None else History()
    if make_solver is None:
        def make_solver(m):
            return _newton(m, limits)
    t0 = time.perf_counter()
    it0 = state.iteration
    base = dataclasses.replace(model, friction=None)
    frictional = model.has_friction
    queue = [(c.prescribed_positions, c.rest_scale, c.external_force) for c in controls]
    prev = model.prescribed_positions
    prev_scale = prev_force = None
    fixed = model.fixed_axes
    steps, cuts, relags_total = [], 0, 0
    res, m, rep = None, model, None
    cut_run = 0
    while queue:
        target, scale, force = queue.pop(0)
        control = Control(target, scale, force)
        snap = state.copy()
        ts = time.perf_counter()
        its = state.iteration
        if frictional:
            ok, m_new, res, relags, rep_new = _frictional_step(base, state, control, limits, callback,
                                                              hist, tuning)
        else:
            m_new = control.apply(base, state)
            res = make_solver(m_new).solve(state, limits, callback, hist)
            ok, relags, rep_new = res.converged, 1, None
        relags_total += relags
        if ok:
            m, rep, prev, prev_scale, prev_force, cut_run = m_new, rep_new, target, scale, force, 0
            # the step's Newton iterations over all its solves (a refresh's solve counts too)
            steps.append({"iterations": int(state.iteration - its), "refreshes": int(relags),
                          "seconds": time.perf_counter() - ts, **(rep_new or {}),
                          **({} if scale is None else {"rest_scale": [float(v) for v in scale]}),
                          **({} if force is None else {"external_force_n": [float(v) for v in force.sum(axis=0)]})})
            continue
        m = m_new
        if res.status not in (Status.DIVERGED, Status.STALLED):
            break  # stopped, out of iterations or time: no cut
        s_from = prev_scale if prev_scale is not None else model_scale
        f_from = prev_force if prev_force is not None else model.external_force if model_force is None else model_force
        moved = not np.array_equal(prev[fixed], target[fixed]) or (scale is not None and tuple(s_from) != tuple(scale)) \
            or (force is not None and not np.array_equal(f_from, force))
        if not moved or cut_run >= tuning.max_cuts:
            break
        # cut the failing step in half and go on from where it started
        state.positions[:] = snap.positions
        state.in_contact[:] = snap.in_contact
        half = np.where(fixed, 0.5 * (prev + target), target)
        half_scale = None if scale is None else tuple(0.5 * (np.asarray(s_from) + np.asarray(scale)))
        half_force = None if force is None else 0.5 * (np.asarray(f_from, float) + force)
        queue[:0] = [(half, half_scale, half_force), (target, scale, force)]
        cuts += 1
        cut_run += 1
    done = len(steps)
    converged = res is not None and res.converged and not queue
    report = {"mu": float(model.friction_mu), "load_steps": len(controls), "steps_solved": done,
              **({} if model.friction_mu_nodes is None else {"mu_max": float(model.friction_mu_nodes.max())}),
              "cuts": cuts, "refreshes": relags_total, "steps": steps}
    if rep is not None:
        report.update(rep)
    report = FrictionReport(**report).to_dict()  # the fields summary.json and sweeps read
    msg = res.message if res is not None else "no load step"
    if cuts:
        msg += f"; {cuts} load step(s) cut in half"
    if not converged and frictional and res is not None and res.status == Status.DIVERGED:
        msg += " (with friction: no static equilibrium held the load, the sheet slid away)"
    out = SolveResult(
        converged=converged, status=res.status if res is not None else Status.STALLED,
        message=f"{done} load steps: {msg}" if converged else f"load step {done + 1} failed: {msg}",
        iterations=state.iteration - it0, residual=res.residual, relative_residual=res.relative_residual,
        energy=res.energy, contact_count=int(state.in_contact.sum()), wall_time_s=time.perf_counter() - t0,
        method=res.method, history=hist, best_residual=res.best_residual, friction=report)
    return m, out


def coulomb_residual(model, state) -> float:
    """||V||_inf [N] of ``state`` with the friction Coulomb's law allows, whatever the path: at
    every contact node without a constrained axis the mold takes, besides its pressing normal
    force f_n (:func:`normal_forces`), a tangential force of up to mu f_n against the springs',
    seams' and loads' tangential resultant; what is left is judged as ``common.residual``
    judges it. The residual of a frictional equilibrium without the load step's anchor (the
    lagged friction needs it; a converged step's friction lies in the cone, so this is at most
    the solver's residual). With mu = 0 it is the frictionless residual."""
    F = elastic_forces(model, state.positions)
    if model.has_friction:
        nodes, nrm, lam = normal_forces(model, state)
        mu = model.friction_mu_of(nodes)
        f = F[nodes]
        ft = f - np.einsum("ij,ij->i", f, nrm)[:, None] * nrm
        mag = np.linalg.norm(ft, axis=1)
        take = np.divide(np.minimum(mag, mu * lam), mag, out=np.zeros_like(mag), where=mag > 0)
        F[nodes] = f - take[:, None] * ft
    has_mold, margs = model_mold_args(model)
    return float(residual_from_forces(state.positions, F, model.fixed_axes, state.in_contact, has_mold, margs,
                                      np.empty(model.node_count)))
