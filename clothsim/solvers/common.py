"""What every solver shares: the result record, the progress record, the residual, the energy.

The solver contract (``Solver``, ``step``, ``StepReport``, the status enums) is in
``clothsim.solvers.base``; the driver that runs a solver (limits, stall detection, history,
callback) is ``clothsim.solvers.driver.run``. Solvers never print; they report through
``callback(progress)``, which may return True to stop the run (scipy.optimize style).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..contact import residual_from_forces
from ..kernels import forces_and_energy, spring_strains_tensions
from ..model import State

from ..mold import load_mold
from .status import Status

# the run statuses' strings (``Status`` values), in the order they have always been listed
STATUSES = tuple(s.value for s in Status)


@dataclass
class Progress:
    """Reported to the callback after each batch of iterations."""

    iteration: int
    residual: float  # N, ||V||_inf
    energy: float  # J
    elapsed_s: float
    iterations_per_s: float
    contact_count: int
    state: State  # the live State (read only, between batches)
    method: str = ""


@dataclass
class SolveResult:
    """The outcome of a run (scipy.optimize's ``OptimizeResult`` for this package).

    converged; status (a :class:`Status`, which compares equal to and serialises as its string;
    ``"idle"`` for a scene never run); message; iterations; residual [N] (||V||_inf, eq. 6);
    relative_residual (residual / largest spring force); energy [J]; contact_count; wall_time_s
    [s]; method (the solver's name, ``newton+paper`` for auto's rescue); history: the run's
    ``History`` (a mapping of arrays iteration, residual [N], energy [J], time [s]);
    best_residual [N]: the smallest residual reached; friction: the load steps' report of a scene
    solved in load steps (clothsim.solvers.friction.solve_steps), else None."""

    converged: bool
    status: Status | str
    message: str
    iterations: int
    residual: float
    relative_residual: float
    energy: float
    contact_count: int
    wall_time_s: float
    method: str
    history: dict = field(default_factory=dict)
    best_residual: float = math.nan
    friction: dict | None = None


@functools.lru_cache(maxsize=1)
def _dummy_mold_args():
    return load_mold({"plane": {"point": [0.0, 0.0, -1e9], "normal": [0.0, 0.0, 1.0]}}).kernel_args()


def model_mold_args(model):
    """(has_mold, margs): the mold's kernel arguments, or a far-away plane's (same numba type, so
    a scene without a mold compiles nothing extra and never queries it: has_mold is False)."""
    if model.mold is None:
        return False, _dummy_mold_args()
    return True, model.mold.kernel_args()


def residual(model, state, V: Optional[np.ndarray] = None) -> tuple[float, np.ndarray]:
    """(||V||_inf [N], V (N,)) at the current state."""
    has_mold, margs = model_mold_args(model)
    if V is None:
        V = np.empty(model.node_count)
    F = np.empty_like(state.positions)
    forces_and_energy(state.positions, *model.spring_args(), model.external_force, F)
    model.add_seam_forces(state.positions, F)
    if model.friction is not None:
        model.add_friction_forces(state.positions, F)
    vinf = residual_from_forces(state.positions, F, model.fixed_axes, state.in_contact, has_mold, margs, V)
    return vinf, V


def energy(model, state) -> float:
    """Total potential energy [J] (springs minus external work)."""
    out = np.empty_like(state.positions)
    e = forces_and_energy(state.positions, *model.spring_args(), model.external_force, out)
    e = e + model.add_seam_forces(state.positions, out)
    if model.friction is not None:
        e = e + model.add_friction_forces(state.positions, out)
    return e


def force_scale(model, state) -> float:
    """Largest spring force [N] (for the relative residual)."""
    s = np.empty(model.spring_count)
    f = np.empty(model.spring_count)
    spring_strains_tensions(state.positions, *model.spring_args(), s, f)
    fmax = float(np.max(np.abs(f))) if f.size else 0.0
    gmax = float(np.max(np.linalg.norm(model.external_force, axis=1))) if model.node_count else 0.0
    return max(fmax, gmax)


def blowup_limit(model) -> float:
    """Positions beyond this [m] from the origin count as a blow-up: the farthest rest or
    prescribed coordinate plus 1000 times the larger of the sheet's extent and the prescribed
    coordinates' spread (a strip stretched 300 m by its constraints is not a blow-up)."""
    rest = model.rest_positions
    fixed = model.fixed_axes
    far = float(np.abs(rest).max())
    ext = float(np.ptp(rest, axis=0).max())
    for a in range(3):
        held = model.prescribed_positions[fixed[:, a], a]
        if held.size:
            far = max(far, float(np.abs(held).max()))
            ext = max(ext, float(np.ptp(np.concatenate([rest[:, a], held]))))
    return far + 1e3 * max(ext, 1e-9)

