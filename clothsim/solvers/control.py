"""Controls: what is prescribed for one load step, so that a load can be applied in steps.

A :class:`Control` holds the prescribed positions [m] (N, 3) of the constrained coordinates (the
``fixed_axes`` of the Model) for one load step. Applied before a solve it moves those coordinates
of the State there and returns the Model with its ``prescribed_positions`` replaced; the other
coordinates keep their values (the previous step's equilibrium is the next one's start).
:func:`load_steps` interpolates controls linearly from initial prescribed positions to final ones;
:func:`solve_load_steps` solves each in turn. With friction the answer depends on the path
(clothsim.solvers.friction.solve_steps); without it the last step's equilibrium is the one-step one.

A Control may also carry a garment-level rest scale (warp, weft): the pattern's size relative to
its design, as a stocking is pulled on wider than it is cut and relaxed onto the leg
(:func:`scale_rest`; a stage's ``rest_scale``), and the external force [N] (N, 3) on the nodes
(``Model.external_force``: gravity), so that a stage's loads are ramped as its displacements are.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..model import SpringFamily
from .driver import History


@dataclass(frozen=True)
class Control:
    """prescribed_positions [m] (N, 3): the values of the model's constrained coordinates
    (``Model.fixed_axes``) for one load step; entries of free coordinates are ignored."""

    prescribed_positions: np.ndarray
    # the pattern's size relative to its design along (warp, weft); None: the model's own
    rest_scale: tuple | None = None
    # the external force [N] (N, 3) on the nodes (Model.external_force); None: the model's own
    external_force: np.ndarray | None = None

    def __post_init__(self):
        p = np.ascontiguousarray(self.prescribed_positions, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"Control.prescribed_positions must have shape (N, 3) (got {p.shape})")
        object.__setattr__(self, "prescribed_positions", p)
        if self.external_force is not None:
            f = np.ascontiguousarray(self.external_force, dtype=float)
            if f.shape != p.shape or not np.all(np.isfinite(f)):
                raise ValueError(f"Control.external_force must be finite with the shape of the prescribed "
                                 f"positions {p.shape} (got {f.shape})")
            object.__setattr__(self, "external_force", f)
        if self.rest_scale is not None:
            sc = tuple(float(v) for v in np.broadcast_to(np.asarray(self.rest_scale, float), (2,)))
            if not all(np.isfinite(v) and v > 0 for v in sc):
                raise ValueError(f"Control.rest_scale must be positive (got {sc})")
            object.__setattr__(self, "rest_scale", sc)

    def apply(self, model, state):
        """Move the constrained coordinates of ``state`` (in place) to this control's values and
        return the Model with ``prescribed_positions`` replaced (Model is frozen), its rest
        lengths scaled and its ``external_force`` replaced when the control carries them."""
        p = self.prescribed_positions
        if p.shape != (model.node_count, 3):
            raise ValueError(f"Control for {p.shape[0]} nodes applied to a model of {model.node_count}")
        fixed = model.fixed_axes
        if not np.all(np.isfinite(p[fixed])):
            raise ValueError("Control.prescribed_positions has non-finite constrained coordinates")
        state.positions[fixed] = p[fixed]
        out = dataclasses.replace(model, prescribed_positions=p.copy())
        if self.external_force is not None:
            out = dataclasses.replace(out, external_force=self.external_force.copy())
        return out if self.rest_scale is None else scale_rest(out, self.rest_scale)


def scale_rest(model, scale):
    """``model`` with its pattern scaled by ``scale`` = (s_warp, s_weft) from the design (the
    model's own rest lengths and widths): every warp spring (and warp bending spring) is
    s_warp times as long at rest and s_weft times as wide, every weft spring the reverse, a shear
    diagonal as long as the scaled cell's diagonal with its rest area share scaled by
    s_warp s_weft; seams are unchanged (zero-length joins). A spring's strain is then
    L / (s L0) - 1 and its force the table's tension at that strain times its scaled width.
    (1, 1) returns ``model`` itself (bit for bit the design)."""
    su, sv = (float(v) for v in np.broadcast_to(np.asarray(scale, float), (2,)))
    if su == 1.0 and sv == 1.0:
        return model
    fam = model.spring_family
    rest = model.spring_rest_length.copy()
    width = model.spring_width.copy()
    F = SpringFamily
    for fams, along, across in (((F.WARP, F.BEND_WARP), su, sv), ((F.WEFT, F.BEND_WEFT), sv, su)):
        k = np.isin(fam, fams)
        rest[k] *= along
        width[k] *= across
    k = fam == F.SHEAR
    if k.any():
        du, dv = (float(v) for v in model.spacing)
        f = np.hypot(su * du, sv * dv) / np.hypot(du, dv) if du > 0 and dv > 0 else np.sqrt(su * sv)
        rest[k] *= f
        width[k] *= su * sv / f
    return dataclasses.replace(model, spring_rest_length=rest, spring_width=width)


def load_steps(initial: np.ndarray, final: np.ndarray, n: int, scales=None, forces=None) -> list[Control]:
    """n controls whose prescribed positions [m] (N, 3) go linearly from ``initial`` (excluded)
    to ``final`` (the last control, exactly): step k of n prescribes initial + k/n (final - initial).
    ``scales`` = (from, to), each (s_warp, s_weft): the rest scale ramped the same way (None: none);
    ``forces`` = (from, to), each (N, 3) [N]: the external force ramped the same way (None: the
    model's own in every step)."""
    if int(n) != n or n < 1:
        raise ValueError(f"load_steps needs n >= 1 (got {n})")
    n = int(n)
    a = np.asarray(initial, float)
    b = np.asarray(final, float)
    if a.shape != b.shape:
        raise ValueError(f"initial {a.shape} and final {b.shape} prescribed positions differ in shape")

    def ramp(lo, hi, k):
        return hi.copy() if k == n else lo + (k / n) * (hi - lo)

    s0 = s1 = f0 = f1 = None
    if scales is not None:
        s0, s1 = (np.broadcast_to(np.asarray(v, float), (2,)) for v in scales)
    if forces is not None:
        f0, f1 = (np.asarray(v, float) for v in forces)
        if f0.shape != a.shape or f1.shape != a.shape:
            raise ValueError(f"external forces {f0.shape} -> {f1.shape} do not match the prescribed positions {a.shape}")
    return [Control(ramp(a, b, k), None if s0 is None else tuple(ramp(s0, s1, k)),
                    None if f0 is None else ramp(f0, f1, k)) for k in range(1, n + 1)]


def solve_load_steps(make_solver, model, state, controls, limits, callback=None, history=None):
    """Solve ``state`` in place through the load steps ``controls``: for each, apply it and run
    ``make_solver(model)`` (a solver for the model with that step's prescribed positions) under
    ``limits`` to equilibrium. Returns (the last step's Model, [SolveResult per step]); a step that
    does not converge ends the sequence. ``history`` (a History, optional) records every step."""
    hist = history if history is not None else History()
    results = []
    for c in controls:
        model = c.apply(model, state)
        res = make_solver(model).solve(state, limits, callback, hist)
        results.append(res)
        if not res.converged:
            break
    return model, results
