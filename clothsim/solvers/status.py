"""How a run and one step end: :class:`Status` and :class:`StepStatus` (str-valued enums). A leaf
module: the base, the driver and the shared helpers all read it."""

from __future__ import annotations

from enum import Enum


class _StrEnum(str, Enum):
    """A str-valued enum whose members compare, hash, format and serialise (json) as their value."""

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


class Status(_StrEnum):
    """How a run ended (``SolveResult.status``, ``summary.json``'s ``status``)."""

    CONVERGED = "converged"  # ||V||_inf <= e
    MAX_ITERATIONS = "max_iterations"  # the iteration budget ran out
    TIME_LIMIT = "time_limit"  # the wall-clock budget ran out
    STALLED = "stalled"  # no 1 % gain in the best residual over the stall window, or no move possible
    DIVERGED = "diverged"  # non-finite or blown-up positions (the last finite state is kept)
    STOPPED = "stopped"  # the callback asked to stop


class StepStatus(_StrEnum):
    """How one ``Solver.step`` ended."""

    OK = "ok"  # performed the iterations asked for (or stopped early for no reason below)
    CONVERGED = "converged"  # reached ||V||_inf <= e within the step
    DIVERGED = "diverged"  # the last iteration blew up; the state was restored to the last finite one
    NO_PROGRESS = "no_progress"  # no iteration could lower the energy or the residual; state unchanged
