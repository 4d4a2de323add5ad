"""Model and State, and the lattice builder: nodes, springs, tributary widths, constraint masks.

A :class:`~clothsim.topology.Topology` says which nodes exist and which warp and weft springs
join them; this module gives them their rest lengths, tributary widths and tables, adds the
optional shear, bending and seam families (built only when a scene asks for them: an unused term
costs nothing), and the constraint masks. Springs are stored warp first, then weft (in the
topology's order), then shear, bending and seams. Grid sequencing's coarse models come from the
same builder on the stride-2 lattice (:func:`coarsen_model`).

Tributary width (paper Fig. 3): a warp spring carries the band of width dy around its row: half
of it (dy/2) on each side where the lattice has a cell, so half on the bottom and top rows of a
rectangle; a weft spring the band of width dx likewise. Spring force = tension [N/m] x width
[m]. A node's area is a quarter of each adjacent cell. The only reader of the scene file above
this module is :mod:`clothsim.compile`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .material import Table, TablePack
from .topology import Topology

FAMILY_WARP, FAMILY_WEFT, FAMILY_SHEAR, FAMILY_BEND_WARP, FAMILY_BEND_WEFT, FAMILY_SEAM = 0, 1, 2, 3, 4, 5

#: rest length of a seam spring, relative to the smaller grid spacing. A seam is a zero-length
#: linear spring (force k * gap); the kernels' spring model (force = T(l/l0 - 1) * w) represents it
#: exactly with the table T(s) = 1 + s [N/m] (compression allowed) and width w = k * l0, since
#: then force = k * l and energy = k (l^2 - l0^2) / 2. l0 only has to be positive; keeping it
#: tiny makes the paper's "elongation" l - l0 of a seam its gap.
SEAM_REST_RATIO = 1e-6


@dataclass(frozen=True)
class Placement:
    """Where the flat sheet goes in space at the start: unchanged (``wrap`` None), or rolled onto a
    cylinder (warp x runs round the axis, weft y along it, centred on ``center``).

    origin [m] (3,) and size [m] (2,): the flat sheet's origin and extent; wrap: an object with
    ``center`` [m], ``axis``, ``radius`` [m] and ``start_angle`` [deg], or None."""

    origin: tuple = (0.0, 0.0, 0.0)
    size: tuple = (0.0, 0.0)
    wrap: object = None

    def apply(self, flat: np.ndarray) -> np.ndarray:
        """Points of the flat sheet (N, 3) [m] -> their placement in space (N, 3) [m]."""
        w = self.wrap
        if w is None:
            return flat.copy()
        a = np.asarray(w.axis, float)
        a = a / np.linalg.norm(a)
        t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = t - a * (t @ a)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        u = flat[:, 0] - self.origin[0]
        v = flat[:, 1] - self.origin[1] - self.size[1] / 2
        r = w.radius + (flat[:, 2] - self.origin[2])
        theta = math.radians(w.start_angle) + u / w.radius
        c = np.asarray(w.center, float)
        return c + r[:, None] * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2) + v[:, None] * a


@dataclass(frozen=True)
class Model:
    """Constant arrays of a scene (MuJoCo's model/data split: the State changes, this does not).

    topology: the lattice (:class:`~clothsim.topology.Topology`: nodes, warp/weft pairs, faces).
    node_count: N. rest_positions [m] (N,3): the flat sheet.
    spring_nodes (S,2) int64; spring_rest_length [m] (S,); spring_width [m] (S,) tributary width
    (force = tension [N/m] x width); spring_table (S,) int64 index into ``tables``;
    spring_family (S,) int8 (0 warp, 1 weft, 2 shear, 3/4 bending, 5 seam); fixed_axes (N,3) bool;
    prescribed_positions [m] (N,3) (the constrained coordinates' values); prescribed_flat [m]
    (N,3) the same in the flat sheet's own coordinates before placement and displacement (stretch
    only; used to build the initial guess); external_force [N]
    (N,3) constant (gravity; zeros when off); node_area [m^2] (N,) tributary area of each node;
    node adjacency in CSR form: adj_ptr (N+1,), adj_node, adj_spring; mold: clothsim.mold.Mold or
    None; spacing [m] (dx, dy) of the lattice; placement: where the flat sheet starts in space."""

    node_count: int
    topology: Topology
    rest_positions: np.ndarray
    spring_nodes: np.ndarray
    spring_rest_length: np.ndarray
    spring_width: np.ndarray
    spring_table: np.ndarray
    spring_family: np.ndarray
    tables: TablePack
    table_list: tuple
    fixed_axes: np.ndarray
    prescribed_positions: np.ndarray
    external_force: np.ndarray
    node_area: np.ndarray
    adj_ptr: np.ndarray
    adj_node: np.ndarray
    adj_spring: np.ndarray
    mold: object = None
    spacing: tuple[float, float] = (0.0, 0.0)
    prescribed_flat: np.ndarray | None = None
    placement: Placement = Placement()

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(nx+1, ny+1) of a one-panel full rectangle (see Topology.grid_shape)."""
        return self.topology.grid_shape

    @property
    def warp_count(self) -> int:
        """Warp springs, stored first."""
        return self.topology.warp_count

    @property
    def weft_count(self) -> int:
        """Weft springs, stored after the warp springs."""
        return self.topology.weft_count

    @property
    def spring_count(self) -> int:
        return int(self.spring_nodes.shape[0])

    def spring_args(self) -> tuple:
        """The spring arrays in the order the kernels take them."""
        t = self.tables
        return (self.spring_nodes, self.spring_rest_length, self.spring_width, self.spring_table,
                t.x, t.y, t.cum, t.start, t.compression)

    def adjacency_args(self) -> tuple:
        t = self.tables
        return (self.adj_ptr, self.adj_node, self.adj_spring, self.spring_rest_length,
                self.spring_width, self.spring_table, t.x, t.y, t.cum, t.start, t.compression)


@dataclass
class State:
    """What a solver changes: positions [m] (N,3), in_contact (N,) bool, iteration count."""

    positions: np.ndarray
    in_contact: np.ndarray
    iteration: int = 0

    def copy(self) -> "State":
        return State(self.positions.copy(), self.in_contact.copy(), self.iteration)


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


def _cells(idx: np.ndarray) -> np.ndarray:
    """(nx, ny) bool: the cells of a panel's index grid whose four corners exist."""
    return (idx[:-1, :-1] >= 0) & (idx[1:, :-1] >= 0) & (idx[1:, 1:] >= 0) & (idx[:-1, 1:] >= 0)


def _band_width(cells: np.ndarray, h: float, along: int) -> np.ndarray:
    """Tributary width of the springs running along lattice direction ``along`` (0: warp, 1:
    weft): h/2 from each side where the lattice has a cell; shape (nx, ny+1) for warp, (nx+1, ny)
    for weft."""
    c = cells if along == 0 else cells.T
    pad = np.zeros((c.shape[0], c.shape[1] + 2), bool)
    pad[:, 1:-1] = c
    w = 0.5 * h * pad[:, :-1] + 0.5 * h * pad[:, 1:]
    return w if along == 0 else w.T


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


def lattice_springs(topology: Topology, dx: float, dy: float, *, warp_table: int = 0, weft_table: int = 1,
                    shear_table: int | None = None, bend_table: int | None = None) -> _Springs:
    """The warp and weft springs of a lattice with spacing dx, dy [m] (and shear and bending when
    their table ids are given), with their tributary widths (see the module docstring)."""
    sp = _Springs()
    warp_w, weft_w = [], []
    for idx in topology.index:
        cells = _cells(idx)
        w = _band_width(cells, dy, 0)
        warp_w.append(w[(idx[:-1, :] >= 0) & (idx[1:, :] >= 0)])
        w = _band_width(cells, dx, 1)
        weft_w.append(w[(idx[:, :-1] >= 0) & (idx[:, 1:] >= 0)])
    sp.add(topology.warp[:, 0], topology.warp[:, 1], dx, np.concatenate(warp_w), warp_table, FAMILY_WARP)
    sp.add(topology.weft[:, 0], topology.weft[:, 1], dy, np.concatenate(weft_w), weft_table, FAMILY_WEFT)
    if shear_table is not None:
        # both diagonals of every cell; stiffness is per width across the diagonal
        diag = math.hypot(dx, dy)
        wdiag = 0.5 * dx * dy / diag  # each diagonal carries half the cell, across its length
        c = topology.cells
        sp.add(c[:, 0], c[:, 2], diag, wdiag, shear_table, FAMILY_SHEAR)
        sp.add(c[:, 1], c[:, 3], diag, wdiag, shear_table, FAMILY_SHEAR)
    if bend_table is not None:
        # skip-one springs along warp (i, j)-(i+2, j) and weft (i, j)-(i, j+2), with the band
        # width of the warp (weft) spring they span first
        for along, fam in ((0, FAMILY_BEND_WARP), (1, FAMILY_BEND_WEFT)):
            a_, b_, w_ = [], [], []
            for idx in topology.index:
                cells = _cells(idx)
                if along == 0 and idx.shape[0] >= 3:
                    a, m, b = idx[:-2, :], idx[1:-1, :], idx[2:, :]
                    band = _band_width(cells, dy, 0)[:-1, :]
                elif along == 1 and idx.shape[1] >= 3:
                    a, m, b = idx[:, :-2], idx[:, 1:-1], idx[:, 2:]
                    band = _band_width(cells, dx, 1)[:, :-1]
                else:
                    continue
                keep = (a >= 0) & (m >= 0) & (b >= 0)
                a_.append(a[keep]); b_.append(b[keep]); w_.append(band[keep])
            if a_:
                h = dx if along == 0 else dy
                sp.add(np.concatenate(a_), np.concatenate(b_), 2 * h, np.concatenate(w_), bend_table, fam)
    return sp


def lattice_node_area(topology: Topology, dx: float, dy: float) -> np.ndarray:
    """Rest tributary area [m^2] (N,) of each node: a quarter of each adjacent cell."""
    q = 0.25 * dx * dy
    n = topology.node_count
    count = np.zeros(n)
    for corner in range(4):
        count += np.bincount(topology.cells[:, corner], minlength=n)
    return count * q


def build_model(*, topology: Topology, spacing: tuple[float, float], origin, tables: list,
                constraints=(), placement: Placement | None = None, shear_stiffness: float | None = None,
                bending_stiffness: float | None = None, gravity=None, seams=(), mold=None) -> Model:
    """The constant arrays of a lattice (see the module docstring).

    topology: the lattice; spacing (dx, dy) [m]; origin (3,) [m] of node (0, 0) of the flat sheet;
    tables: [warp, weft] tension Tables [N/m]; constraints: objects with ``nodes`` (a selector),
    ``axes``, ``stretch`` and ``displacement`` [m]; placement: where the flat sheet starts;
    shear_stiffness / bending_stiffness [N/m] or None; gravity: an object with ``areal_density``
    [kg/m^2], ``g`` [m/s^2] and ``direction``, or None; seams: objects with ``a``, ``b``,
    ``reverse`` and ``stiffness`` [N/m^2] (None = the default); mold: a loaded Mold or None."""
    from .selection import seam_pairs, select_nodes

    dx, dy = spacing
    ox, oy, oz = origin
    placement = placement if placement is not None else Placement(tuple(origin), (0.0, 0.0), None)
    ij = topology.node_ij
    n = topology.node_count
    rest = np.stack([ox + ij[:, 0] * dx, oy + ij[:, 1] * dy, np.full(n, oz, float)], -1)

    warp_table, weft_table = tables
    tables = [warp_table, weft_table]
    shear_tid = bend_tid = None
    if shear_stiffness is not None:
        tables.append(Table.linear(shear_stiffness, compression=True))
        shear_tid = len(tables) - 1
    if bending_stiffness is not None:
        tables.append(Table.linear(bending_stiffness, compression=True))
        bend_tid = len(tables) - 1
    sp = lattice_springs(topology, dx, dy, shear_table=shear_tid, bend_table=bend_tid)

    if seams:
        tables.append(Table(np.array([0.0, 1.0]), np.array([1.0, 2.0]), compression=True))
        tid = len(tables) - 1
        l0 = SEAM_REST_RATIO * min(dx, dy)
        slope = max(float(np.max(np.diff(t.tension) / np.diff(t.strain))) for t in (warp_table, weft_table))
        for seam in seams:
            a, b, share, (da, db) = seam_pairs(seam, topology)
            # the pair's share of the seam length [m], averaged over the two sides
            length = share * 0.5 * ((dx if da == 0 else dy) + (dx if db == 0 else dy))
            k_line = seam.stiffness if seam.stiffness is not None else 1000.0 * max(slope, 1e-300) / min(dx, dy)
            k = k_line * length  # [N/m] per pair
            sp.add(a, b, l0, k * l0, tid, FAMILY_SEAM)

    spring_nodes, rest_len, width, table, family = sp.arrays()
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    node_area = lattice_node_area(topology, dx, dy)

    ext = np.zeros((n, 3))
    if gravity is not None:
        d = np.asarray(gravity.direction, float)
        d = d / np.linalg.norm(d)
        ext[:] = (gravity.areal_density * gravity.g * node_area)[:, None] * d[None, :]

    fixed = np.zeros((n, 3), bool)
    flat = rest.copy()
    shift = np.zeros((n, 3))
    # stretch is about the sheet's centre
    centre = np.array([ox + placement.size[0] / 2, oy + placement.size[1] / 2])
    for c in constraints:
        m = select_nodes(c.nodes, topology)
        for ax in c.axes:
            fixed[m, "xyz".index(ax)] = True
        if c.stretch is not None:
            s = np.array([c.stretch, c.stretch] if isinstance(c.stretch, (int, float)) else c.stretch, float)
            flat[m, :2] = centre + (flat[m, :2] - centre) * s
        if c.displacement is not None:
            shift[m] += np.asarray(c.displacement, float)
    # stretch acts in the sheet's own coordinates, then the sheet is placed (flat or wrapped),
    # then displacements act in space
    prescribed = placement.apply(flat) + shift

    return Model(
        node_count=n,
        topology=topology,
        rest_positions=rest,
        spring_nodes=spring_nodes,
        spring_rest_length=rest_len,
        spring_width=width,
        spring_table=table,
        spring_family=family,
        tables=TablePack.from_tables(tables),
        table_list=tuple(tables),
        fixed_axes=fixed,
        prescribed_positions=np.ascontiguousarray(prescribed),
        prescribed_flat=flat,
        external_force=ext,
        node_area=node_area,
        adj_ptr=ptr,
        adj_node=adj_node,
        adj_spring=adj_spring,
        mold=mold,
        spacing=(dx, dy),
        placement=placement,
    )


def coarsen_model(model: Model):
    """The same scene on the stride-2 lattice (``Topology.coarsen``), built by the same spring
    builder with twice the spacing: (coarse model, sub) where sub (Nc,) are the nodes of
    ``model`` the coarse lattice keeps; (None, None) unless the lattice is a full rectangle with
    even divisions of at least 4 (what grid sequencing interpolates between)."""
    topo = model.topology
    if not topo.is_grid:
        return None, None
    nx1, ny1 = topo.grid_shape
    nx, ny = nx1 - 1, ny1 - 1
    if nx % 2 or ny % 2 or nx < 4 or ny < 4:
        return None, None
    ctopo, sub = topo.coarsen()
    dx, dy = 2 * model.spacing[0], 2 * model.spacing[1]
    n = ctopo.node_count
    fam = model.spring_family

    def tid(f):
        sel = fam == f
        return int(model.spring_table[sel][0]) if sel.any() else None

    bend = tid(FAMILY_BEND_WARP)
    bend = bend if bend is not None else tid(FAMILY_BEND_WEFT)
    sp = lattice_springs(ctopo, dx, dy, warp_table=tid(FAMILY_WARP), weft_table=tid(FAMILY_WEFT),
                         shear_table=tid(FAMILY_SHEAR), bend_table=bend)
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
            sp.add(ca[keep], cb[keep], model.spring_rest_length[seam][keep], 2.0 * model.spring_width[seam][keep],
                   model.spring_table[seam][keep], FAMILY_SEAM)
    spring_nodes, rest_len, width, table, family = sp.arrays()
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    area = lattice_node_area(ctopo, dx, dy)
    fine_area = model.node_area[sub]
    ext = model.external_force[sub] * (area / np.where(fine_area > 0, fine_area, 1.0))[:, None]
    coarse = Model(
        node_count=n, topology=ctopo, rest_positions=model.rest_positions[sub].copy(), spring_nodes=spring_nodes,
        spring_rest_length=rest_len, spring_width=width, spring_table=table, spring_family=family,
        tables=model.tables, table_list=model.table_list,
        fixed_axes=np.ascontiguousarray(model.fixed_axes[sub]),
        prescribed_positions=np.ascontiguousarray(model.prescribed_positions[sub]),
        external_force=np.ascontiguousarray(ext), node_area=area, adj_ptr=ptr, adj_node=adj_node,
        adj_spring=adj_spring, mold=model.mold, spacing=(dx, dy), placement=model.placement)
    return coarse, sub
