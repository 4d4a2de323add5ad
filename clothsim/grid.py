"""Model and State, and the lattice builder: nodes, springs, tributary widths, constraint masks.

A :class:`~clothsim.topology.Topology` says which nodes exist and which warp and weft springs
join them; this module gives them their rest lengths, tributary widths and tables, adds the
optional shear, bending and seam families (built only when a scene asks for them: an unused term
costs nothing), and the constraint masks. Springs are stored warp first, then weft (in the
topology's order), then shear, bending and seams. A seam of unequal node counts is not a spring:
it is a set of seam elements (``Model.seam_nodes``, built by
:func:`clothsim.selection.arc_elements`; none when no seam needs them). Grid sequencing's coarse
models come from the same builder on the stride-2 lattice (:func:`coarsen_model`).

Tributary width (paper Fig. 3): a warp spring carries the band of width dy around its row: half
of it (dy/2) on each side where the lattice has a cell, so half on the bottom and top rows of a
rectangle; a weft spring the band of width dx likewise. Spring force = tension [N/m] x width
[m]. A node's area is a quarter of each adjacent cell. The only reader of the scene file above
this module is :mod:`clothsim.compile`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

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
    """Where one panel's flat lattice goes in space at the start.

    origin [m] (3,): the panel's reference corner in its plane (the ``fabric`` sheet's origin);
    size [m] (2,): its extent along and across the grain; grain (2,): its warp direction in its
    plane (None: x); wrap: an object with ``center`` [m], ``axis``, ``radius`` [m] and
    ``start_angle`` [deg] (the panel rolled onto a cylinder, warp round the axis, weft along it,
    centred on ``center``), or None; rotation (3, 3) and translation (3,) [m]: a rigid placement
    (used when wrap is None; None: the identity); hull: a clothsim.hullwrap.HullWrap (the panel
    laid round the hull of a mold's slab), or None."""

    origin: tuple = (0.0, 0.0, 0.0)
    size: tuple = (0.0, 0.0)
    wrap: object = None
    grain: tuple | None = None
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    hull: object = None

    def apply(self, flat: np.ndarray) -> np.ndarray:
        """Points of the flat panel (N, 3) [m] -> their placement in space (N, 3) [m]."""
        if self.hull is not None:
            g = np.asarray(self.grain if self.grain is not None else (1.0, 0.0), float)
            d = flat[:, :2] - np.asarray(self.origin[:2])
            return self.hull.place(d @ g, d @ np.array([-g[1], g[0]]), flat[:, 2] - self.origin[2])
        w = self.wrap
        if w is None:
            if self.rotation is None:
                return flat.copy()
            return flat @ np.asarray(self.rotation).T + np.asarray(self.translation)
        a = np.asarray(w.axis, float)
        a = a / np.linalg.norm(a)
        t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = t - a * (t @ a)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        if self.grain is None:
            u = flat[:, 0] - self.origin[0]
            v = flat[:, 1] - self.origin[1] - self.size[1] / 2
        else:
            g = np.asarray(self.grain, float)
            d = flat[:, :2] - np.asarray(self.origin[:2])
            u = d @ g
            v = d @ np.array([-g[1], g[0]]) - self.size[1] / 2
        r = w.radius + (flat[:, 2] - self.origin[2])
        theta = math.radians(w.start_angle) + u / w.radius
        c = np.asarray(w.center, float)
        return c + r[:, None] * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2) + v[:, None] * a


@dataclass(frozen=True)
class Placements:
    """The placement of every panel: ``parts`` ((start, stop, Placement), ...) over node ranges
    (a panel's nodes are consecutive)."""

    parts: tuple = ()

    def apply(self, flat: np.ndarray) -> np.ndarray:
        """Flat lattice points (N, 3) [m] -> their placement in space (N, 3) [m]."""
        if len(self.parts) == 1:
            return self.parts[0][2].apply(flat)
        out = np.empty_like(flat)
        for a, b, pl in self.parts:
            out[a:b] = pl.apply(flat[a:b])
        return out

    @property
    def identity(self) -> bool:
        """True when every panel stays where its flat lattice is (no wrap, no rigid motion)."""
        return all(pl.wrap is None and pl.rotation is None and pl.hull is None for _, _, pl in self.parts)

    @property
    def size(self) -> tuple:
        """The largest panel extent (2,) [m]."""
        return tuple(np.max([pl.size for _, _, pl in self.parts], axis=0)) if self.parts else (0.0, 0.0)


