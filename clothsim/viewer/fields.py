"""Per-node fields the viewer colours the sheet by, computed from (model, positions, in_contact).

The same quantities as :class:`clothsim.results.Result`, from the same whole-array helpers, spread
to nodes for colouring. No viser import.
"""

from __future__ import annotations

import numpy as np

from ..kernels import spring_strains_tensions
from ..pressure import MMHG, contact_reaction


def contact_pressure(model, positions: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """Contact pressure [Pa] per node (N,) (see clothsim.pressure.contact_reaction)."""
    return contact_reaction(model, positions, in_contact)[1]

#: label -> (unit shown in the legend, short key)
FIELDS: dict[str, tuple[str, str]] = {
    "warp strain": ("", "strain_warp"),
    "weft strain": ("", "strain_weft"),
    "tension (max of warp, weft)": ("N/m", "tension"),
    "contact pressure": ("mmHg", "pressure"),
    "in contact": ("", "contact"),
}


def node_field(model, positions: np.ndarray, in_contact: np.ndarray, key: str) -> np.ndarray:
    """Per-node values (N,) of a field key (see FIELDS): strains are engineering strain, tension
    is tension per width [N/m] (the larger of the mean warp and weft values), pressure in mmHg,
    contact 0/1."""
    topo = model.topology
    if key == "contact":
        return in_contact.astype(np.float64)
    if key == "pressure":
        return contact_pressure(model, positions, in_contact) / MMHG
    # the fields are warp and weft quantities: only those springs (stored first) are evaluated
    wc, fc = model.warp_count, model.weft_count
    S = wc + fc
    strain = np.empty(S)
    force = np.empty(S)
    nodes, rest, width, table, *tabs = model.spring_args()
    spring_strains_tensions(positions, nodes[:S], rest[:S], width[:S], table[:S], *tabs, strain, force)
    if key == "tension":
        t = np.divide(force, width[:S], out=np.zeros(S), where=width[:S] > 0)
        return np.maximum(topo.spread(t[:wc], "warp"), topo.spread(t[wc:wc + fc], "weft"))
    if key == "strain_warp":
        return topo.spread(strain[:wc], "warp")
    if key == "strain_weft":
        return topo.spread(strain[wc:wc + fc], "weft")
    raise ValueError(f"unknown field {key!r}")
