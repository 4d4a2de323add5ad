"""``auto``: a composite solver — Newton, and on a stall the paper's relaxation (its rescue).

Newton is the fastest method on every measured scene, but it can stall (no further progress,
e.g. nodes sliding over many small mold facets); the paper's relaxation then finishes from the
same state within the rest of the iteration and time budget. Both phases append to one history
(contiguous iteration numbers); the result says ``method = "newton+paper"``.
"""

from __future__ import annotations

import dataclasses

from .base import Solver, Status
from .common import SolveResult
from .driver import History
from .newton import NewtonSolver
from .options import AutoOptions
from .paper import PaperSolver


def _with(limits, **kw):
    """A copy of limits (SolverSettings or RunLimits) with some fields replaced."""
    if hasattr(limits, "model_copy"):
        return limits.model_copy(update=kw)
    return dataclasses.replace(limits, **kw)


class AutoSolver(Solver):
    """``AutoSolver(model, AutoOptions(newton=NewtonOptions(...), paper=PaperOptions(...)))``.

    ``step`` advances the current phase's solver (Newton until a run hands over to the paper's
    relaxation); ``solve`` runs the composite: Newton under the driver, then — only when it
    stalled and budget is left — the paper's relaxation with the remaining iterations and time."""

    name = "auto"
    Options = AutoOptions

    def __init__(self, model, options: AutoOptions | None = None):
        super().__init__(model, options)

        self.newton = NewtonSolver(model, self.options.newton)
        self._rescue = None
        self.current = self.newton

    @property
    def rescue(self):
        """The paper's relaxation (built on first use)."""
        if self._rescue is None:
            self._rescue = PaperSolver(self.model, self.options.paper)
        return self._rescue

    @property
    def max_batch(self):
        return self.current.max_batch

    @property
    def stall_window(self):
        return self.current.stall_window

    def step(self, state, n, *, e=0.0, time_left_s=None):
        return self.current.step(state, n, e=e, time_left_s=time_left_s)

    def solve(self, state, limits, callback=None, history=None, before_batch=None) -> SolveResult:
        hist = history if history is not None else History()
        self.current = self.newton
        res = self.newton.solve(state, limits, callback, hist)
        if res.status != Status.STALLED:
            return res
        left = limits.max_iterations - res.iterations
        limit = limits.time_limit_s
        if left <= 0 or (limit is not None and res.wall_time_s >= limit):
            return res
        rest = _with(limits, max_iterations=left,
                     time_limit_s=None if limit is None else max(limit - res.wall_time_s, 1e-3))
        self.current = self.rescue
        res2 = self.rescue.solve(state, rest, callback, hist, before_batch)
        return SolveResult(
            converged=res2.converged, status=res2.status,
            message=f"newton stalled at {res.residual:.3e} N after {res.iterations} iterations; "
                    f"paper relaxation then: {res2.message}",
            iterations=res.iterations + res2.iterations, residual=res2.residual,
            relative_residual=res2.relative_residual, energy=res2.energy, contact_count=res2.contact_count,
            wall_time_s=res.wall_time_s + res2.wall_time_s, method="newton+paper", history=hist,
            best_residual=min(res.best_residual, res2.best_residual))
