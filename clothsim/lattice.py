"""The spring arrays of a lattice and the stride-2 coarse model grid sequencing solves.

:func:`lattice_springs` gives a :class:`~clothsim.topology.Topology`'s warp and weft springs their
rest lengths and tributary widths (and adds the shear and bending families when asked);
:func:`clothsim.grid.build_model` calls it for a scene, :func:`coarsen_model` for the same scene
on the stride-2 lattice. Springs are stored warp first, then weft (in the topology's order), then
shear, bending and seams.

Tributary width (paper Fig. 3): a warp spring carries the band of width dy around its row: half
of it (dy/2) on each side where the lattice has a cell, so half on the bottom and top rows of a
rectangle; a weft spring the band of width dx likewise. Spring force = tension [N/m] x width
[m]. A node's area is a quarter of each adjacent cell.

This module reads no scene and imports no solver: solvers (grid sequencing) may import it.
"""

from __future__ import annotations

import math

import numpy as np

from .model import Model, Placements, SpringFamily
from .panels import rectangle_geometry
from .topology import Topology


def _adjacency(n: int, spring_nodes: np.ndarray):
    s = spring_nodes.shape[0]
    ends = np.concatenate([spring_nodes[:, 0], spring_nodes[:, 1]])
    others = np.concatenate([spring_nodes[:, 1], spring_nodes[:, 0]])
    sids = np.concatenate([np.arange(s), np.arange(s)])
    order = np.argsort(ends, kind="stable")
    counts = np.bincount(ends, minlength=n)
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(counts, out=ptr[1:])
    return ptr, others[order].astype(np.int64), sids[order].astype(np.int64)


def seam_adjacency(n: int, seam_nodes: np.ndarray):
    """Per node the seam elements touching it, in CSR form: (ptr (n+1,), elem) with node k's
    elements elem[ptr[k]:ptr[k+1]] (each once, even where an element names k twice)."""
    q = np.repeat(np.arange(seam_nodes.shape[0]), seam_nodes.shape[1])
    k = seam_nodes.reshape(-1)
    pairs = np.unique(np.stack([k, q], 1), axis=0) if k.size else np.zeros((0, 2), np.int64)
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=n), out=ptr[1:])
    return ptr, np.ascontiguousarray(pairs[:, 1], np.int64)


class _Springs:
    """Spring arrays collected family by family."""

    def __init__(self):
        self.nodes, self.rest, self.width, self.table, self.family = [], [], [], [], []

    def add(self, a, b, l0, w, t, f):
        a = np.asarray(a).ravel()
        self.nodes.append(np.stack([a, np.asarray(b).ravel()], 1))
        self.rest.append(np.broadcast_to(np.asarray(l0, float), a.shape).ravel())
        self.width.append(np.broadcast_to(np.asarray(w, float), a.shape).ravel())
        self.table.append(np.broadcast_to(np.asarray(t, np.int64), a.shape).ravel())
        self.family.append(np.full(a.size, f, np.int8))

    def arrays(self):
        return (np.ascontiguousarray(np.concatenate(self.nodes).astype(np.int64)),
                np.ascontiguousarray(np.concatenate(self.rest), float),
                np.ascontiguousarray(np.concatenate(self.width), float),
                np.ascontiguousarray(np.concatenate(self.table).astype(np.int64)),
                np.concatenate(self.family))


