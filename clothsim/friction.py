"""Coulomb friction between the fabric and the mold: the frozen (lagged) friction of one load
step and what a frictional equilibrium reports.

Per load step every contact node either sticks (it has not slid since the previous step's
equilibrium, |f_t| <= mu f_n) or slips (|f_t| = mu f_n against its slide in the step). The
Newton solver sees this as a smoothed dissipation potential per node (``contact``'s friction
kernels, after Incremental Potential Contact: Li M. et al., ACM Trans. Graph. 39 (4), 2020) whose
normal force and tangent plane are frozen from an earlier iterate (:func:`lag_friction`); the
load step is solved again with them refreshed until the residual with the refreshed friction is
within the scene's e (``solvers/friction.py``). One coefficient serves for static and kinetic
friction. Nodes with a constrained axis carry no friction (their constraint takes any force).

Shapes: n nodes; m friction nodes; positions (n, 3) [m]; forces [N].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kernels import forces_and_energy
from .mold import mold_query_many

# the slide [m], as a share of the lattice spacing, below which a node sticks (the mollifier's
# width eps: a sticking node's friction is a stiff spring of 2 mu f_n / eps, and it may creep by
# up to eps per load step). 1e-3 of the spacing: the capstan's ratio and the incline's threshold
# are met to well within their discretisation errors (docs/method/friction.md)
SLIP_SHARE = 1e-3


@dataclass(frozen=True)
class FrictionLag:
    """The friction frozen for one solve. nodes (m,) int64: the contact nodes that carry it;
    anchor (m, 3) [m]: their positions at the previous load step's equilibrium; normal (m, 3):
    the frozen unit outward normals; lam (m,) [N]: the frozen normal forces; weight (m,) [N] =
    mu lam; eps [m]: the slip below which a node sticks; mu (m,) [-]: each node's coefficient
    (``mold.friction``, or a friction region's)."""

    nodes: np.ndarray
    anchor: np.ndarray
    normal: np.ndarray
    lam: np.ndarray
    weight: np.ndarray
    eps: float
    mu: np.ndarray


def slip_eps(model) -> float:
    """The mollifier's width eps [m]: SLIP_SHARE times the lattice's smallest spacing."""
    h = [s for s in model.spacing if s > 0]
    if not h:
        h = [float(np.ptp(model.rest_positions, axis=0).max()) or 1.0]
    return SLIP_SHARE * float(min(h))


def elastic_forces(model, positions) -> np.ndarray:
    """The resultants (n, 3) [N] of the springs, seams and loads (no friction) at positions."""
    F = np.empty_like(positions)
    forces_and_energy(positions, *model.spring_args(), model.external_force, F)
    model.add_seam_forces(positions, F)
    return F


def normal_forces(model, state):
    """(nodes (m,), normals (m, 3), lam (m,) [N]) of the contact nodes without a constrained
    axis: their mold normals at their positions and their normal forces lam = max(0, -n . F)
    (F: springs, seams and loads; the reaction the mold gives them)."""
    nodes = np.nonzero(state.in_contact & ~model.fixed_axes.any(axis=1))[0].astype(np.int64)
    m = nodes.shape[0]
    nrm = np.zeros((m, 3))
    if m == 0 or model.mold is None:
        return nodes, nrm, np.zeros(m)
    p = np.ascontiguousarray(state.positions[nodes])
    mold_query_many(model.mold.kernel_args(), p, np.empty(m), np.empty((m, 3)), nrm, np.empty((m, 2), np.int64))
    F = elastic_forces(model, state.positions)[nodes]
    lam = np.maximum(0.0, -np.einsum("ij,ij->i", F, nrm))
    return nodes, nrm, lam


def lag_friction(model, state, anchor, eps_scale: float = 1.0) -> FrictionLag:
    """The friction frozen at ``state``: its contact nodes' normals and normal forces
    (:func:`normal_forces`; only the nodes whose mu is above 0), each node anchored at ``anchor`` (n, 3) [m] (the previous load
    step's equilibrium); its slip eps ``eps_scale`` times :func:`slip_eps` (above 1 only for a
    load step's smoother first solve: ``solvers/friction.py``)."""
    nodes, nrm, lam = normal_forces(model, state)
    mu = model.friction_mu_of(nodes)
    if model.friction_mu_nodes is not None:  # a node with mu = 0 (outside a grip band) carries none
        keep = mu > 0
        nodes, nrm, lam, mu = nodes[keep], nrm[keep], lam[keep], mu[keep]
    return FrictionLag(nodes, np.ascontiguousarray(anchor[nodes], float), np.ascontiguousarray(nrm),
                       lam, mu * lam, eps_scale * slip_eps(model), mu)


def slides(lag: FrictionLag, positions) -> np.ndarray:
    """|u| (m,) [m]: each friction node's tangential slide from its anchor."""
    d = positions[lag.nodes] - lag.anchor
    u = d - np.einsum("ij,ij->i", d, lag.normal)[:, None] * lag.normal
    return np.linalg.norm(u, axis=1)


def friction_report(model, lag: FrictionLag, positions, e: float) -> dict:
    """The Coulomb state of an equilibrium, ``lag`` being the friction refreshed there: stick and
    slip counts over the contact nodes with friction pressed onto the mold (slip: slid at least eps in the
    step), and the cone violation max((|f_t| - mu f_n)+ / f_n) of the mold's reaction (f_n its
    normal part, f_t its tangential part: minus the springs' and loads' resultant) over the
    nodes pressed by more than e [N], the residual limit (below it the cone holds to within the
    solve's own tolerance)."""
    pressed = lag.lam > 0.0
    slip = int(np.count_nonzero(pressed & (slides(lag, positions) >= lag.eps)))
    viol = 0.0
    big = lag.lam > e
    if big.any():
        F = elastic_forces(model, positions)[lag.nodes[big]]
        n = lag.normal[big]
        ft = np.linalg.norm(F - np.einsum("ij,ij->i", F, n)[:, None] * n, axis=1)
        fn = lag.lam[big]
        viol = float(np.max(np.maximum(0.0, ft - lag.mu[big] * fn) / fn))
    return {"stick": int(np.count_nonzero(pressed)) - slip, "slip": slip, "cone_violation": viol}
