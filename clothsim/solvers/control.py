"""Controls: what is prescribed for one load step, so that a load can be applied in steps.

A :class:`Control` holds the prescribed positions [m] (N, 3) of the constrained coordinates (the
``fixed_axes`` of the Model) for one load step. Applied before a solve it moves those coordinates
of the State there and returns the Model with its ``prescribed_positions`` replaced; the other
coordinates keep their values (the previous step's equilibrium is the next one's start).
:func:`load_steps` interpolates controls linearly from initial prescribed positions to final ones;
:func:`solve_load_steps` solves each in turn. Path-dependent physics (friction) will need the
path; for the present path-independent model the last step's equilibrium is the one-step one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Control:
    """prescribed_positions [m] (N, 3): the values of the model's constrained coordinates
    (``Model.fixed_axes``) for one load step; entries of free coordinates are ignored."""

    prescribed_positions: np.ndarray

    def __post_init__(self):
        p = np.ascontiguousarray(self.prescribed_positions, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"Control.prescribed_positions must have shape (N, 3) (got {p.shape})")
        object.__setattr__(self, "prescribed_positions", p)

    def apply(self, model, state):
        """Move the constrained coordinates of ``state`` (in place) to this control's values and
        return the Model with ``prescribed_positions`` replaced (Model is frozen)."""
        p = self.prescribed_positions
        if p.shape != (model.node_count, 3):
            raise ValueError(f"Control for {p.shape[0]} nodes applied to a model of {model.node_count}")
        fixed = model.fixed_axes
        if not np.all(np.isfinite(p[fixed])):
            raise ValueError("Control.prescribed_positions has non-finite constrained coordinates")
        state.positions[fixed] = p[fixed]
        return dataclasses.replace(model, prescribed_positions=p.copy())


def load_steps(initial: np.ndarray, final: np.ndarray, n: int) -> list[Control]:
    """n controls whose prescribed positions [m] (N, 3) go linearly from ``initial`` (excluded)
    to ``final`` (the last control, exactly): step k of n prescribes initial + k/n (final - initial)."""
    if int(n) != n or n < 1:
        raise ValueError(f"load_steps needs n >= 1 (got {n})")
    a = np.asarray(initial, float)
    b = np.asarray(final, float)
    if a.shape != b.shape:
        raise ValueError(f"initial {a.shape} and final {b.shape} prescribed positions differ in shape")
    return [Control(b.copy() if k == n else a + (k / n) * (b - a)) for k in range(1, int(n) + 1)]


def solve_load_steps(make_solver, model, state, controls, limits, callback=None, history=None):
    """Solve ``state`` in place through the load steps ``controls``: for each, apply it and run
    ``make_solver(model)`` (a solver for the model with that step's prescribed positions) under
    ``limits`` to equilibrium. Returns (the last step's Model, [SolveResult per step]); a step that
    does not converge ends the sequence. ``history`` (a History, optional) records every step."""
    from .driver import History

    hist = history if history is not None else History()
    results = []
    for c in controls:
        model = c.apply(model, state)
        res = make_solver(model).solve(state, limits, callback, hist)
        results.append(res)
        if not res.converged:
            break
    return model, results
