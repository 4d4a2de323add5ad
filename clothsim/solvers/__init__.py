"""Solvers: objects with one contract (``clothsim.solvers.base``), run by one driver.

A solver is built from ``(model, options)``: ``PaperSolver(model, PaperOptions(C, max_retries))``,
``NewtonSolver(model, NewtonOptions(kink, sequencing))``, ``AutoSolver(model, AutoOptions(...))``
(Newton, then the paper's relaxation on a stall). ``solver.step(state, n)`` performs at most n
iterations and returns a ``StepReport``; ``solver.solve(state, limits, callback)`` runs the driver
(limits, stall detection, history) and returns a ``SolveResult`` whose ``status`` is a ``Status``.

For scenes, :func:`solve` keeps the settings-based signature ``solve(model, state, settings,
callback=None)``: it maps ``settings.method`` and the scene's solver keys onto a solver and its
options (``options.options_from_settings``, the one place) and runs it.
"""

from __future__ import annotations

from .auto import AutoSolver
from .base import RunLimits, Solver, Status, StepReport, StepStatus
from .common import Progress, SolveResult, STATUSES, residual
from .control import Control, load_steps, solve_load_steps
from .driver import History, run
from .newton import NewtonSolver
from .options import AutoOptions, NewtonOptions, PaperOptions, live_options, options_from_settings
from .paper import PaperSolver


def pick_method(model, settings) -> str:
    """The method ``auto`` runs: ``newton`` (always available: scipy is a dependency)."""
    if settings.method != "auto":
        return settings.method
    return "newton"


def solver_class(method: str) -> type:
    """The Solver class of ``method`` ("paper", "newton" or "auto")."""
    if method == "paper":
        cls = PaperSolver
    elif method == "newton":
        cls = NewtonSolver
    elif method == "auto":
        cls = AutoSolver
    else:  # validated by config, so this is a programming error
        raise ValueError(f"unknown solver method {method!r}")
    return cls


def make_solver(model, settings) -> Solver:
    """The solver a scene's ``SolverSettings`` asks for, with its typed options: ``auto`` is the
    composite (Newton, rescued by the paper's relaxation) when Newton is available, else the
    paper's relaxation."""
    method = settings.method
    if method == "auto" and pick_method(model, settings) != "newton":
        method = "paper"
    return solver_class(method)(model, options_from_settings(method, settings))


def solve(model, state, settings, callback=None, history: History | None = None) -> SolveResult:
    """Advance ``state`` in place to equilibrium with ``settings.method`` (see :func:`make_solver`).

    ``settings`` (a SolverSettings) is re-read between batches: e, max_iterations and the paper's
    C and max_retries reach a running solve. ``history``: a History to append to (Simulation keeps
    one across its runs). ``auto`` runs Newton; if Newton stalls, the paper's relaxation continues
    for the rest of the budget and the result says ``method = "newton+paper"``."""
    solver = make_solver(model, settings)
    return solver.solve(state, settings, callback, history, before_batch=live_options(settings))


__all__ = ["Progress", "SolveResult", "STATUSES", "Status", "StepStatus", "StepReport", "RunLimits",
           "Solver", "History", "run", "PaperSolver", "NewtonSolver", "AutoSolver", "PaperOptions",
           "NewtonOptions", "AutoOptions", "options_from_settings", "Control", "load_steps",
           "solve_load_steps", "residual", "solve", "pick_method", "make_solver", "solver_class"]

