"""Scene -> Model: nodes, springs, tributary widths, constraint masks, initial state.

Node (i, j), i along warp (x, 0..nx) and j along weft (y, 0..ny), is row ``k = i * (ny + 1) + j``
of the flat (N, 3) arrays. Springs are stored warp first (``(i, j)-(i+1, j)``, ``nx * (ny+1)`` of
them, warp spring (i, j) at index ``i * (ny+1) + j``), then weft (``(i, j)-(i, j+1)``,
``(nx+1) * ny``, weft spring (i, j) at ``nx*(ny+1) + i * ny + j``), then the optional shear,
bending and seam families, which are only built when the scene asks for them (an unused term
costs nothing).

Tributary width (paper Fig. 3): a warp spring carries the band of width dy around its row, half of
it on the bottom and top rows; a weft spring the band of width dx, half on the left and right
columns. Spring force = tension [N/m] x width [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .config import Scene, SceneError
from .material import Table, TablePack

FAMILY_WARP, FAMILY_WEFT, FAMILY_SHEAR, FAMILY_BEND_WARP, FAMILY_BEND_WEFT, FAMILY_SEAM = 0, 1, 2, 3, 4, 5

#: rest length of a seam spring, relative to the smaller grid spacing. A seam is a zero-length
#: linear spring (force k * gap); the kernels' spring model (force = T(l/l0 - 1) * w) represents it
#: exactly with the table T(s) = 1 + s [N/m] (compression allowed) and width w = k * l0, since
#: then force = k * l and energy = k (l^2 - l0^2) / 2. l0 only has to be positive; keeping it
#: tiny makes the paper's "elongation" l - l0 of a seam its gap.
SEAM_REST_RATIO = 1e-6


@dataclass(frozen=True)
class Model:
    """Constant arrays of a scene (MuJoCo's model/data split: the State changes, this does not).

    node_count: N. grid_shape: (nx+1, ny+1). rest_positions [m] (N,3): the flat sheet.
    spring_nodes (S,2) int64; spring_rest_length [m] (S,); spring_width [m] (S,) tributary width
    (force = tension [N/m] x width); spring_table (S,) int64 index into ``tables``;
    spring_family (S,) int8 (0 warp, 1 weft, 2 shear, 3/4 bending, 5 seam); fixed_axes (N,3) bool;
    prescribed_positions [m] (N,3) (the constrained coordinates' values); prescribed_flat [m]
    (N,3) the same in the flat sheet's own coordinates before placement and displacement (stretch
    only; used to build the initial guess); external_force [N]
    (N,3) constant (gravity; zeros when off); node_area [m^2] (N,) tributary area of each node;
    node adjacency in CSR form: adj_ptr (N+1,), adj_node, adj_spring; mold: clothsim.mold.Mold or
    None."""

    node_count: int
    grid_shape: tuple[int, int]
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
    warp_count: int = 0
    weft_count: int = 0

    def node_index(self, i: int, j: int) -> int:
        return i * self.grid_shape[1] + j

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


def select_nodes(sel, nx: int, ny: int, what: str = "constraints") -> np.ndarray:
    """Boolean mask (nx+1, ny+1) of a node selector (see config.Constraint); ``what`` names the
    field in error messages."""
    m = np.zeros((nx + 1, ny + 1), bool)
    if isinstance(sel, str):
        if sel in ("left", "perimeter"):
            m[0, :] = True
        if sel in ("right", "perimeter"):
            m[nx, :] = True
        if sel in ("bottom", "perimeter"):
            m[:, 0] = True
        if sel in ("top", "perimeter"):
            m[:, ny] = True
        if sel in ("bottom_left", "corners"):
            m[0, 0] = True
        if sel in ("bottom_right", "corners"):
            m[nx, 0] = True
        if sel in ("top_left", "corners"):
            m[0, ny] = True
        if sel in ("top_right", "corners"):
            m[nx, ny] = True
        if sel == "all":
            m[:] = True
        return m

    def rng(r, n, name):
        if r is None:
            return 0, n
        a, b = (r, r) if isinstance(r, int) else r
        a = a + n + 1 if a < 0 else a
        b = b + n + 1 if b < 0 else b
        if not (0 <= a <= b <= n):
            raise SceneError(f"{what}: {name} range {list(r) if not isinstance(r, int) else r} outside 0..{n}")
        return a, b

    ia, ib = rng(sel.i, nx, "i")
    ja, jb = rng(sel.j, ny, "j")
    m[ia:ib + 1, ja:jb + 1] = True
    return m


def _seam_line(sel, nx: int, ny: int, name: str) -> tuple[np.ndarray, int]:
    """Node indices of one seam side in index order, and the grid direction it runs along
    (0: i varies, 1: j varies; 1 for a single node)."""
    ii, jj = np.nonzero(select_nodes(sel, nx, ny, name))
    if ii.size == 0:
        raise SceneError(f"{name}: selects no nodes")
    if ii.size > 1 and not ((ii == ii[0]).all() or (jj == jj[0]).all()):
        raise SceneError(f"{name}: must select one line of nodes (a single i or a single j); it selects "
                         f"{ii.size} nodes over i {ii.min()}..{ii.max()}, j {jj.min()}..{jj.max()}")
    direction = 0 if ii.size > 1 and (jj == jj[0]).all() else 1
    return (ii * (ny + 1) + jj).astype(np.int64), direction


def seam_pairs(seam, nx: int, ny: int):
    """The node pairs a seam (config.Seam) sews: (a (P,), b (P,), tributary length factors (P,)),
    where the factor of a pair is its share of the seam in grid spacings along each side (1 inside,
    1/2 at the ends, averaged over the two sides). Pairs of a node with itself (the tip of a dart)
    are dropped. Raises SceneError naming the side ("a: ..." or "b: ...")."""
    a, da = _seam_line(seam.a, nx, ny, "a")
    b, db = _seam_line(seam.b, nx, ny, "b")
    if a.size != b.size:
        raise SceneError(f"b: selects {b.size} nodes but a selects {a.size}; a seam sews them one to one")
    if seam.reverse:
        b = b[::-1]
    share = np.ones(a.size)
    if a.size > 1:
        share[0] = share[-1] = 0.5
    keep = a != b
    if not keep.any():
        raise SceneError("b: selects the same nodes as a (nothing to sew)")
    return a[keep], b[keep], share[keep], (da, db)


def place_sheet(scene: Scene, flat: np.ndarray) -> np.ndarray:
    """Map points of the flat sheet (N,3) [m] to their initial placement in space: unchanged, or
    rolled onto a cylinder when ``initial.wrap`` is set (warp x runs round the cylinder's axis,
    weft y along it, centred on ``wrap.center``)."""
    w = scene.initial.wrap
    if w is None:
        return flat.copy()
    fab = scene.fabric
    a = np.asarray(w.axis, float)
    a = a / np.linalg.norm(a)
    t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = t - a * (t @ a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    u = flat[:, 0] - fab.origin[0]
    v = flat[:, 1] - fab.origin[1] - fab.size[1] / 2
    r = w.radius + (flat[:, 2] - fab.origin[2])
    theta = math.radians(w.start_angle) + u / w.radius
    c = np.asarray(w.center, float)
    return c + r[:, None] * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2) + v[:, None] * a


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


def build_model(scene: Scene, mold=None) -> Model:
    """Build the constant arrays of a scene. ``mold`` is a loaded clothsim.mold.Mold or None."""
    fab = scene.fabric
    nx, ny = fab.divisions
    lx, ly = fab.size
    dx, dy = lx / nx, ly / ny
    ox, oy, oz = fab.origin
    ii, jj = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    rest = np.stack([ox + ii * dx, oy + jj * dy, np.full(ii.shape, oz, float)], -1).reshape(-1, 3)
    n = rest.shape[0]
    idx = np.arange(n).reshape(nx + 1, ny + 1)

    warp_table, weft_table = scene.tables()
    tables = [warp_table, weft_table]

    nodes, rest_len, width, table, family = [], [], [], [], []

    # warp springs: (i,j)-(i+1,j), width dy (half on bottom/top rows)
    a = idx[:-1, :].ravel()
    b = idx[1:, :].ravel()
    w = np.full((nx, ny + 1), dy)
    w[:, 0] *= 0.5
    w[:, ny] *= 0.5
    nodes.append(np.stack([a, b], 1)); rest_len.append(np.full(a.size, dx)); width.append(w.ravel())
    table.append(np.zeros(a.size, np.int64)); family.append(np.full(a.size, FAMILY_WARP, np.int8))
    # weft springs: (i,j)-(i,j+1), width dx (half on left/right columns)
    a = idx[:, :-1].ravel()
    b = idx[:, 1:].ravel()
    w = np.full((nx + 1, ny), dx)
    w[0, :] *= 0.5
    w[nx, :] *= 0.5
    nodes.append(np.stack([a, b], 1)); rest_len.append(np.full(a.size, dy)); width.append(w.ravel())
    table.append(np.ones(a.size, np.int64)); family.append(np.full(a.size, FAMILY_WEFT, np.int8))

    if scene.shear is not None:
        # both diagonals of every cell; stiffness is per width across the diagonal
        tables.append(Table.linear(scene.shear.stiffness, compression=True))
        tid = len(tables) - 1
        diag = math.hypot(dx, dy)
        wdiag = 0.5 * dx * dy / diag  # each diagonal carries half the cell, across its length
        for a, b in ((idx[:-1, :-1], idx[1:, 1:]), (idx[1:, :-1], idx[:-1, 1:])):
            a = a.ravel(); b = b.ravel()
            nodes.append(np.stack([a, b], 1)); rest_len.append(np.full(a.size, diag))
            width.append(np.full(a.size, wdiag)); table.append(np.full(a.size, tid, np.int64))
            family.append(np.full(a.size, FAMILY_SHEAR, np.int8))
    if scene.bending is not None:
        tables.append(Table.linear(scene.bending.stiffness, compression=True))
        tid = len(tables) - 1
        if nx >= 2:
            a = idx[:-2, :].ravel(); b = idx[2:, :].ravel()
            w = np.full((nx - 1, ny + 1), dy); w[:, 0] *= 0.5; w[:, ny] *= 0.5
            nodes.append(np.stack([a, b], 1)); rest_len.append(np.full(a.size, 2 * dx))
            width.append(w.ravel()); table.append(np.full(a.size, tid, np.int64))
            family.append(np.full(a.size, FAMILY_BEND_WARP, np.int8))
        if ny >= 2:
            a = idx[:, :-2].ravel(); b = idx[:, 2:].ravel()
            w = np.full((nx + 1, ny - 1), dx); w[0, :] *= 0.5; w[nx, :] *= 0.5
            nodes.append(np.stack([a, b], 1)); rest_len.append(np.full(a.size, 2 * dy))
            width.append(w.ravel()); table.append(np.full(a.size, tid, np.int64))
            family.append(np.full(a.size, FAMILY_BEND_WEFT, np.int8))

    if scene.seams:
        tables.append(Table(np.array([0.0, 1.0]), np.array([1.0, 2.0]), compression=True))
        tid = len(tables) - 1
        l0 = SEAM_REST_RATIO * min(dx, dy)
        slope = max(float(np.max(np.diff(t.tension) / np.diff(t.strain))) for t in (warp_table, weft_table))
        for seam in scene.seams:
            a, b, share, (da, db) = seam_pairs(seam, nx, ny)
            # the pair's share of the seam length [m], averaged over the two sides
            length = share * 0.5 * ((dx if da == 0 else dy) + (dx if db == 0 else dy))
            k_line = seam.stiffness if seam.stiffness is not None else 1000.0 * max(slope, 1e-300) / min(dx, dy)
            k = k_line * length  # [N/m] per pair
            nodes.append(np.stack([a, b], 1)); rest_len.append(np.full(a.size, l0))
            width.append(k * l0); table.append(np.full(a.size, tid, np.int64))
            family.append(np.full(a.size, FAMILY_SEAM, np.int8))

    spring_nodes = np.ascontiguousarray(np.concatenate(nodes).astype(np.int64))
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)

    # node tributary areas (for pressure and gravity)
    wx = np.full(nx + 1, dx); wx[0] *= 0.5; wx[-1] *= 0.5
    wy = np.full(ny + 1, dy); wy[0] *= 0.5; wy[-1] *= 0.5
    node_area = np.outer(wx, wy).ravel()

    ext = np.zeros((n, 3))
    if scene.gravity is not None:
        g = scene.gravity
        d = np.asarray(g.direction, float)
        d = d / np.linalg.norm(d)
        ext[:] = (g.areal_density * g.g * node_area)[:, None] * d[None, :]

    fixed = np.zeros((nx + 1, ny + 1, 3), bool)
    flat = rest.reshape(nx + 1, ny + 1, 3).copy()
    shift = np.zeros((nx + 1, ny + 1, 3))
    centre = np.array([ox + lx / 2, oy + ly / 2])
    for c in scene.constraints:
        m = select_nodes(c.nodes, nx, ny)
        for ax in c.axes:
            fixed[m, "xyz".index(ax)] = True
        if c.stretch is not None:
            s = np.array([c.stretch, c.stretch] if isinstance(c.stretch, (int, float)) else c.stretch, float)
            flat[m, :2] = centre + (flat[m, :2] - centre) * s
        if c.displacement is not None:
            shift[m] += np.asarray(c.displacement, float)
    # stretch acts in the sheet's own coordinates, then the sheet is placed (flat or wrapped),
    # then displacements act in space
    prescribed = place_sheet(scene, flat.reshape(-1, 3)) + shift.reshape(-1, 3)

    return Model(
        node_count=n,
        grid_shape=(nx + 1, ny + 1),
        rest_positions=rest,
        spring_nodes=spring_nodes,
        spring_rest_length=np.ascontiguousarray(np.concatenate(rest_len), float),
        spring_width=np.ascontiguousarray(np.concatenate(width), float),
        spring_table=np.ascontiguousarray(np.concatenate(table)),
        spring_family=np.concatenate(family),
        tables=TablePack.from_tables(tables),
        table_list=tuple(tables),
        fixed_axes=fixed.reshape(n, 3),
        prescribed_positions=np.ascontiguousarray(prescribed),
        prescribed_flat=flat.reshape(-1, 3),
        external_force=ext,
        node_area=node_area,
        adj_ptr=ptr,
        adj_node=adj_node,
        adj_spring=adj_spring,
        mold=mold,
        spacing=(dx, dy),
        warp_count=nx * (ny + 1),
        weft_count=(nx + 1) * ny,
    )