def lattice_springs(topology: Topology, geometries, table_ids, *, shear_table: int | None = None,
                    bend_table: int | None = None) -> _Springs:
    """The warp and weft springs of a lattice (and shear and bending when their table ids are
    given), with their tributary widths (see the module docstring).

    geometries: one clothsim.panels.PanelGeometry per panel of ``topology`` (spacing and the band
    and cell fractions); table_ids: ((warp id, weft id), ...) per panel."""
    sp = _Springs()
    for fam, pairs, frac_name, l_axis, w_axis in ((SpringFamily.WARP, topology.warp, "warp_frac", 0, 1),
                                                  (SpringFamily.WEFT, topology.weft, "weft_frac", 1, 0)):
        rest, width, table = [], [], []
        for p, (g, idx) in enumerate(zip(geometries, topology.index)):
            exists = (idx[:-1, :] >= 0) & (idx[1:, :] >= 0) if fam == SpringFamily.WARP else (idx[:, :-1] >= 0) & (idx[:, 1:] >= 0)
            frac = getattr(g, frac_name)[exists]
            r = np.full(frac.size, g.spacing[l_axis])
            w = frac * g.spacing[w_axis]
            step = (1, 0) if fam == SpringFamily.WARP else (0, 1)
            moved = _material_lengths(g, exists, step)
            if moved is not None:
                # row ends on the outline: the length between the material points, the band's
                # area over it (clothsim.panels)
                k, length = moved
                r[k] = length[k]
                w[k] = frac[k] * (g.spacing[0] * g.spacing[1]) / length[k]
            rest.append(r)
            width.append(w)
            table.append(np.full(frac.size, table_ids[p][fam], np.int64))
        sp.add(pairs[:, 0], pairs[:, 1], np.concatenate(rest), np.concatenate(width), np.concatenate(table), fam)
    if shear_table is not None:
        # both diagonals of every cell; stiffness is per width across the diagonal: each diagonal
        # carries half the cell (the part of it inside the outline), across its length
        l0, w = ([], []), ([], [])
        for g, idx in zip(geometries, topology.index):
            dx, dy = g.spacing
            diag = math.hypot(dx, dy)
            have = (idx[:-1, :-1] >= 0) & (idx[1:, :-1] >= 0) & (idx[1:, 1:] >= 0) & (idx[:-1, 1:] >= 0)
            for first, step in (((0, 0), (1, 1)), ((1, 0), (-1, 1))):
                r = np.full(int(have.sum()), diag)
                wd = g.cell_frac[have] * (0.5 * dx * dy / diag)
                moved = _material_lengths(g, have, step, first)
                if moved is not None:
                    k, length = moved
                    r[k] = length[k]
                    wd[k] = g.cell_frac[have][k] * (0.5 * dx * dy) / length[k]
                l0[first[0]].append(r)
                w[first[0]].append(wd)
        c = topology.cells
        sp.add(c[:, 0], c[:, 2], np.concatenate(l0[0]), np.concatenate(w[0]), shear_table, SpringFamily.SHEAR)
        sp.add(c[:, 1], c[:, 3], np.concatenate(l0[1]), np.concatenate(w[1]), shear_table, SpringFamily.SHEAR)
    if bend_table is not None:
        # skip-one springs along warp (i, j)-(i+2, j) and weft (i, j)-(i, j+2), with the band
        # width of the warp (weft) spring they span first
        for along, fam in ((0, SpringFamily.BEND_WARP), (1, SpringFamily.BEND_WEFT)):
            a_, b_, l_, w_ = [], [], [], []
            for g, idx in zip(geometries, topology.index):
                if along == 0 and idx.shape[0] >= 3:
                    a, m, b = idx[:-2, :], idx[1:-1, :], idx[2:, :]
                    band = g.warp_frac[:-1, :] * g.spacing[1]
                elif along == 1 and idx.shape[1] >= 3:
                    a, m, b = idx[:, :-2], idx[:, 1:-1], idx[:, 2:]
                    band = g.weft_frac[:, :-1] * g.spacing[0]
                else:
                    continue
                keep = (a >= 0) & (m >= 0) & (b >= 0)
                a_.append(a[keep]); b_.append(b[keep]); w_.append(band[keep])
                r = np.full(int(keep.sum()), 2 * g.spacing[along])
                moved = _material_lengths(g, keep, (2, 0) if along == 0 else (0, 2))
                if moved is not None:
                    r[moved[0]] = moved[1][moved[0]]
                l_.append(r)
            if a_:
                sp.add(np.concatenate(a_), np.concatenate(b_), np.concatenate(l_), np.concatenate(w_), bend_table, fam)
    return sp


def _material_lengths(g, keep: np.ndarray, step, first=(0, 0)):
    """Springs from node (i, j) + ``first`` to (i, j) + ``first`` + ``step`` for the cells or
    springs ``keep`` selects (in its row-major order): (moved (n,) bool, length (n,) [m]) — which
    of them join a node whose material point is not its lattice point (a row end on the outline,
    clothsim.panels) and the distance between their material points; None when the panel's
    nodes are all at their lattice points."""
    uv = g.node_uv
    if uv is None:
        return None
    lat = np.stack(np.meshgrid(np.arange(uv.shape[0]), np.arange(uv.shape[1]), indexing="ij"), -1)
    off = (uv != lat).any(axis=-1)
    if not off.any():
        return None
    i, j = np.nonzero(keep)
    ia, ja = i + first[0], j + first[1]
    ib, jb = ia + step[0], ja + step[1]
    moved = off[ia, ja] | off[ib, jb]
    d = (uv[ib, jb] - uv[ia, ja]) * np.asarray(g.spacing, float)
    return moved, np.hypot(d[:, 0], d[:, 1])


def _coarse_seams(model, fam, sub, n: int, sp) -> None:
    """Adds to the coarse spring set ``sp`` the seam pairs of ``model`` whose two nodes are both
    kept (``sub`` (n,): the fine index of each coarse node); each carries the seam length of two
    fine pairs (twice the width, so twice the stiffness)."""
    seam = fam == SpringFamily.SEAM
    if not seam.any():
        return
    cmap = -np.ones(model.node_count, np.int64)
    cmap[sub] = np.arange(n)
    ca = cmap[model.spring_nodes[seam, 0]]
    cb = cmap[model.spring_nodes[seam, 1]]
    keep = (ca >= 0) & (cb >= 0)
    if keep.any():
        sp.add(ca[keep], cb[keep], model.spring_rest_length[seam][keep], 2.0 * model.spring_width[seam][keep],
               model.spring_table[seam][keep], SpringFamily.SEAM)


