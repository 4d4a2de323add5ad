"""Settling a cut lattice's outline band on an interpolated start (grid sequencing).

On a lattice cut by an outline, the coarse grids of the sequencing represent the outline only
roughly: a coarse node beside a held fine node is held at a guessed position (see
``lattice.coarsen_model``), and the interpolation loses corners at the fringe. The fine start then
carries a force error concentrated in the few node rows next to the outline (on the 225-across
circular blank: 2e-2 N there against 6e-4 N inside), high-frequency along the outline and decaying
within a few rows. Node-wise nonlinear Gauss-Seidel (each node moved by the 3x3 Newton step of its
own springs, the others fixed) is the smoother that removes such an error cheaply: a sweep over the
band costs a fraction of a force pass over the whole lattice.

Shapes: n nodes; positions (n, 3) [m]; forces [N]; stiffness blocks [N/m].
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from ...model import SpringFamily
from .settle import node_spring_block, spring_kinks

from ..tuning import NewtonTuning

# the band's depth and sweeps: NewtonTuning.rim_band, NewtonTuning.rim_gs_sweeps


def outline_band(model, depth: int | None = None) -> np.ndarray:
    """(m,) int64: the free nodes of ``model`` within ``depth`` (None: ``NewtonTuning.rim_band``) lattice steps
    (warp/weft springs) of a held node or of an unsewn node with fewer than four lattice
    neighbours (the outline), ordered by that distance (nearest first). Nodes of seam springs or
    seam elements are left out and do not start a band: their missing neighbours are across
    their seam, in the other panel. Empty on a model without such nodes. (Grid sequencing
    settles no band where every panel is a full rectangle: its coarse lattices hold those
    outlines exactly, ``Topology.panels_full``.)"""
    depth = NewtonTuning.rim_band if depth is None else int(depth)
    n = model.node_count
    fam = model.spring_family
    lat = (fam == SpringFamily.WARP) | (fam == SpringFamily.WEFT)
    a, b = model.spring_nodes[lat, 0], model.spring_nodes[lat, 1]
    deg = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
    held = model.fixed_axes.any(axis=1)
    sewn = np.zeros(n, bool)
    sewn[model.spring_nodes[fam == SpringFamily.SEAM].ravel()] = True
    if model.seam_count:
        sewn[model.seam_nodes.ravel()] = True
    # a sewn node's missing lattice neighbours are across its seam: not an outline
    seed = held | ((deg < 4) & ~sewn)
    if not seed.any():
        return np.zeros(0, np.int64)
    A = sp.csr_matrix((np.ones(2 * a.size), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))
    dist = np.full(n, -1, np.int64)
    dist[seed] = 0
    front = seed.astype(float)
    for d in range(1, depth + 1):
        nb = (A @ front) > 0
        new = nb & (dist < 0)
        if not new.any():
            break
        dist[new] = d
        front = new.astype(float)
    ok = (dist >= 0) & ~held & ~sewn
    idx = np.nonzero(ok)[0]
    return np.ascontiguousarray(idx[np.argsort(dist[idx], kind="stable")], np.int64)


@njit(cache=True, error_model="numpy")
def node_gauss_seidel(pos, nodes, skip, ptr, nbr, sid, rest, width, table, x, y, cum, start, comp, ext, kink,
                      sweeps):
    """Nonlinear Gauss-Seidel on the nodes ``nodes`` (m,) of pos (n,3) [m], in place: each node in
    turn moves by the Newton step H^-1 R of its own springs, the other nodes held (R its resultant
    [N] and H the sum of its springs' stiffness blocks [N/m], ``settle.node_spring_block``; kink
    (S,) [N/m]: each spring's kink stiffness, ``settle.spring_kinks``); ``sweeps``
    forward-then-backward passes. ptr (n+1,), nbr, sid: the node adjacency (``Model.adj_ptr``,
    ``adj_node``, ``adj_spring``); the spring and table arrays as in ``kernels.forces_and_energy``;
    ext (n,3) [N]. Nodes with skip[k] set are passed over; a step longer than half the node's
    shortest rest length is shortened to it. Returns the largest |R| [N] met in the last pass
    (before the node's own move)."""
    rmax = 0.0
    m = nodes.shape[0]
    f = np.empty(3)
    H = np.empty((3, 3))
    for sw in range(2 * sweeps):
        rmax = 0.0
        for q in range(m):
            k = nodes[q] if sw % 2 == 0 else nodes[m - 1 - q]
            if skip[k]:
                continue
            lmin = node_spring_block(k, pos, ptr, sid, nbr, rest, width, table, x, y, cum, start, comp, kink, ext,
                                     f, H)
            f0, f1, f2 = f[0], f[1], f[2]
            h00, h11, h22 = H[0, 0], H[1, 1], H[2, 2]
            h01, h02, h12 = H[0, 1], H[0, 2], H[1, 2]
            r = max(abs(f0), abs(f1), abs(f2))
            if r > rmax:
                rmax = r
            tr = h00 + h11 + h22
            if not (tr > 0.0):
                continue
            eps = 1e-9 * tr
            a00 = h00 + eps
            a11 = h11 + eps
            a22 = h22 + eps
            c00 = a11 * a22 - h12 * h12
            c01 = h02 * h12 - h01 * a22
            c02 = h01 * h12 - h02 * a11
            det = a00 * c00 + h01 * c01 + h02 * c02
            if not (det > 0.0):
                continue
            c11 = a00 * a22 - h02 * h02
            c12 = h01 * h02 - a00 * h12
            c22 = a00 * a11 - h01 * h01
            d0 = (c00 * f0 + c01 * f1 + c02 * f2) / det
            d1 = (c01 * f0 + c11 * f1 + c12 * f2) / det
            d2 = (c02 * f0 + c12 * f1 + c22 * f2) / det
            dl = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            cap = 0.5 * lmin
            if dl > cap:
                d0 *= cap / dl
                d1 *= cap / dl
                d2 *= cap / dl
            pos[k, 0] += d0
            pos[k, 1] += d1
            pos[k, 2] += d2
    return rmax


def settle_outline(model, pos, cont, kink: float, band: np.ndarray | None = None, sweeps: int | None = None):
    """Settle the outline band (``outline_band``) of the cut lattice ``model`` at pos (n,3) [m] in
    place by ``node_gauss_seidel`` (``sweeps``, symmetric sweeps; None: ``NewtonTuning.rim_gs_sweeps``); contact nodes (cont (n,)
    bool) stay. kink: NewtonOptions.kink.
    Returns the largest resultant [N] of the band in the last pass."""
    if band is None:
        band = outline_band(model)
    if band.size == 0:
        return 0.0
    t = model.tables
    return node_gauss_seidel(pos, band, np.ascontiguousarray(cont), model.adj_ptr, model.adj_node,
                             model.adj_spring, model.spring_rest_length, model.spring_width, model.spring_table,
                             t.x, t.y, t.cum, t.start, t.compression, model.external_force,
                             spring_kinks(model, kink), int(NewtonTuning.rim_gs_sweeps if sweeps is None else sweeps))
