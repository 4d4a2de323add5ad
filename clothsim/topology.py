"""The lattice: which nodes exist, which warp and weft springs join them, and what follows from
that alone — boundaries, display faces, spreading spring values to nodes, coarsening.

A lattice is one or more *panels*; a panel is a boolean mask over its own (i, j) grid, i along
warp and j along weft. A node exists where the mask is true; a warp spring joins (i, j) and
(i+1, j) where both exist, a weft spring (i, j) and (i, j+1). Nodes are numbered panel by panel,
row-major in (i, j) (node (i, j) of a full rectangle is row ``k = i * (ny+1) + j`` of the flat
(N, 3) arrays); warp springs come before weft springs, each in row-major order of their first
node. A full rectangle, a panel cut to an outline, and several panels in one model are the same
data: only the masks differ, so nothing downstream (results, viewer, GLB export, multigrid)
needs to know the lattice's shape — it asks this object.

Coarsening keeps the nodes whose i and j are both even and builds the coarse lattice with the
same constructor (the stride-2 lattice): grid sequencing and multigrid use it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True, eq=False)
class Topology:
    """The lattice of a model (see the module docstring). Build it with :meth:`rectangle` or
    :meth:`from_masks`; it is constant once built.

    masks: one boolean array (nx_p+1, ny_p+1) per panel. names: the panels' names.
    node_panel (N,) int64: the panel of each node; node_ij (N, 2) int64: its lattice indices in
    that panel; index: one int64 array per panel, (nx_p+1, ny_p+1), node number or -1.
    warp (Sw, 2) int64 and weft (Sf, 2) int64: node pairs of the warp and weft springs."""

    masks: tuple
    names: tuple
    node_panel: np.ndarray
    node_ij: np.ndarray
    index: tuple
    warp: np.ndarray
    weft: np.ndarray
    outlines: tuple = ()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_masks(cls, masks, names=None, outlines=None) -> "Topology":
        """The lattice of panels given as boolean masks (nx_p+1, ny_p+1); names default to
        ``panel0``, ``panel1``, ...; outlines: each panel's outline (K, 2) in lattice units
        (counter-clockwise; None for a plain lattice), used to select nodes along outline edges."""
        masks = tuple(np.ascontiguousarray(m, bool) for m in masks)
        if not masks:
            raise ValueError("a lattice needs at least one panel")
        names = tuple(names) if names is not None else tuple(f"panel{p}" for p in range(len(masks)))
        index, panel, ij, warp, weft = [], [], [], [], []
        offset = 0
        for p, m in enumerate(masks):
            if m.ndim != 2:
                raise ValueError(f"panel {names[p]}: mask must be 2-D, got shape {m.shape}")
            idx = -np.ones(m.shape, np.int64)
            ii, jj = np.nonzero(m)  # row-major: i, then j
            idx[ii, jj] = offset + np.arange(ii.size)
            offset += ii.size
            index.append(idx)
            panel.append(np.full(ii.size, p, np.int64))
            ij.append(np.stack([ii, jj], 1).astype(np.int64))
            a, b = idx[:-1, :], idx[1:, :]
            keep = (a >= 0) & (b >= 0)
            warp.append(np.stack([a[keep], b[keep]], 1))
            a, b = idx[:, :-1], idx[:, 1:]
            keep = (a >= 0) & (b >= 0)
            weft.append(np.stack([a[keep], b[keep]], 1))
        return cls(masks=masks, names=names, node_panel=np.concatenate(panel),
                   node_ij=np.concatenate(ij), index=tuple(index),
                   warp=np.concatenate(warp).astype(np.int64).reshape(-1, 2),
                   weft=np.concatenate(weft).astype(np.int64).reshape(-1, 2),
                   outlines=tuple(outlines) if outlines is not None else (None,) * len(masks))

    @classmethod
    def rectangle(cls, nx: int, ny: int, name: str = "fabric") -> "Topology":
        """A full nx x ny-division rectangle: (nx+1) x (ny+1) nodes."""
        return cls.from_masks([np.ones((nx + 1, ny + 1), bool)], [name])

    # ------------------------------------------------------------------ sizes
    @property
    def node_count(self) -> int:
        return int(self.node_ij.shape[0])

    @property
    def warp_count(self) -> int:
        return int(self.warp.shape[0])

    @property
    def weft_count(self) -> int:
        return int(self.weft.shape[0])

    @property
    def panel_count(self) -> int:
        return len(self.masks)

    def panel_index(self, name: str) -> int:
        """The number of the panel called ``name`` (ValueError if none is)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown panel '{name}' (known: {', '.join(self.names)})") from None

    def panel_nodes(self, panel: int) -> np.ndarray:
        """(n_p,) the node numbers of a panel (consecutive)."""
        return np.nonzero(self.node_panel == panel)[0]

    @cached_property
    def is_grid(self) -> bool:
        """True for one full rectangular panel: the case the line-smoothed multigrid, the grid
        sequencing and the (nx+1, ny+1, ...) result arrays are written for."""
        return len(self.masks) == 1 and bool(self.masks[0].all())

    @cached_property
    def panels_full(self) -> bool:
        """True when every panel is a full rectangle (no outline cut across the lattice): grid
        sequencing's coarse lattices then hold every outline exactly, as on one rectangle."""
        return all(bool(m.all()) for m in self.masks)

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(nx+1, ny+1) of a one-panel full rectangle; ValueError for any other lattice."""
        if not self.is_grid:
            raise ValueError("grid_shape: this lattice is not one full rectangle")
        return tuple(int(s) for s in self.masks[0].shape)  # type: ignore[return-value]

    def panel_shape(self, panel: int = 0) -> tuple[int, int]:
        """(nx_p+1, ny_p+1): the extent of a panel's (i, j) grid."""
        return tuple(int(s) for s in self.masks[panel].shape)  # type: ignore[return-value]

    def node(self, i: int, j: int, panel: int = 0) -> int:
        """Node number of (i, j) in a panel, -1 where the lattice has no node."""
        idx = self.index[panel]
        if 0 <= i < idx.shape[0] and 0 <= j < idx.shape[1]:
            return int(idx[i, j])
        return -1

    # ------------------------------------------------------------------ fields
    def to_grid(self, values: np.ndarray, panel: int = 0, fill=np.nan) -> np.ndarray:
        """Per-node values (N, ...) laid out on a panel's grid (nx_p+1, ny_p+1, ...); cells
        without a node hold ``fill``. On a full rectangle this is a plain reshape (a view)."""
        values = np.asarray(values)
        if self.is_grid:
            return values.reshape(self.masks[0].shape + values.shape[1:])
        idx = self.index[panel]
        if values.dtype.kind == "b":
            fill = False
        elif values.dtype.kind in "iu":
            fill = -1
        out = np.full(idx.shape + values.shape[1:], fill, dtype=values.dtype)
        have = idx >= 0
        out[have] = values[idx[have]]
        return out

    def springs_to_grid(self, values: np.ndarray, family: str, panel: int = 0, fill=np.nan) -> np.ndarray:
        """Warp values (Sw,) laid out (nx_p, ny_p+1), or weft values (Sf,) laid out (nx_p+1, ny_p),
        indexed by the spring's first node (i, j); missing springs hold ``fill``."""
        pairs = self.warp if family == "warp" else self.weft
        shape = self.masks[panel].shape
        shape = (shape[0] - 1, shape[1]) if family == "warp" else (shape[0], shape[1] - 1)
        values = np.asarray(values)
        if self.is_grid:
            return values.reshape(shape)
        out = np.full(shape, fill, dtype=float)
        sel = self.node_panel[pairs[:, 0]] == panel
        ij = self.node_ij[pairs[sel, 0]]
        out[ij[:, 0], ij[:, 1]] = values[sel]
        return out

    def spread(self, values: np.ndarray, family: str) -> np.ndarray:
        """Mean of warp (``family='warp'``, values (Sw,)) or weft (values (Sf,)) spring values at
        each node (N,); 0 at a node with no such spring."""
        pairs = self.warp if family == "warp" else self.weft
        n = self.node_count
        v = np.asarray(values, float)
        s = np.bincount(pairs[:, 0], v, n) + np.bincount(pairs[:, 1], v, n)
        c = np.bincount(pairs[:, 0], minlength=n) + np.bincount(pairs[:, 1], minlength=n)
        return s / np.maximum(c, 1)

    # ------------------------------------------------------------------ geometry
    @cached_property
    def cells(self) -> np.ndarray:
        """(C, 4) int64: the lattice cells whose four corners exist, corners (i, j), (i+1, j),
        (i+1, j+1), (i, j+1) (counter-clockwise seen from +z on a flat sheet)."""
        out = []
        for idx in self.index:
            a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
            keep = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
            out.append(np.stack([a[keep], b[keep], c[keep], d[keep]], 1))
        return np.concatenate(out).astype(np.int64).reshape(-1, 4)

    @cached_property
    def faces(self) -> np.ndarray:
        """(2C, 3) int64 display triangles: every cell split along its (i, j)-(i+1, j+1)
        diagonal, all first triangles then all second ones."""
        c = self.cells
        return np.concatenate([c[:, [0, 1, 2]], c[:, [0, 2, 3]]]).astype(np.int64)

    def deformed_node_area(self, positions: np.ndarray) -> np.ndarray:
        """Tributary area [m^2] (N,) of each node on the deformed sheet: a quarter of each
        adjacent cell (a cell's area being that of its two triangles). positions (N, 3) [m]."""
        p = np.asarray(positions)
        c = self.cells
        a, b, cc, d = p[c[:, 0]], p[c[:, 1]], p[c[:, 2]], p[c[:, 3]]
        cell = 0.5 * (np.linalg.norm(np.cross(b - a, cc - a), axis=-1)
                      + np.linalg.norm(np.cross(cc - a, d - a), axis=-1))
        q = 0.25 * cell
        n = self.node_count
        area = np.zeros(n)
        for corner in range(4):  # the corners in a fixed order: the sums do not depend on layout
            area += np.bincount(c[:, corner], q, n)
        return area

    @cached_property
    def boundary(self) -> np.ndarray:
        """(N,) bool: nodes with a missing warp or weft neighbour (the lattice's outline)."""
        out = np.zeros(self.node_count, bool)
        for p, m in enumerate(self.masks):
            pad = np.pad(m, 1)
            inner = m & pad[:-2, 1:-1] & pad[2:, 1:-1] & pad[1:-1, :-2] & pad[1:-1, 2:]
            edge = m & ~inner
            out[self.index[p][edge]] = True
        return out

    # ------------------------------------------------------------------ coarsening
    def grid_prolongation(self):
        """(coarse Topology, P) for a full rectangle: the coarse grid keeps every second node of
        each line and its last one, and P (N, Nc) scipy CSR interpolates bilinearly in the node
        indices (multigrid's transfer; with even divisions the coarse grid is :meth:`coarsen`'s)."""
        import scipy.sparse as sp

        nx1, ny1 = self.grid_shape
        px = _interp_1d(nx1)
        py = _interp_1d(ny1)
        P = sp.kron(px, py, format="csr")
        return Topology.rectangle(px.shape[1] - 1, py.shape[1] - 1, self.names[0]), P

    def coarsen(self) -> tuple["Topology", np.ndarray]:
        """The stride-2 lattice (nodes whose i and j are both even, built by the same
        constructor) and ``sub`` (Nc,) int64: the node of this lattice each coarse node is."""
        masks = tuple(m[::2, ::2] for m in self.masks)
        outlines = tuple(None if o is None else np.asarray(o) / 2 for o in self.outlines)
        coarse = Topology.from_masks(masks, self.names, outlines)
        sub = np.concatenate([idx[::2, ::2][m] for idx, m in zip(self.index, masks)]).astype(np.int64)
        return coarse, sub


    def lattice_prolongation(self, coarse: "Topology", sub: np.ndarray):
        """P (N, Nc) scipy CSR: interpolation from :meth:`coarsen`'s lattice (``coarse``, ``sub``)
        onto this one, for any panels: bilinear in the node indices over the coarse nodes that
        exist (weights renormalised to sum 1); a node none of whose up to four coarse corners
        exists takes the nearest coarse node of its panel (lattice distance). On a full rectangle
        with even divisions it equals :meth:`grid_prolongation`'s P."""
        import scipy.sparse as sp

        n = self.node_count
        rows, cols, vals = [], [], []
        for p in range(self.panel_count):
            cidx = coarse.index[p]
            nodes = self.panel_nodes(p)
            ij = self.node_ij[nodes]
            w = np.zeros(nodes.size)
            cand = []
            for di in (0, 1):
                for dj in (0, 1):
                    ci = ij[:, 0] // 2 + di * (ij[:, 0] % 2)
                    cj = ij[:, 1] // 2 + dj * (ij[:, 1] % 2)
                    # each distinct corner once: an even index has one corner along that axis
                    dup = ((di == 1) & (ij[:, 0] % 2 == 0)) | ((dj == 1) & (ij[:, 1] % 2 == 0))
                    ok = (ci < cidx.shape[0]) & (cj < cidx.shape[1]) & ~dup
                    c = np.full(nodes.size, -1, np.int64)
                    c[ok] = cidx[ci[ok], cj[ok]]
                    wt = np.where(ij[:, 0] % 2, 0.5, 1.0) * np.where(ij[:, 1] % 2, 0.5, 1.0)
                    wt = np.where(c >= 0, wt, 0.0)
                    cand.append((c, wt))
                    w += wt
            for c, wt in cand:
                k = (c >= 0) & (w > 0)
                rows.append(nodes[k]); cols.append(c[k]); vals.append(wt[k] / w[k])
            lost = w <= 0
            if lost.any():
                cn = coarse.panel_nodes(p)
                cij = 2 * coarse.node_ij[cn]
                d = ((ij[lost][:, None, :] - cij[None, :, :]) ** 2).sum(-1)
                rows.append(nodes[lost]); cols.append(cn[d.argmin(axis=1)]); vals.append(np.ones(int(lost.sum())))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n, coarse.node_count))


def _interp_1d(n: int):
    """Linear interpolation (n, nc) scipy CSR from the coarse node set (every second node, plus
    the last) of a line of n nodes."""
    import scipy.sparse as sp

    coarse = list(range(0, n, 2))
    if coarse[-1] != n - 1:
        coarse.append(n - 1)
    pos = {c: q for q, c in enumerate(coarse)}
    rows, cols, vals = [], [], []
    for i in range(n):
        if i in pos:
            rows.append(i); cols.append(pos[i]); vals.append(1.0)
        else:
            rows += [i, i]; cols += [pos[i - 1], pos[i + 1]]; vals += [0.5, 0.5]
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, len(coarse)))
