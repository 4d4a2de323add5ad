"""Per-node fields the viewer colours the sheet by, computed from (model, positions, in_contact).

The same quantities as :class:`clothsim.results.Result`, from the same whole-array helpers, spread
to nodes for colouring. No viser import.
"""

from __future__ import annotations

import numpy as np

from ..kernels import spring_strains_tensions
from ..friction import slides
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
    "stick / slip": ("", "friction"),
}

#: the categories of the "stick / slip" field (its values 0..3) and their colours (sRGB 0-255)
FRICTION_STATES = ("no contact", "contact without friction", "stick", "slip")
FRICTION_COLOURS = ((116, 192, 252), (250, 176, 5), (47, 158, 68), (224, 49, 49))


def friction_state(model, positions: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """Per node (N,) float: 0 no contact; 1 in contact without friction (frictionless, a
    constrained node, not pressed onto the mold, or no frictional load step solved yet); 2 stick;
    3 slip. A node sticks or slips by the rule of the run summary's counts
    (``clothsim.friction.friction_report``): ``model.friction``, the friction refreshed at the
    last load step's equilibrium, names the pressed nodes, and one that slid at least the slip
    eps from its anchor (where the step began) slipped."""

    out = in_contact.astype(np.float64)
    lag = model.friction
    if lag is None or not len(lag.nodes) or not (lag.mu > 0).any():
        return out
    pressed = lag.lam > 0.0
    nodes = lag.nodes[pressed]
    slid = slides(lag, positions)[pressed] >= lag.eps
    touching = in_contact[nodes]
    out[nodes[touching]] = np.where(slid[touching], 3.0, 2.0)
    return out


def node_field(model, positions: np.ndarray, in_contact: np.ndarray, key: str) -> np.ndarray:
    """Per-node values (N,) of a field key (see FIELDS): strains are engineering strain, tension
    is tension per width [N/m] (the larger of the mean warp and weft values), pressure in mmHg,
    contact 0/1, friction the stick/slip category (:func:`friction_state`)."""
    topo = model.topology
    if key == "friction":
        return friction_state(model, positions, in_contact)
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
