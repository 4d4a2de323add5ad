"""The solver contract: what every solver is built from, what one ``step`` returns, how a run ends.

A solver is an object built from ``(model, options)`` — the Model it relaxes and its own typed,
validated options (``clothsim.solvers.options``) — with one verb, ``step(state, n)``, that performs
at most n iterations on the State in place and returns a :class:`StepReport` (in the manner of the
Newton physics engine's solver classes and of scipy.optimize's ``OptimizeResult``). Everything a
run needs around the iterations — iteration and time limits, stall detection, the history, the
progress callback, the final residual check — is the driver's (``clothsim.solvers.driver.run``),
the same for every solver; ``Solver.solve`` runs it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..defaults import SOLVER_DEFAULTS
from .driver import run
from .status import Status, StepStatus, _StrEnum  # noqa: F401  (re-exported)


def settings_default(name: str):
    """The default of ``solver.<name>`` (``clothsim.defaults``, which ``config.SolverSettings``
    reads too): the one place the solvers' defaults are kept (RunLimits and the options read it)."""
    return SOLVER_DEFAULTS[name]


@dataclass
class StepReport:
    """What one ``step`` did: ``iterations`` performed (and counted in ``state.iteration``);
    ``residuals`` [N] (iterations,) ||V||_inf (eq. 6) after each; ``energies`` [J] (iterations,)
    total potential energy after each; ``status``."""

    iterations: int
    residuals: np.ndarray
    energies: np.ndarray
    status: StepStatus = StepStatus.OK

    @property
    def residual(self) -> float:
        """||V||_inf [N] after the last iteration (nan when none was performed)."""
        return float(self.residuals[-1]) if self.iterations else math.nan


@dataclass
class RunLimits:
    """The driver's bounds, for runs not driven by a scene's ``SolverSettings`` (which has the same
    fields): e [N] convergence limit on ||V||_inf; max_iterations; time_limit_s [s] (None = none);
    stall_iterations (iterations without a 1 % gain in the best residual before the run stalls)."""

    e: float = settings_default("e")
    max_iterations: int = settings_default("max_iterations")
    time_limit_s: float | None = settings_default("time_limit_s")
    stall_iterations: int = settings_default("stall_iterations")

    def __post_init__(self):
        if not (math.isfinite(self.e) and self.e > 0):
            raise ValueError(f"e must be positive (got {self.e})")
        for k in ("max_iterations", "stall_iterations"):
            if int(getattr(self, k)) < 1:
                raise ValueError(f"{k} must be at least 1 (got {getattr(self, k)})")
        if self.time_limit_s is not None and not (self.time_limit_s > 0):
            raise ValueError(f"time_limit_s must be positive or None (got {self.time_limit_s})")


class Solver:
    """Base of every solver. Subclasses set ``name`` and ``Options`` and implement ``step``.

    Class attributes read by the driver: ``initial_batch`` (iterations of the first batch; the
    driver then sizes batches to about 50 ms), ``max_batch`` (most iterations per batch, None =
    unbounded: Newton does one, each being a linear solve), ``stall_window`` (the solver's own
    bound on the stall window in iterations, None = the run's ``stall_iterations`` only),
    ``failure`` (why the last step that found no move failed, "" when unknown: the run's message
    ends with it)."""

    name: str = ""
    Options: type = object
    initial_batch: int = 1
    max_batch: int | None = None
    stall_window: int | None = None
    failure: str = ""

    def __init__(self, model, options=None):
        if options is None:
            options = self.Options()
        if not isinstance(options, self.Options):
            raise TypeError(f"{type(self).__name__} takes {self.Options.__name__}, not {type(options).__name__}")
        self.model = model
        self.options = options

    def step(self, state, n: int, *, e: float = 0.0, time_left_s: float | None = None) -> StepReport:
        """Perform at most n iterations on ``state`` in place (advancing ``state.iteration``); stop
        early when ||V||_inf <= e [N] (status CONVERGED) or nothing can move. ``time_left_s``: the
        run's remaining wall-clock budget [s] (None = unbounded), for solvers that plan a stage."""
        raise NotImplementedError

    def solve(self, state, limits, callback=None, history=None, before_batch=None):
        """Run to equilibrium under ``limits`` (``SolverSettings`` or :class:`RunLimits`, re-read
        between batches) with the shared driver; returns a ``SolveResult``. See
        ``clothsim.solvers.driver.run`` for ``callback``, ``history`` and ``before_batch``."""
        return run(self, state, limits, callback, history, before_batch)


def empty_report(status: StepStatus = StepStatus.OK) -> StepReport:
    return StepReport(0, np.zeros(0), np.zeros(0), status)


__all__ = ["Status", "StepStatus", "StepReport", "RunLimits", "Solver", "empty_report"]

