"""The Newton solver's entry point: ``solve(model, state, settings, callback)`` (grid sequencing,
then Newton iterations on the fine grid under the shared driver).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..common import Driver
from .iteration import NewtonLevel, _forcing
from .sequencing import grid_sequence

# Newton iterations without a 1 % gain in the best residual before the run counts as stalled
STALL_NEWTON = 100


def solve(model, state, settings, callback=None):
    """Relax ``state`` in place with active-set Newton (see the package docstring).

    Options (``SolverSettings``): ``newton_kink`` (stiffness used at and below strain 0 on
    tension-only springs, as a fraction of the table's first slope; default 1),
    ``newton_sequencing`` (solve coarser grids first; default True), plus the common ``e``,
    ``max_iterations`` and ``time_limit_s``. One recorded iteration = one Newton step (the
    grid-sequencing stage counts as one)."""
    kink = float(getattr(settings, "newton_kink", 1e-3))
    seq = bool(getattr(settings, "newton_sequencing", True))
    fine = NewtonLevel(model, kink=kink)
    drv = Driver(model, state, settings, callback, "newton")
    holder = {"v": None, "seq_done": not seq, "best": math.inf, "since": 0}

    def advance(n):
        if not holder["seq_done"]:
            holder["seq_done"] = True
            t_lim = settings.time_limit_s
            deadline = time.perf_counter() + (0.5 * t_lim if t_lim else 1e30)
            trial = grid_sequence(model, state, settings, kink, deadline)
            if trial is not None:
                E_old = fine.energy_forces(state.positions, fine.F)
                E_new = fine.energy_forces(trial.positions, fine.F)
                v_new = fine.residual(trial.positions, trial.in_contact, fine.F)
                if math.isfinite(E_new) and math.isfinite(v_new) and E_new <= E_old:
                    state.positions[:] = trial.positions
                    state.in_contact[:] = trial.in_contact
                    holder["v"] = v_new
                    drv.record(np.array([v_new]), np.array([E_new]))
                    return 1, 1 if v_new <= settings.e else 0
        if holder["v"] is None:
            holder["v"] = fine.residual(state.positions, state.in_contact)
        v0 = holder["v"]
        prev_pos = state.positions.copy()
        prev_c = state.in_contact.copy()
        v, E, flag = fine.iterate(state, v0, forcing=_forcing(v0, settings.e))
        if flag == 2 or not math.isfinite(v) or not np.isfinite(state.positions).all() \
                or np.abs(state.positions).max() > fine.blowup:
            state.positions[:] = prev_pos
            state.in_contact[:] = prev_c
            return 0, 2
        if flag == 3:
            return 0, 3
        holder["v"] = v
        drv.record(np.array([v]), np.array([E]))
        if v <= settings.e:
            return 1, 1
        # stagnation: no 1 % gain in the best residual over STALL_NEWTON iterations (the
        # active set cycling on a faceted mold, or float64's floor): stop as stalled
        if v < 0.99 * holder["best"]:
            holder["best"] = v
            holder["since"] = 0
        else:
            holder["since"] += 1
            if holder["since"] >= STALL_NEWTON:
                return 1, 3
        return 1, 0

    return drv.run(advance)
