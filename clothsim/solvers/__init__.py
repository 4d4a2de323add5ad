"""Solvers: one module per method, one signature ``solve(model, state, settings, callback=None)``.

``auto`` picks the fastest method available for the scene (see :func:`pick_method`).
"""

from __future__ import annotations

from .common import Progress, SolveResult, STATUSES, residual


def pick_method(model, settings) -> str:
    """The method ``auto`` runs: ``newton`` when it is available, else ``paper``."""
    if settings.method != "auto":
        return settings.method
    try:
        from . import newton  # noqa: F401
    except ImportError:
        return "paper"
    return "newton"


def solve(model, state, settings, callback=None) -> SolveResult:
    """Advance ``state`` in place to equilibrium with ``settings.method``."""
    method = pick_method(model, settings)
    if method == "paper":
        from .paper import solve as run
    elif method == "newton":
        from .newton import solve as run
    else:  # validated by config, so this is a programming error
        raise ValueError(f"unknown solver method {method!r}")
    return run(model, state, settings, callback)


__all__ = ["Progress", "SolveResult", "STATUSES", "residual", "solve", "pick_method"]