@dataclass(frozen=True)
class PanelBuild:
    """One panel as the builder takes it: geometry (clothsim.panels.PanelGeometry), its warp and
    weft Tables [N/m], its Placement, and z [m]: the height of its flat lattice."""

    geometry: object
    warp_table: Table
    weft_table: Table
    placement: Placement
    z: float = 0.0


def rotation_matrix(degrees) -> np.ndarray:
    """(3, 3): rotate about x, then y, then z by the given angles [deg]."""
    ax, ay, az = (math.radians(float(d)) for d in degrees)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class SeamInfo:
    """One seam of a model, for reports: a_length, b_length [m] the rest arc lengths of its two
    sides; springs: indices of its zero-length springs (sides of equal node counts) into the
    model's springs; elements: indices of its seam elements (unequal counts) into
    ``Model.seam_nodes``."""

    a_length: float
    b_length: float
    springs: np.ndarray
    elements: np.ndarray

    @property
    def ease(self) -> float:
        """How much longer the longer side is than the shorter [%]."""
        lo, hi = sorted((self.a_length, self.b_length))
        return 100.0 * (hi - lo) / lo if lo > 0 else math.inf


def _empty(shape, dtype=float):
    return field(default_factory=lambda: np.zeros(shape, dtype))


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
    None; spacing [m] (dx, dy) of the lattice (the smallest over panels); panel_spacing (P, 2)
    [m] each panel's; placement: where each panel's flat lattice starts in space.
    Seam elements (seams of unequal node counts, clothsim.kernels.seam_forces_and_energy):
    seam_nodes (Q,K) int64, seam_weight (Q,K) the gap's coefficients, seam_stiffness (Q,)
    [N/m]; Q = 0 when the scene has none (each element's first node is the node it sews, with
    weight 1). seams: one SeamInfo per scene seam.
    friction_mu: the scene's Coulomb coefficient between fabric and mold (``mold.friction``; 0:
    frictionless); friction: the frozen friction of the load step being solved (a
    clothsim.friction.FrictionLag, set by the frictional load steps; None: no friction force)."""

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
    placement: Placements = Placements()
    panel_spacing: np.ndarray | None = None
    seam_nodes: np.ndarray = _empty((0, 1), np.int64)
    seam_weight: np.ndarray = _empty((0, 1))
    seam_stiffness: np.ndarray = _empty(0)
    seams: tuple = ()
    friction_mu: float = 0.0
    friction: object = None

    @property
    def seam_count(self) -> int:
        """Q: seam elements (0 unless a seam joins sides of unequal node counts)."""
        return int(self.seam_nodes.shape[0])

    def seam_args(self) -> tuple:
        """The seam element arrays in the order the kernels take them."""
        return self.seam_nodes, self.seam_weight, self.seam_stiffness

    def add_seam_forces(self, pos: np.ndarray, out: np.ndarray) -> float:
        """Adds the seam elements' forces [N] into out (N,3); returns their energy [J] (0 and
        nothing done when there are none)."""
        if not self.seam_nodes.shape[0]:
            return 0.0
        from .kernels import seam_forces_and_energy

        return seam_forces_and_energy(pos, self.seam_nodes, self.seam_weight, self.seam_stiffness, out)

    def add_friction_forces(self, pos: np.ndarray, out: np.ndarray) -> float:
        """Adds the frozen friction's forces [N] into out (N,3); returns its dissipation
        potential [J] (0 and nothing done without friction)."""
        f = self.friction
        if f is None:
            return 0.0
        from .contact import friction_forces_energy

        return friction_forces_energy(pos, f.nodes, f.anchor, f.normal, f.weight, f.eps, out)

    def seam_gaps(self, pos: np.ndarray) -> list:
        """Per seam (in scene order) its gaps [m] at positions pos (N,3): the zero-length
        springs' lengths, and for a seam of unequal counts each element's |g| (the distance from
        its node to the point of the other side it is sewn to)."""
        from .kernels import seam_gaps

        g = np.empty(self.seam_count)
        if g.size:
            seam_gaps(pos, self.seam_nodes, self.seam_weight, g)
        out = []
        for info in self.seams:
            ab = self.spring_nodes[info.springs]
            out.append(np.concatenate([np.linalg.norm(pos[ab[:, 1]] - pos[ab[:, 0]], axis=1), g[info.elements]]))
        return out

    def seam_points(self, pos: np.ndarray) -> np.ndarray:
        """(P, 2, 3) [m]: the two ends of every seam spring, and every seam element's node and
        the point of the other side it is sewn to (x - g), for drawing."""
        ab = self.spring_nodes[self.spring_family == FAMILY_SEAM]
        a = [pos[ab[:, 0]]]
        b = [pos[ab[:, 1]]]
        if self.seam_count:
            x = pos[self.seam_nodes[:, 0]]
            a.append(x)
            b.append(x - (self.seam_weight[:, :, None] * pos[self.seam_nodes]).sum(axis=1))
        return np.stack([np.concatenate(a), np.concatenate(b)], axis=1)

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
    for fam, pairs, frac_name, l_axis, w_axis in ((FAMILY_WARP, topology.warp, "warp_frac", 0, 1),
                                                  (FAMILY_WEFT, topology.weft, "weft_frac", 1, 0)):
        rest, width, table = [], [], []
        for p, (g, idx) in enumerate(zip(geometries, topology.index)):
            exists = (idx[:-1, :] >= 0) & (idx[1:, :] >= 0) if fam == FAMILY_WARP else (idx[:, :-1] >= 0) & (idx[:, 1:] >= 0)
            frac = getattr(g, frac_name)[exists]
            rest.append(np.full(frac.size, g.spacing[l_axis]))
            width.append(frac * g.spacing[w_axis])
            table.append(np.full(frac.size, table_ids[p][fam], np.int64))
        sp.add(pairs[:, 0], pairs[:, 1], np.concatenate(rest), np.concatenate(width), np.concatenate(table), fam)
    if shear_table is not None:
        # both diagonals of every cell; stiffness is per width across the diagonal: each diagonal
        # carries half the cell (the part of it inside the outline), across its length
        l0, w = [], []
        for g, idx in zip(geometries, topology.index):
            dx, dy = g.spacing
            diag = math.hypot(dx, dy)
            have = (idx[:-1, :-1] >= 0) & (idx[1:, :-1] >= 0) & (idx[1:, 1:] >= 0) & (idx[:-1, 1:] >= 0)
            l0.append(np.full(int(have.sum()), diag))
            w.append(g.cell_frac[have] * (0.5 * dx * dy / diag))
        c = topology.cells
        l0, w = np.concatenate(l0), np.concatenate(w)
        sp.add(c[:, 0], c[:, 2], l0, w, shear_table, FAMILY_SHEAR)
        sp.add(c[:, 1], c[:, 3], l0, w, shear_table, FAMILY_SHEAR)
    if bend_table is not None:
        # skip-one springs along warp (i, j)-(i+2, j) and weft (i, j)-(i, j+2), with the band
        # width of the warp (weft) spring they span first
        for along, fam in ((0, FAMILY_BEND_WARP), (1, FAMILY_BEND_WEFT)):
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
                l_.append(np.full(int(keep.sum()), 2 * g.spacing[along]))
            if a_:
                sp.add(np.concatenate(a_), np.concatenate(b_), np.concatenate(l_), np.concatenate(w_), bend_table, fam)
    return sp


def build_model(*, panels: list, constraints=(), shear_stiffness: float | None = None,
                bending_stiffness: float | None = None, gravity=None, seams=(), mold=None) -> Model:
    """The constant arrays of a lattice of panels (see the module docstring).

    panels: PanelBuild records (geometry, tables, placement, z), one per panel, in order;
    constraints: objects with ``nodes`` (a selector), ``axes``, ``stretch`` and ``displacement``
    [m]; shear_stiffness / bending_stiffness [N/m] or None; gravity: an object with
    ``areal_density`` [kg/m^2], ``g`` [m/s^2] and ``direction``, or None; seams: objects with
    ``a``, ``b``, ``reverse`` and ``stiffness`` [N/m^2] (None = the default); mold: a loaded Mold
    or None. A selector that selects nothing valid raises SelectionError naming its field
    (``constraints.N.nodes: ...``, ``seams.N.a: ...``)."""
    from .selection import SelectionError, arc_elements, seam_pairs, seam_sides, select_nodes

    geoms = [p.geometry for p in panels]
    topology = Topology.from_masks([g.mask for g in geoms], [g.name for g in geoms],
                                   outlines=[g.outline_lattice for g in geoms])
    n = topology.node_count
    rest = np.empty((n, 3))
    tables: list = []
    table_ids = []

    def table_id(t):
        for k, u in enumerate(tables):
            if u is t:
                return k
        tables.append(t)
        return len(tables) - 1

    starts = np.searchsorted(topology.node_panel, np.arange(len(panels) + 1))
    for p, pb in enumerate(panels):
        g = pb.geometry
        rest[starts[p]:starts[p + 1], :2] = g.to_plane(topology.node_ij[starts[p]:starts[p + 1]])
        rest[starts[p]:starts[p + 1], 2] = pb.z
        table_ids.append((table_id(pb.warp_table), table_id(pb.weft_table)))
    shear_tid = bend_tid = None
    if shear_stiffness is not None:
        tables.append(Table.linear(shear_stiffness, compression=True))
        shear_tid = len(tables) - 1
    if bending_stiffness is not None:
        tables.append(Table.linear(bending_stiffness, compression=True))
        bend_tid = len(tables) - 1
    sp = lattice_springs(topology, geoms, table_ids, shear_table=shear_tid, bend_table=bend_tid)

    seam_infos = []
    el_nodes, el_weight, el_k = [], [], []
    if seams:
        tables.append(Table(np.array([0.0, 1.0]), np.array([1.0, 2.0]), compression=True))
        tid = len(tables) - 1
        h_min = min(min(g.spacing) for g in geoms)
        l0 = SEAM_REST_RATIO * h_min
        slope = max(float(np.max(np.diff(t.tension) / np.diff(t.strain)))
                    for pb in panels for t in (pb.warp_table, pb.weft_table))
        n_springs = sum(x.shape[0] for x in sp.nodes)
        n_elements = 0
        for n_seam, seam in enumerate(seams):
            k_line = seam.stiffness if seam.stiffness is not None else 1000.0 * max(slope, 1e-300) / h_min
            try:
                a_all, b_all, _ = seam_sides(seam, topology)
                if a_all.size != b_all.size:
                    dense_is_a, enodes, eweight, share, la, lb = arc_elements(rest[a_all], rest[b_all])
                else:
                    a, b, share, (sa, sb) = seam_pairs(seam, topology)
            except SelectionError as exc:
                raise SelectionError(f"seams.{n_seam}.{exc}") from None
            arc = [float(np.linalg.norm(np.diff(rest[x], axis=0), axis=1).sum()) for x in (a_all, b_all)]
            if a_all.size != b_all.size:
                # one element per node of the denser side (selection.arc_elements)
                both = np.concatenate([a_all, b_all] if dense_is_a else [b_all, a_all])
                el_nodes.append(both[enodes])
                el_weight.append(eweight)
                el_k.append(k_line * share * 0.5 * (la + lb))  # [N/m] per element
                seam_infos.append(SeamInfo(arc[0], arc[1], np.zeros(0, np.int64),
                                           np.arange(n_elements, n_elements + share.size)))
                n_elements += share.size
                continue
            side = [sa, sb]
            for k, (nodes, s) in enumerate(((a, sa), (b, sb))):
                if isinstance(s, tuple):  # (panel, direction 0/1): the lattice spacing
                    side[k] = geoms[s[0]].spacing[s[1]]
                else:  # along an outline edge: the mean distance between its nodes
                    d = np.linalg.norm(np.diff(rest[s], axis=0), axis=1)
                    side[k] = float(d.mean()) if d.size else h_min
            # the pair's share of the seam length [m], averaged over the two sides
            length = share * 0.5 * (side[0] + side[1])
            k = k_line * length  # [N/m] per pair
            sp.add(a, b, l0, k * l0, tid, FAMILY_SEAM)
            seam_infos.append(SeamInfo(arc[0], arc[1], np.arange(n_springs, n_springs + a.size), np.zeros(0, np.int64)))
            n_springs += a.size
    seam_extra = {}
    if el_nodes:
        # rows padded to the widest element (repeating the first node, weight 0)
        K = max(x.shape[1] for x in el_nodes)
        el_nodes = [np.concatenate([x, np.repeat(x[:, :1], K - x.shape[1], 1)], 1) for x in el_nodes]
        el_weight = [np.concatenate([x, np.zeros((x.shape[0], K - x.shape[1]))], 1) for x in el_weight]
        seam_extra = dict(seam_nodes=np.ascontiguousarray(np.concatenate(el_nodes), np.int64),
                          seam_weight=np.ascontiguousarray(np.concatenate(el_weight)),
                          seam_stiffness=np.ascontiguousarray(np.concatenate(el_k)))

    spring_nodes, rest_len, width, table, family = sp.arrays()
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    node_area = np.concatenate([g.node_frac[g.mask] * (g.spacing[0] * g.spacing[1]) for g in geoms])

    ext = np.zeros((n, 3))
    if gravity is not None:
        d = np.asarray(gravity.direction, float)
        d = d / np.linalg.norm(d)
        ext[:] = (gravity.areal_density * gravity.g * node_area)[:, None] * d[None, :]

    fixed = np.zeros((n, 3), bool)
    flat = rest.copy()
    shift = np.zeros((n, 3))
    # stretch is about each panel's centre, along its grain and across it
    centre = np.empty((n, 2))
    grain = np.empty((n, 2))
    for p, pb in enumerate(panels):
        pl, g = pb.placement, pb.geometry
        gr = np.asarray(g.grain, float)
        c = np.array([pl.origin[0], pl.origin[1]]) + pl.size[0] / 2 * gr + pl.size[1] / 2 * np.array([-gr[1], gr[0]])
        centre[starts[p]:starts[p + 1]] = c
        grain[starts[p]:starts[p + 1]] = gr
    for n_c, c in enumerate(constraints):
        try:
            m = select_nodes(c.nodes, topology)
        except SelectionError as exc:
            raise SelectionError(f"constraints.{n_c}.nodes: {exc}") from None
        for ax in c.axes:
            fixed[m, "xyz".index(ax)] = True
        if c.stretch is not None:
            s = np.array([c.stretch, c.stretch] if isinstance(c.stretch, (int, float)) else c.stretch, float)
            # scaled along the grain and across it (on an x grain: (flat - centre) * s, exactly)
            d = flat[m, :2] - centre[m]
            g = grain[m]
            gp = np.stack([-g[:, 1], g[:, 0]], 1)
            u = (d * g).sum(1) * s[0]
            v = (d * gp).sum(1) * s[1]
            flat[m, :2] = centre[m] + u[:, None] * g + v[:, None] * gp
        if c.displacement is not None:
            shift[m] += np.asarray(c.displacement, float)
    # stretch acts in the panels' own planes, then each panel is placed (flat, rigidly moved or
    # wrapped), then displacements act in space
    placement = Placements(tuple((int(starts[p]), int(starts[p + 1]), pb.placement) for p, pb in enumerate(panels)))
    prescribed = placement.apply(flat) + shift
    spacing = np.array([g.spacing for g in geoms], float)

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
        spacing=(float(spacing[:, 0].min()), float(spacing[:, 1].min())),
        placement=placement,
        panel_spacing=spacing,
        seams=tuple(seam_infos),
        **seam_extra,
    )


def _coarse_seams(model, fam, sub, n: int, sp) -> None:
    """Adds to the coarse spring set ``sp`` the seam pairs of ``model`` whose two nodes are both
    kept (``sub`` (n,): the fine index of each coarse node); each carries the seam length of two
    fine pairs (twice the width, so twice the stiffness)."""
    seam = fam == FAMILY_SEAM
    if not seam.any():
        return
    cmap = -np.ones(model.node_count, np.int64)
    cmap[sub] = np.arange(n)
    ca = cmap[model.spring_nodes[seam, 0]]
    cb = cmap[model.spring_nodes[seam, 1]]
    keep = (ca >= 0) & (cb >= 0)
    if keep.any():
        sp.add(ca[keep], cb[keep], model.spring_rest_length[seam][keep], 2.0 * model.spring_width[seam][keep],
               model.spring_table[seam][keep], FAMILY_SEAM)


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
    from .panels import rectangle_geometry

    ctopo, sub = topo.coarsen()
    dx, dy = 2 * model.spacing[0], 2 * model.spacing[1]
    cgeom = rectangle_geometry(ctopo.names[0], nx // 2, ny // 2, dx, dy)
    n = ctopo.node_count
    fam = model.spring_family

    def tid(f):
        sel = fam == f
        return int(model.spring_table[sel][0]) if sel.any() else None

    bend = tid(FAMILY_BEND_WARP)
    bend = bend if bend is not None else tid(FAMILY_BEND_WEFT)
    sp = lattice_springs(ctopo, [cgeom], [(tid(FAMILY_WARP), tid(FAMILY_WEFT))], shear_table=tid(FAMILY_SHEAR),
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
    if np.any((fam != FAMILY_WARP) & (fam != FAMILY_WEFT) & (fam != FAMILY_SEAM)):
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
    for f, pairs, axis in ((FAMILY_WARP, ctopo.warp, 0), (FAMILY_WEFT, ctopo.weft, 1)):
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