def coarsen_model(model: Model):
    """The same scene on the stride-2 lattice (``Topology.coarsen``), built by the same spring
    builder with twice the spacing: (coarse model, sub) where sub (Nc,) are the nodes of
    ``model`` the coarse lattice keeps; (None, None) unless the lattice is a full rectangle with
    even divisions of at least 4 (what grid sequencing interpolates between). Any other lattice
    (cut or several panels) goes to :func:`_coarsen_lattice`."""
    topo = model.topology
    if model.seam_count:
        # (seam elements tie a node to a point between two fine nodes: not carried to a coarse grid)
        return None, None
    if not topo.is_grid:
        return _coarsen_lattice(model)
    nx1, ny1 = topo.grid_shape
    nx, ny = nx1 - 1, ny1 - 1
    if nx % 2 or ny % 2 or nx < 4 or ny < 4:
        return None, None

    ctopo, sub = topo.coarsen()
    dx, dy = 2 * model.spacing[0], 2 * model.spacing[1]
    cgeom = rectangle_geometry(ctopo.names[0], nx // 2, ny // 2, dx, dy)
    n = ctopo.node_count
    fam = model.spring_family

    def tid(f):
        sel = fam == f
        return int(model.spring_table[sel][0]) if sel.any() else None

    bend = tid(SpringFamily.BEND_WARP)
    bend = bend if bend is not None else tid(SpringFamily.BEND_WEFT)
    sp = lattice_springs(ctopo, [cgeom], [(tid(SpringFamily.WARP), tid(SpringFamily.WEFT))], shear_table=tid(SpringFamily.SHEAR),
                         bend_table=bend)
    _coarse_seams(model, fam, sub, n, sp)
    spring_nodes, rest_len, width, table, family = sp.arrays()
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    area = cgeom.node_frac[cgeom.mask] * (dx * dy)
    fine_area = model.node_area[sub]
    ext = model.external_force[sub] * (area / np.where(fine_area > 0, fine_area, 1.0))[:, None]
    coarse = Model(
        node_count=n, topology=ctopo, rest_positions=model.rest_positions[sub].copy(), spring_nodes=spring_nodes,
        spring_rest_length=rest_len, spring_width=width, spring_table=table, spring_family=family,
        tables=model.tables, table_list=model.table_list,
        fixed_axes=np.ascontiguousarray(model.fixed_axes[sub]),
        prescribed_positions=np.ascontiguousarray(model.prescribed_positions[sub]),
        external_force=np.ascontiguousarray(ext), node_area=area, adj_ptr=ptr, adj_node=adj_node,
        adj_spring=adj_spring, mold=model.mold, spacing=(dx, dy), placement=model.placement,
        panel_spacing=np.array([[dx, dy]]))
    return coarse, sub


def _coarsen_lattice(model: Model):
    """The stride-2 coarse model of a cut or multi-panel lattice (``Topology.coarsen``), or
    (None, None) when a panel has odd divisions or fewer than 5 nodes a side, or the model has
    springs other than warp, weft and seam pairs (shear, bending: not carried over).

    The coarse springs' tributary widths [m] are the fine ones summed over the band each coarse
    spring stands for (a coarse warp spring (I, J)-(I+1, J) spans fine springs 2I and 2I+1 on
    fine line 2J in full and lines 2J -/+ 1 by half, divided by its two fine segments), so a cut
    cell's true share carries over and a full rectangle gives its closed-form widths; rest
    lengths [m] are twice the panel's spacing; node areas [m^2] and external forces [N] are the
    fine ones restricted by the interpolation's transpose (totals kept). Nodes held on the fine
    lattice's outline are mostly not coarse nodes: a free coarse node next to a held fine node
    is held on that node's axes at its prescribed position plus their placed rest offset
    (a starting guess only); seam pairs are carried as in the full-grid case."""
    topo = model.topology
    fam = model.spring_family
    if np.any((fam != SpringFamily.WARP) & (fam != SpringFamily.WEFT) & (fam != SpringFamily.SEAM)):
        return None, None
    for p in range(topo.panel_count):
        nx1, ny1 = topo.panel_shape(p)
        if nx1 % 2 == 0 or ny1 % 2 == 0 or nx1 < 5 or ny1 < 5:
            return None, None
    ctopo, sub = topo.coarsen()
    if ctopo.node_count == 0:
        return None, None
    P = topo.lattice_prolongation(ctopo, sub)
    n = ctopo.node_count
    spacing = np.asarray(model.panel_spacing, float).reshape(-1, 2)
    sp = _Springs()
    for f, pairs, axis in ((SpringFamily.WARP, ctopo.warp, 0), (SpringFamily.WEFT, ctopo.weft, 1)):
        sel = np.nonzero(fam == f)[0]
        a = model.spring_nodes[sel, 0]
        pa = topo.node_panel[a]
        ij = topo.node_ij[a]
        if pairs.shape[0] == 0:
            continue
        cp = ctopo.node_panel[pairs[:, 0]]
        cij = ctopo.node_ij[pairs[:, 0]]
        width = np.zeros(pairs.shape[0])
        table = np.zeros(pairs.shape[0], np.int64)
        for p in range(topo.panel_count):
            shp = list(topo.panel_shape(p))
            shp[axis] -= 1  # springs along axis: one fewer than the nodes
            W = np.zeros(shp)
            k = pa == p
            W[ij[k, 0], ij[k, 1]] = model.spring_width[sel[k]]
            tid = int(model.spring_table[sel[k]][0]) if k.any() else 0
            # pad the cross direction by one on both sides (half weights reach lines 2J -/+ 1)
            Wp = np.pad(W, [(0, 1), (1, 1)] if axis == 0 else [(1, 1), (0, 1)])
            q = cp == p
            I, J = cij[q, 0], cij[q, 1]
            if axis == 0:
                seg = lambda s: 0.5 * Wp[s, 2 * J] + Wp[s, 2 * J + 1] + 0.5 * Wp[s, 2 * J + 2]  # noqa: E731
                w = 0.5 * (seg(2 * I) + seg(2 * I + 1))
            else:
                seg = lambda s: 0.5 * Wp[2 * I, s] + Wp[2 * I + 1, s] + 0.5 * Wp[2 * I + 2, s]  # noqa: E731
                w = 0.5 * (seg(2 * J) + seg(2 * J + 1))
            width[q] = w
            table[q] = tid
        rest = 2.0 * spacing[cp, axis]
        sp.add(pairs[:, 0], pairs[:, 1], rest, width, table, f)
    _coarse_seams(model, fam, sub, n, sp)
    spring_nodes, rest_len, width, table, family = sp.arrays()
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    area = np.asarray(P.T @ model.node_area)
    ext = np.asarray(P.T @ model.external_force)
    fixed = model.fixed_axes[sub].copy()
    presc = model.prescribed_positions[sub].copy()
    # a free coarse node beside a held fine node (8-neighbourhood, same panel) is held like it
    free = np.nonzero(~fixed.any(axis=1))[0]
    if free.size and model.fixed_axes.any():
        fi = sub[free]
        fp, fij = topo.node_panel[fi], topo.node_ij[fi]
        best = np.full(free.size, -1, np.int64)
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            for p in range(topo.panel_count):
                idx = topo.index[p]
                k = (fp == p) & (best < 0)
                i, j = fij[k, 0] + di, fij[k, 1] + dj
                ok = (i >= 0) & (j >= 0) & (i < idx.shape[0]) & (j < idx.shape[1])
                nb = np.full(k.sum(), -1, np.int64)
                nb[ok] = idx[i[ok], j[ok]]
                nb[nb >= 0] = np.where(model.fixed_axes[nb[nb >= 0]].any(axis=1), nb[nb >= 0], -1)
                best[np.nonzero(k)[0]] = nb
        h = best >= 0
        fixed[free[h]] = model.fixed_axes[best[h]]
        # at the held node's prescribed position plus the placed rest offset between the two
        placed = model.placement.apply(model.rest_positions)
        presc[free[h]] = model.prescribed_positions[best[h]] + placed[fi[h]] - placed[best[h]]
    cstart = np.searchsorted(ctopo.node_panel, np.arange(ctopo.panel_count + 1))
    coarse = Model(
        node_count=n, topology=ctopo, rest_positions=model.rest_positions[sub].copy(), spring_nodes=spring_nodes,
        spring_rest_length=rest_len, spring_width=width, spring_table=table, spring_family=family,
        tables=model.tables, table_list=model.table_list,
        fixed_axes=np.ascontiguousarray(fixed), prescribed_positions=np.ascontiguousarray(presc),
        external_force=np.ascontiguousarray(ext), node_area=area, adj_ptr=ptr, adj_node=adj_node,
        adj_spring=adj_spring, mold=model.mold, spacing=(2 * model.spacing[0], 2 * model.spacing[1]),
        placement=Placements(tuple((int(st), int(sp_), part[2]) for part, st, sp_ in zip(
            model.placement.parts, cstart[:-1], cstart[1:]))), panel_spacing=2.0 * spacing)
    return coarse, sub
