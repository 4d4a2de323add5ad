"""Grid sequencing: the scene on coarser grids (every second node, recursively), each solved by
Newton from the previous one's interpolated solution, gives the fine grid's starting state.

Shapes: a grid of nx1 x ny1 nodes (``Model.grid_shape``), node k = i * ny1 + j; positions (n, 3) [m].
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse as sp

from .active_set import PENETRATION_TOL
from .iteration import NewtonLevel, _forcing
from .linalg import _interp_1d


def coarsen_model(model):
    """The same scene on the grid of every second node (needs even divisions), or None."""
    from ...grid import FAMILY_BEND_WARP, FAMILY_BEND_WEFT, FAMILY_SEAM, FAMILY_SHEAR, Model, _adjacency

    nx1, ny1 = model.grid_shape
    nx, ny = nx1 - 1, ny1 - 1
    if nx % 2 or ny % 2 or nx < 4 or ny < 4:
        return None, None
    cx, cy = nx // 2, ny // 2
    dx, dy = 2 * model.spacing[0], 2 * model.spacing[1]
    sub = np.arange(nx1 * ny1).reshape(nx1, ny1)[::2, ::2].ravel()
    n = (cx + 1) * (cy + 1)
    idx = np.arange(n).reshape(cx + 1, cy + 1)
    rest = model.rest_positions[sub].copy()
    fam = model.spring_family
    nodes, rest_len, width, table, family = [], [], [], [], []

    def add(a, b, l0, w, t, f):
        nodes.append(np.stack([a.ravel(), b.ravel()], 1)); rest_len.append(np.full(a.size, l0))
        width.append(np.broadcast_to(w, a.shape).ravel().astype(float))
        table.append(np.full(a.size, t, np.int64)); family.append(np.full(a.size, f, np.int8))

    t_warp = int(model.spring_table[fam == 0][0])
    t_weft = int(model.spring_table[fam == 1][0])
    w = np.full((cx, cy + 1), dy); w[:, 0] *= 0.5; w[:, cy] *= 0.5
    add(idx[:-1, :], idx[1:, :], dx, w, t_warp, 0)
    w = np.full((cx + 1, cy), dx); w[0, :] *= 0.5; w[cx, :] *= 0.5
    add(idx[:, :-1], idx[:, 1:], dy, w, t_weft, 1)
    if (fam == FAMILY_SHEAR).any():
        t = int(model.spring_table[fam == FAMILY_SHEAR][0])
        diag = math.hypot(dx, dy)
        wd = 0.5 * dx * dy / diag
        add(idx[:-1, :-1], idx[1:, 1:], diag, wd, t, FAMILY_SHEAR)
        add(idx[1:, :-1], idx[:-1, 1:], diag, wd, t, FAMILY_SHEAR)
    if (fam == FAMILY_BEND_WARP).any() and cx >= 2:
        t = int(model.spring_table[fam == FAMILY_BEND_WARP][0])
        w = np.full((cx - 1, cy + 1), dy); w[:, 0] *= 0.5; w[:, cy] *= 0.5
        add(idx[:-2, :], idx[2:, :], 2 * dx, w, t, FAMILY_BEND_WARP)
    if (fam == FAMILY_BEND_WEFT).any() and cy >= 2:
        t = int(model.spring_table[fam == FAMILY_BEND_WEFT][0])
        w = np.full((cx + 1, cy - 1), dx); w[0, :] *= 0.5; w[cx, :] *= 0.5
        add(idx[:, :-2], idx[:, 2:], 2 * dy, w, t, FAMILY_BEND_WEFT)
    seam = fam == FAMILY_SEAM
    if seam.any():
        # seams keep the pairs whose two nodes are both on the coarse grid; each carries the
        # seam length of two fine pairs (twice the stiffness)
        cmap = -np.ones(model.node_count, np.int64)
        cmap[sub] = np.arange(n)
        ca = cmap[model.spring_nodes[seam, 0]]
        cb = cmap[model.spring_nodes[seam, 1]]
        keep = (ca >= 0) & (cb >= 0)
        if keep.any():
            nodes.append(np.stack([ca[keep], cb[keep]], 1))
            rest_len.append(model.spring_rest_length[seam][keep])
            width.append(2.0 * model.spring_width[seam][keep])
            table.append(model.spring_table[seam][keep])
            family.append(np.full(int(keep.sum()), FAMILY_SEAM, np.int8))
    spring_nodes = np.ascontiguousarray(np.concatenate(nodes).astype(np.int64))
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    wx = np.full(cx + 1, dx); wx[0] *= 0.5; wx[-1] *= 0.5
    wy = np.full(cy + 1, dy); wy[0] *= 0.5; wy[-1] *= 0.5
    area = np.outer(wx, wy).ravel()
    fine_area = model.node_area[sub]
    ext = model.external_force[sub] * (area / np.where(fine_area > 0, fine_area, 1.0))[:, None]
    coarse = Model(
        node_count=n, grid_shape=(cx + 1, cy + 1), rest_positions=rest, spring_nodes=spring_nodes,
        spring_rest_length=np.ascontiguousarray(np.concatenate(rest_len), float),
        spring_width=np.ascontiguousarray(np.concatenate(width), float),
        spring_table=np.ascontiguousarray(np.concatenate(table)), spring_family=np.concatenate(family),
        tables=model.tables, table_list=model.table_list,
        fixed_axes=np.ascontiguousarray(model.fixed_axes[sub]),
        prescribed_positions=np.ascontiguousarray(model.prescribed_positions[sub]),
        external_force=np.ascontiguousarray(ext), node_area=area, adj_ptr=ptr, adj_node=adj_node,
        adj_spring=adj_spring, mold=model.mold, spacing=(dx, dy), warp_count=cx * (cy + 1),
        weft_count=(cx + 1) * cy)
    return coarse, sub


def prolong_state(coarse_model, coarse_state, fine_model, fine_state):
    """Interpolate a coarse solution onto the fine grid (bilinear in the node indices), keep
    the fine constrained coordinates, and put nodes that would be inside the mold (or between
    two contact nodes) onto its surface as contact nodes."""
    from ...mold import mold_query_many

    nx1, ny1 = fine_model.grid_shape
    cx1, cy1 = coarse_model.grid_shape
    px, _ = _interp_1d(nx1)
    py, _ = _interp_1d(ny1)
    P = sp.kron(px, py, format="csr")
    pos = P @ coarse_state.positions
    cont = (P @ coarse_state.in_contact.astype(float)) > 1.0 - 1e-9
    fixed = fine_model.fixed_axes
    pos[fixed] = fine_state.positions[fixed]
    if fine_model.mold is not None:
        margs = fine_model.mold.kernel_args()
        n = fine_model.node_count
        sd = np.empty(n); cp = np.empty((n, 3)); nrm = np.empty((n, 3)); feat = np.empty((n, 2), np.int64)
        mold_query_many(margs, pos, sd, cp, nrm, feat)
        put = (sd < 0) | cont
        put &= ~fixed.all(axis=1)
        k = np.nonzero(put)[0]
        for a in range(3):
            sel = k[~fixed[k, a]]
            pos[sel, a] = cp[sel, a]
        mold_query_many(margs, pos, sd, cp, nrm, feat)
        inside = sd < -PENETRATION_TOL
        if inside.any():
            return False
        cont = put
    else:
        cont = np.zeros(fine_model.node_count, bool)
    fine_state.positions[:] = pos
    fine_state.in_contact[:] = cont
    return True


def _solve_level(level: NewtonLevel, state, e, max_iter, deadline):
    """Newton iterations on a coarse level until its residual is below e (or no progress)."""
    v = level.residual(state.positions, state.in_contact)
    for _ in range(max_iter):
        if v <= e or time.perf_counter() > deadline:
            break
        v, E, flag = level.iterate(state, v, forcing=_forcing(v, e))
        if flag:
            break
    return v


def sequencing_chain(model, min_nodes: int = 400):
    """[(model, sub), ...] from the coarsest grid to the given one; each coarser grid has half
    the divisions of the next, and ``sub`` (for all but the last) indexes the next grid's nodes
    that it keeps."""
    chain = [(model, None)]
    m = model
    while True:
        c, sub = coarsen_model(m)
        if c is None or c.node_count < min_nodes:
            break
        chain.append((c, sub))  # sub: the nodes of m (the next finer grid) that c keeps
        m = c
    return chain[::-1]


def grid_sequence(model, state, e, kink, deadline):
    """Solve the scene on the coarser grids (coarsest first), each started from the previous
    one's solution, and return the interpolated starting state for ``model`` (or None when the
    grid cannot be coarsened or the interpolation fails). e [N]: the run's convergence limit (no
    level is solved tighter); kink: NewtonOptions.kink; deadline: a ``time.perf_counter`` value."""
    from ...grid import State

    chain = sequencing_chain(model)
    if len(chain) < 2:
        return None
    # restrict the current state down the chain (each level keeps every second node)
    starts = [None] * len(chain)
    starts[-1] = (state.positions, state.in_contact)
    for li in range(len(chain) - 1, 0, -1):
        p, c = starts[li]
        sub = chain[li - 1][1]
        starts[li - 1] = (p[sub].copy(), c[sub].copy())
    prev_model = prev_state = None
    for li, (mdl, _) in enumerate(chain[:-1]):
        p, c = starts[li]
        cst = State(np.ascontiguousarray(p), c.copy(), 0)
        if prev_state is not None:
            # the previous level's solution; when it cannot be interpolated (prolong_state then
            # leaves cst alone) this level starts from the restricted state
            prolong_state(prev_model, prev_state, mdl, cst)
        lvl = NewtonLevel(mdl, kink=kink)
        v0 = lvl.residual(cst.positions, cst.in_contact)
        # the coarsest grid is solved tightly (it fixes the contact set), the others only as far
        # as their discretisation error matters for the next grid's start
        rel = 1e-8 if li == 0 else 1e-4
        _solve_level(lvl, cst, max(e, rel * v0), 60, deadline)
        prev_model, prev_state = mdl, cst
    trial = state.copy()
    if not prolong_state(prev_model, prev_state, model, trial):
        return None
    return trial
