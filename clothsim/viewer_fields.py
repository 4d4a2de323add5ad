"""Per-node fields the viewer colours the sheet by, computed from (model, positions, in_contact).

The same quantities as :class:`clothsim.results.Result` (whose per-node contact force loop is fine
for one export but too slow to repeat 25 times a second on a 200 x 200 grid): here every step is a
whole-array numba kernel or numpy operation. No viser import.
"""

from __future__ import annotations

import numpy as np

from .kernels import forces_and_energy, spring_strains_tensions
from .results import MMHG, deformed_node_area

#: label -> (unit shown in the legend, short key)
FIELDS: dict[str, tuple[str, str]] = {
    "warp strain": ("", "strain_warp"),
    "weft strain": ("", "strain_weft"),
    "tension (max of warp, weft)": ("N/m", "tension"),
    "contact pressure": ("mmHg", "pressure"),
    "in contact": ("", "contact"),
}


def _spread_warp(v: np.ndarray, nx1: int, ny1: int) -> np.ndarray:
    """Mean of the warp springs (nx, ny1) at each node."""
    s = np.zeros((nx1, ny1))
    c = np.zeros((nx1, ny1))
    s[:-1] += v
    s[1:] += v
    c[:-1] += 1
    c[1:] += 1
    return s / np.maximum(c, 1)


def _spread_weft(v: np.ndarray, nx1: int, ny1: int) -> np.ndarray:
    s = np.zeros((nx1, ny1))
    c = np.zeros((nx1, ny1))
    s[:, :-1] += v
    s[:, 1:] += v
    c[:, :-1] += 1
    c[:, 1:] += 1
    return s / np.maximum(c, 1)


def contact_pressure(model, positions: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """Contact pressure [Pa] per node (N,): the normal reaction max(0, -R . n) over the deformed
    tributary area, R the resultant of the node's springs and external force, n the mold's
    outward (pseudo-)normal at the closest point; zero off contact."""
    n = model.node_count
    out = np.zeros(n)
    if model.mold is None or not in_contact.any():
        return out
    from .mold import mold_query_many

    forces = np.empty((n, 3))
    forces_and_energy(positions, *model.spring_args(), model.external_force, forces)
    k = np.nonzero(in_contact)[0]
    P = np.ascontiguousarray(positions[k])
    sd = np.empty(len(k))
    cp = np.empty((len(k), 3))
    nrm = np.empty((len(k), 3))
    feat = np.empty((len(k), 2), np.int64)
    mold_query_many(model.mold.kernel_args(), P, sd, cp, nrm, feat)
    reaction = np.maximum(0.0, -np.einsum("ij,ij->i", forces[k], nrm))
    nx1, ny1 = model.grid_shape
    area = deformed_node_area(positions, nx1, ny1)[k]
    out[k] = np.divide(reaction, area, out=np.zeros_like(reaction), where=area > 0)
    return out


def node_field(model, positions: np.ndarray, in_contact: np.ndarray, key: str) -> np.ndarray:
    """Per-node values (N,) of a field key (see FIELDS): strains are engineering strain, tension
    is tension per width [N/m] (the larger of the mean warp and weft values), pressure in mmHg,
    contact 0/1."""
    nx1, ny1 = model.grid_shape
    if key == "contact":
        return in_contact.astype(np.float64)
    if key == "pressure":
        return contact_pressure(model, positions, in_contact) / MMHG
    S = model.spring_count
    strain = np.empty(S)
    force = np.empty(S)
    spring_strains_tensions(positions, *model.spring_args(), strain, force)
    wc, fc = model.warp_count, model.weft_count
    if key == "tension":
        width = model.spring_width
        t = np.divide(force, width, out=np.zeros(S), where=width > 0)
        w = _spread_warp(t[:wc].reshape(nx1 - 1, ny1), nx1, ny1) if nx1 > 1 else np.zeros((nx1, ny1))
        f = _spread_weft(t[wc:wc + fc].reshape(nx1, ny1 - 1), nx1, ny1) if ny1 > 1 else np.zeros((nx1, ny1))
        return np.maximum(w, f).ravel()
    if key == "strain_warp":
        if nx1 < 2:
            return np.zeros(nx1 * ny1)
        return _spread_warp(strain[:wc].reshape(nx1 - 1, ny1), nx1, ny1).ravel()
    if key == "strain_weft":
        if ny1 < 2:
            return np.zeros(nx1 * ny1)
        return _spread_weft(strain[wc:wc + fc].reshape(nx1, ny1 - 1), nx1, ny1).ravel()
    raise ValueError(f"unknown field {key!r}")
