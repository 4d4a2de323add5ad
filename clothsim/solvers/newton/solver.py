"""The Newton solver object (grid sequencing, then Newton iterations on the fine grid) and the
settings-based ``solve(model, state, settings, callback)`` wrapper.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..base import Solver, StepReport, StepStatus
from ..options import NewtonOptions, newton_options
from .iteration import NewtonLevel, _forcing
from .sequencing import grid_sequence

# Newton iterations without a 1 % gain in the best residual before the run counts as stalled
# (the active set cycling on a faceted mold, or float64's floor); the driver applies it
STALL_NEWTON = 100


class NewtonSolver(Solver):
    """Active-set Newton as a solver object: ``NewtonSolver(model, NewtonOptions(kink,
    sequencing))`` (see the package docstring for the method, its references and limitations).

    One iteration = one Newton step; the grid-sequencing stage (first step, when
    ``options.sequencing`` and the grid can be coarsened) counts as one. The driver runs one
    iteration per batch (each is a linear solve) and stops a run whose best residual has not
    gained 1 % in ``STALL_NEWTON`` iterations."""

    name = "newton"
    Options = NewtonOptions
    max_batch = 1
    stall_window = STALL_NEWTON

    def __init__(self, model, options: NewtonOptions | None = None):
        super().__init__(model, options)
        self.fine = NewtonLevel(model, kink=self.options.kink, tuning=self.options.tuning)
        # (a frictional load step starts from the previous equilibrium: no coarse grids, which
        # would not carry its frozen friction)
        self._seq_done = not self.options.sequencing or model.friction is not None
        self._v = None  # ||V||_inf [N] at (self._at_pos, self._at_contact), when known
        self._at_pos = None
        self._at_contact = None
        # None, or state -> Model: the model with the friction refreshed at the state, taken
        # before every iteration (set by clothsim.solvers.friction)
        self.refresh = None
        # why the last iteration that found no step failed, when known (the driver's message)
        self.failure = ""

    def retarget(self, model):
        """Go on with ``model``: the same lattice and mold with another frozen friction
        (Model.friction), forgetting the old model's forces."""
        self.model = model
        self.fine.model = model
        self.fine._cache = None
        self._v = None

    def _known_residual(self, state):
        """The residual [N] of the last iteration when ``state`` is still where it left it (the
        state may be another one, or moved in between, e.g. by a Control), else None."""
        if self._v is None or self._at_pos is None or not np.array_equal(self._at_pos, state.positions) \
                or not np.array_equal(self._at_contact, state.in_contact):
            return None
        return self._v

    def _remember(self, state, v):
        self._v = v
        self._at_pos = state.positions.copy()
        self._at_contact = state.in_contact.copy()

    def step(self, state, n, *, e=0.0, time_left_s=None) -> StepReport:
        res = np.empty(n)
        en = np.empty(n)
        done = 0
        status = StepStatus.OK
        while done < n:
            k, v, E, status = self._iteration(state, e, time_left_s)
            if k:
                res[done], en[done] = v, E
                done += 1
                state.iteration += 1
            if status != StepStatus.OK:
                break
        return StepReport(done, res[:done], en[:done], status)

    def _iteration(self, state, e, time_left_s):
        """One iteration: (1 or 0 iterations done, residual [N], energy [J], StepStatus)."""
        model, fine = self.model, self.fine
        if not self._seq_done:
            self._seq_done = True
            deadline = time.perf_counter() + (0.5 * time_left_s if time_left_s else 1e30)
            trial = grid_sequence(model, state, e, self.options.kink, deadline, self.options.tuning)
            if trial is not None:
                E_old = fine.energy_forces(state.positions, fine.F)
                E_new = fine.energy_forces(trial.positions, fine.F)
                v_new = fine.residual(trial.positions, trial.in_contact, fine.F)
                if math.isfinite(E_new) and math.isfinite(v_new) and E_new <= E_old:
                    state.positions[:] = trial.positions
                    state.in_contact[:] = trial.in_contact
                    self._remember(state, v_new)
                    return 1, v_new, E_new, StepStatus.CONVERGED if v_new <= e else StepStatus.OK
        if self.refresh is not None:
            # friction refreshed at the iterate (its normal forces and tangent planes frozen
            # there for this iteration: clothsim.solvers.friction)
            self.retarget(self.refresh(state))
            model = self.model
        v0 = self._known_residual(state)
        if v0 is None:
            v0 = fine.residual(state.positions, state.in_contact)
        prev_pos = state.positions.copy()
        prev_c = state.in_contact.copy()
        v, E, status = fine.iterate(state, v0, forcing=_forcing(v0, e, fine.v_prev, self.options.tuning.forcing_max))
        if status == StepStatus.DIVERGED or not math.isfinite(v) or not np.isfinite(state.positions).all() \
                or np.abs(state.positions).max() > fine.blowup:
            state.positions[:] = prev_pos
            state.in_contact[:] = prev_c
            return 0, v0, math.nan, StepStatus.DIVERGED
        if status == StepStatus.NO_PROGRESS:
            self.failure = fine.failure
            return 0, v0, math.nan, StepStatus.NO_PROGRESS
        self._remember(state, v)
        return 1, v, E, StepStatus.CONVERGED if v <= e else StepStatus.OK


def solve(model, state, settings, callback=None, history=None):
    """Relax ``state`` in place with active-set Newton under ``settings`` (a SolverSettings:
    ``newton_kink`` and ``newton_sequencing`` become the NewtonOptions, plus the driver's limits
    ``e``, ``max_iterations``, ``time_limit_s``, ``stall_iterations``); returns a SolveResult."""
    return NewtonSolver(model, newton_options(settings)).solve(state, settings, callback, history)
