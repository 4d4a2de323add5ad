"""Solvers: one module per method, one signature ``solve(model, state, settings, callback=None)``.

``auto`` picks the fastest method available for the scene (see :func:`pick_method`) and falls
back on the paper's relaxation where it stalls (see :func:`solve`).
"""

from __future__ import annotations

import numpy as np

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


def _module(method: str):
    if method == "paper":
        from . import paper as mod
    elif method == "newton":
        from . import newton as mod
    else:  # validated by config, so this is a programming error
        raise ValueError(f"unknown solver method {method!r}")
    return mod


def solve(model, state, settings, callback=None) -> SolveResult:
    """Advance ``state`` in place to equilibrium with ``settings.method``.

    ``auto`` runs ``newton``; if Newton stalls (no further progress, e.g. nodes sliding over many
    small mold facets), it hands the state to the paper's relaxation for the rest of the iteration
    and time budget — the robust method finishes what the fast one could not. The result then says
    ``method = "newton+paper"`` and its history covers both phases."""
    method = pick_method(model, settings)
    res = _module(method).solve(model, state, settings, callback)
    if settings.method != "auto" or method != "newton" or res.status != "stalled":
        return res
    left = settings.max_iterations - res.iterations
    limit = settings.time_limit_s
    if left <= 0 or (limit is not None and res.wall_time_s >= limit):
        return res
    rest = settings.model_copy(update={
        "max_iterations": left,
        "time_limit_s": None if limit is None else max(limit - res.wall_time_s, 1e-3),
    })
    res2 = _module("paper").solve(model, state, rest, callback)
    h1, h2 = res.history, res2.history
    history = {
        "iteration": np.concatenate([h1["iteration"], h2["iteration"]]),
        "residual": np.concatenate([h1["residual"], h2["residual"]]),
        "energy": np.concatenate([h1["energy"], h2["energy"]]),
        "time": np.concatenate([h1["time"], h2["time"] + res.wall_time_s]),
    }
    return SolveResult(
        converged=res2.converged, status=res2.status,
        message=f"newton stalled at {res.residual:.3e} N after {res.iterations} iterations; "
                f"paper relaxation then: {res2.message}",
        iterations=res.iterations + res2.iterations, residual=res2.residual,
        relative_residual=res2.relative_residual, energy=res2.energy, contact_count=res2.contact_count,
        wall_time_s=res.wall_time_s + res2.wall_time_s, method="newton+paper", history=history,
        best_residual=min(res.best_residual, res2.best_residual))


__all__ = ["Progress", "SolveResult", "STATUSES", "residual", "solve", "pick_method"]
