"""Each solver's own typed, validated options, and the one place where a scene's ``solver:``
settings are mapped onto them.

The scene file keeps its flat keys (``solver.C``, ``solver.max_retries``, ``solver.newton_kink``,
``solver.newton_sequencing``; ``config.SolverSettings`` validates them as before):
:func:`options_from_settings` is the only reader of those keys below the scene, so no solver reads
``SolverSettings`` (or reaches for a field through ``getattr``).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from .base import settings_default
from .tuning import NewtonTuning


def _real(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _integer(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


@dataclass(frozen=True)
class PaperOptions:
    """The paper's relaxation (Garcia et al. 2007, sec. 3.2): C, the step divisor of eq. 4
    (> 1; also the factor a rejected step is divided by); max_retries (>= 1), the retries per
    node before it stays where it is."""

    C: float = settings_default("C")
    max_retries: int = settings_default("max_retries")

    def __post_init__(self):
        if not (_real(self.C) and self.C > 1.0):
            raise ValueError(f"PaperOptions.C must be a finite number greater than 1 (got {self.C!r})")
        if not (_integer(self.max_retries) and self.max_retries >= 1):
            raise ValueError(f"PaperOptions.max_retries must be an integer of at least 1 (got {self.max_retries!r})")
        object.__setattr__(self, "C", float(self.C))
        object.__setattr__(self, "max_retries", int(self.max_retries))


@dataclass(frozen=True)
class NewtonOptions:
    """Active-set Newton: kink, the stiffness used at and below strain 0 on tension-only springs as a
    fraction of the table's first slope (0 to 1000; default 1e-3: regularises the singular Hessian
    of slack springs, shapes the search direction only, never the forces); sequencing, whether to
    solve coarser grids first (grid sequencing; default True); tuning, the solver's switches and
    constants (``tuning.NewtonTuning``; its defaults are the solver's behaviour)."""

    kink: float = settings_default("newton_kink")
    sequencing: bool = settings_default("newton_sequencing")
    tuning: NewtonTuning = NewtonTuning()

    def __post_init__(self):
        if not (_real(self.kink) and 0.0 <= self.kink <= 1e3):
            raise ValueError(f"NewtonOptions.kink must be a number in [0, 1000] (got {self.kink!r})")
        if not isinstance(self.sequencing, (bool, np.bool_)):
            raise ValueError(f"NewtonOptions.sequencing must be true or false (got {self.sequencing!r})")
        if not isinstance(self.tuning, NewtonTuning):
            raise ValueError(f"NewtonOptions.tuning must be a NewtonTuning (got {self.tuning!r})")
        object.__setattr__(self, "kink", float(self.kink))
        object.__setattr__(self, "sequencing", bool(self.sequencing))


@dataclass(frozen=True)
class AutoOptions:
    """``auto``: Newton with ``newton``'s options, and on a stall the paper's relaxation with
    ``paper``'s for the rest of the budget."""

    newton: NewtonOptions = NewtonOptions()
    paper: PaperOptions = PaperOptions()

    def __post_init__(self):
        if not isinstance(self.newton, NewtonOptions) or not isinstance(self.paper, PaperOptions):
            raise ValueError("AutoOptions takes a NewtonOptions and a PaperOptions")


def paper_options(settings) -> PaperOptions:
    """``solver.C``, ``solver.max_retries`` -> PaperOptions."""
    return PaperOptions(C=float(settings.C), max_retries=int(settings.max_retries))


def newton_options(settings) -> NewtonOptions:
    """``solver.newton_kink``, ``solver.newton_sequencing`` -> NewtonOptions."""
    return NewtonOptions(kink=float(settings.newton_kink), sequencing=bool(settings.newton_sequencing))


def options_from_settings(method: str, settings):
    """The typed options of solver ``method`` ("paper", "newton" or "auto") from a scene's
    ``SolverSettings``."""
    if method == "paper":
        return paper_options(settings)
    if method == "newton":
        return newton_options(settings)
    if method == "auto":
        return AutoOptions(newton=newton_options(settings), paper=paper_options(settings))
    raise ValueError(f"unknown solver method {method!r}")


def live_options(settings):
    """A driver ``before_batch`` hook: the options a GUI may edit during a run (the paper's C and
    max_retries, edited in place in ``settings`` by ``Simulation.set_solver``) are re-read from
    ``settings`` into a running paper relaxation (alone or as auto's rescue). Newton's options
    shape the structures it built at the start and are not live."""

    def sync(solver):
        if isinstance(solver.options, PaperOptions):
            new = paper_options(settings)
            if new != solver.options:
                solver.options = new

    return sync


__all__ = ["PaperOptions", "NewtonOptions", "NewtonTuning", "AutoOptions", "options_from_settings", "paper_options",
           "newton_options", "live_options"]
