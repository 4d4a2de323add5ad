"""Pattern panels: a warp/weft lattice cut to a panel's outline, with exact tributary areas.

A panel is a closed polygon in its own plane [m] with a grain (the warp direction). Its lattice
runs along the grain with spacing dx (warp) and dy (weft), node (0, 0) at the outline's lower-left
bounding corner in the grain frame. Everything is computed in *lattice units* (cells are unit
squares), where an outline aligned with the lattice gives exact fractions (1/4, 1/2, 1).

How the outline is represented faithfully (the paper's tributary rule, generalised): split every
cell into four quarters, one per corner. The part of the panel a node carries is its *dual cell*
(the four quarters round it) clipped to the outline; a warp spring (i, j)-(i+1, j) carries the
band of the four quarters along it (the upper half of the cell below, the lower half of the cell
above) clipped to the outline, divided by its length; a weft spring likewise. On a rectangle this
is exactly the paper's rule (half width on border springs, a quarter cell at a corner node). Cut
cells carry their true share of width, so the membrane's stiffness (sum of width x length = the
panel's area, in each yarn direction) does not depend on where the lattice crosses the outline,
and the node areas sum to the polygon's area (tested to 1e-12 relative). A node exists where its
dual cell holds area; a spring where both its nodes exist and its band holds area. A node left
without a spring (a sliver of the outline under a quarter cell) hands its area to the nearest
node of the panel, so nothing is lost.

Quarters wholly inside or outside the outline are classified with shapely's vectorised
predicates; only the quarters the outline crosses are clipped (shapely intersection).

Row ends on the outline (``row_ends="outline"``, the scene's ``panels.N.row_ends: outline``):
the rule above gives cut cells their true share of *width*, but every spring keeps the lattice's
*length*, so a row's rest length is a whole number of cells: where the outline crosses a row
between two lattice nodes, the row's end node sits up to half a cell inside or outside it, and a
shaped panel's row lengths follow its outline as a staircase (a course round a leg jumps by a
cell where the lattice adds a column). With ``outline`` each row's two end nodes stand for the
points where the outline crosses the row (``node_uv``, their material points): the row's end
springs take the sliver's length (between half and one and a half cells), so the sum of a row's
rest lengths is the outline's width at the row's height, continuous from row to row; every
spring's rest length is the distance between its nodes' material points, and its width is its
band's area over that length (width x length still sums to the panel's area). Nodes, masks,
bands and node areas are the same as with ``lattice``; an outline on lattice lines (a rectangle)
moves no node, and builds the same model bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: coordinates within this many lattice units of an integer or half-integer are snapped to it, so
#: that an outline meant to lie on lattice lines does (rounding of size / spacing)
SNAP = 1e-9
#: quarter areas below this (cell units) count as empty
EMPTY = 1e-12
#: with row ends on the outline, a row's end spring keeps at least this length [cells]
MIN_END_LENGTH = 0.25
#: how a row's end nodes stand on a cut outline (see the module docstring)
ROW_ENDS = ("lattice", "outline")


class PanelError(ValueError):
    """A panel that cannot be built; the message names the panel."""


@dataclass(frozen=True, eq=False)
class PanelGeometry:
    """A panel's lattice and its share of the outline, all in lattice order (i, j).

    name; mask (nx+1, ny+1) bool: the nodes that exist; spacing (dx, dy) [m]; origin (2,) [m]:
    node (0, 0) in the panel's plane; grain (2,) unit warp direction in that plane;
    node_frac (nx+1, ny+1): node areas in cells (area = node_frac dx dy);
    warp_frac (nx, ny+1) and weft_frac (nx+1, ny): band areas in cells (width = warp_frac dy,
    = weft_frac dx); cell_frac (nx, ny): each cell's area inside the outline in cells;
    outline (K, 2) [m] in the panel's plane (counter-clockwise); outline_lattice (K, 2): the same
    in lattice units; node_uv (nx+1, ny+1, 2) or None: each node's material point in lattice units
    (row ends on the outline, see the module docstring; None: the lattice points themselves)."""

    name: str
    mask: np.ndarray
    spacing: tuple[float, float]
    origin: np.ndarray
    grain: np.ndarray
    node_frac: np.ndarray
    warp_frac: np.ndarray
    weft_frac: np.ndarray
    cell_frac: np.ndarray
    outline: np.ndarray
    outline_lattice: np.ndarray
    node_uv: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(int(s) for s in self.mask.shape)  # type: ignore[return-value]

    def to_plane(self, ij: np.ndarray) -> np.ndarray:
        """Lattice coordinates (n, 2) -> points (n, 2) [m] in the panel's plane."""
        g = self.grain
        gp = np.array([-g[1], g[0]])
        u = np.asarray(ij, float)[:, 0] * self.spacing[0]
        v = np.asarray(ij, float)[:, 1] * self.spacing[1]
        return self.origin + u[:, None] * g + v[:, None] * gp

    def material_ij(self, ij: np.ndarray) -> np.ndarray:
        """Lattice indices (n, 2) -> the nodes' material points (n, 2) in lattice units (the
        indices themselves unless the row ends stand on the outline)."""
        ij = np.asarray(ij)
        if self.node_uv is None:
            return ij.astype(float)
        return self.node_uv[ij[:, 0], ij[:, 1]]

    def node_area(self) -> np.ndarray:
        """(n_nodes,) [m^2] in the mask's row-major order."""
        return self.node_frac[self.mask] * (self.spacing[0] * self.spacing[1])


def _snap(x: np.ndarray) -> np.ndarray:
    h = np.round(2 * x) / 2
    return np.where(np.abs(x - h) < SNAP, h, x)


def rectangle_geometry(name: str, nx: int, ny: int, dx: float, dy: float, origin=(0.0, 0.0)) -> PanelGeometry:
    """The full nx x ny rectangle (the ``fabric:`` sheet), by the same rule in closed form."""
    node = np.full((nx + 1, ny + 1), 1.0)
    node[[0, -1], :] *= 0.5
    node[:, [0, -1]] *= 0.5
    warp = np.ones((nx, ny + 1))
    warp[:, [0, -1]] = 0.5
    weft = np.ones((nx + 1, ny))
    weft[[0, -1], :] = 0.5
    outline = np.array([[0, 0], [nx * dx, 0], [nx * dx, ny * dy], [0, ny * dy]], float) + np.asarray(origin, float)
    return PanelGeometry(name, np.ones((nx + 1, ny + 1), bool), (dx, dy), np.asarray(origin, float),
                         np.array([1.0, 0.0]), node, warp, weft, np.ones((nx, ny)), outline,
                         np.array([[0, 0], [nx, 0], [nx, ny], [0, ny]], float))


def check_outline(outline, name: str = "panel") -> np.ndarray:
    """A validated outline (K, 2) [m], counter-clockwise, without a repeated closing point;
    PanelError for fewer than 3 points, non-finite values, a zero area or a self-crossing."""
    import shapely

    p = np.asarray(outline, float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise PanelError(f"{name}: outline must be a list of [x, y] points (got shape {p.shape})")
    if len(p) > 1 and np.allclose(p[0], p[-1]):
        p = p[:-1]
    if len(p) < 3:
        raise PanelError(f"{name}: outline needs at least 3 points (got {len(p)})")
    if not np.isfinite(p).all():
        raise PanelError(f"{name}: outline has non-finite coordinates")
    poly = shapely.Polygon(p)
    if not poly.is_valid:
        reason = shapely.is_valid_reason(poly)
        raise PanelError(f"{name}: outline is not a simple polygon ({reason})")
    if not poly.area > 0:
        raise PanelError(f"{name}: outline has zero area")
    if shapely.Polygon(p).exterior.is_ccw is False:
        p = p[::-1].copy()
    return p


def panel_geometry(name: str, outline, grain=(1.0, 0.0), spacing=None, divisions=None,
                   row_ends: str = "lattice") -> PanelGeometry:
    """The lattice of a panel cut to ``outline`` (K, 2) [m] along ``grain`` (2,), with ``spacing``
    (dx, dy) [m] or ``divisions`` (nx, ny) of the outline's extent along and across the grain;
    ``row_ends`` "lattice" or "outline" (the rows' end nodes on the outline: module docstring)."""
    import shapely

    if row_ends not in ROW_ENDS:
        raise PanelError(f"{name}: row_ends must be one of {', '.join(ROW_ENDS)} (got {row_ends!r})")

    p = check_outline(outline, name)
    g = np.asarray(grain, float)
    if not (g.shape == (2,) and np.isfinite(g).all() and np.linalg.norm(g) > 0):
        raise PanelError(f"{name}: grain must be a non-zero [x, y] direction (got {grain})")
    g = g / np.linalg.norm(g)
    gp = np.array([-g[1], g[0]])
    uv = np.stack([p @ g, p @ gp], 1)
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    ext = hi - lo
    if spacing is not None:
        dx, dy = (spacing, spacing) if np.isscalar(spacing) else spacing
    elif divisions is not None:
        dx, dy = ext[0] / divisions[0], ext[1] / divisions[1]
    else:
        raise PanelError(f"{name}: give spacing or divisions")
    if not (dx > 0 and dy > 0):
        raise PanelError(f"{name}: spacing must be positive (got {dx}, {dy})")
    lat = _snap((uv - lo) / [dx, dy])
    nx = max(1, int(np.ceil(lat[:, 0].max() - SNAP)))
    ny = max(1, int(np.ceil(lat[:, 1].max() - SNAP)))
    if (nx + 1) * (ny + 1) > 4_000_000:
        raise PanelError(f"{name}: too many lattice nodes ({(nx + 1) * (ny + 1)}; at most 4,000,000)")
    poly = shapely.Polygon(lat)
    shapely.prepare(poly)

    # quarter q of cell (i, j): corners of q in lattice units; q = 0 (i, j), 1 (i+1, j),
    # 2 (i+1, j+1), 3 (i, j+1): the quarter touching that corner
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    quarter = np.zeros((nx, ny, 4))
    offs = ((0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.0, 0.5))
    for q, (ox, oy) in enumerate(offs):
        x0 = (ii + ox).ravel()
        y0 = (jj + oy).ravel()
        boxes = shapely.box(x0, y0, x0 + 0.5, y0 + 0.5)
        inside = shapely.contains(poly, boxes)
        touch = shapely.intersects(poly, boxes) & ~inside
        a = np.where(inside, 0.25, 0.0)
        if touch.any():
            a[touch] = shapely.area(shapely.intersection(boxes[touch], poly))
        quarter[:, :, q] = a.reshape(nx, ny)
    quarter[quarter < EMPTY] = 0.0

    node = np.zeros((nx + 1, ny + 1))
    node[:-1, :-1] += quarter[:, :, 0]
    node[1:, :-1] += quarter[:, :, 1]
    node[1:, 1:] += quarter[:, :, 2]
    node[:-1, 1:] += quarter[:, :, 3]
    mask = node > EMPTY
    # warp spring (i, j)-(i+1, j): the quarters along it, at its first node (quarter 3 of cell
    # (i, j-1), quarter 0 of cell (i, j)) and at its second (quarters 2 and 1)
    z = np.zeros((nx, 1))
    w_first = np.hstack([z, quarter[:, :, 3]]) + np.hstack([quarter[:, :, 0], z])
    w_second = np.hstack([z, quarter[:, :, 2]]) + np.hstack([quarter[:, :, 1], z])
    # weft spring (i, j)-(i, j+1): at its first node quarter 1 of cell (i-1, j) and 0 of (i, j);
    # at its second quarters 2 and 3
    z = np.zeros((1, ny))
    f_first = np.vstack([z, quarter[:, :, 1]]) + np.vstack([quarter[:, :, 0], z])
    f_second = np.vstack([z, quarter[:, :, 2]]) + np.vstack([quarter[:, :, 3], z])
    node, mask = _absorb_isolated(node, mask, w_first + w_second, f_first + f_second, name)
    warp = _carry_over(w_first, w_second, mask)
    weft = _carry_over(f_first.T, f_second.T, mask.T).T
    origin = lo[0] * g + lo[1] * gp
    uv = _row_ends_on_outline(poly, mask) if row_ends == "outline" else None
    return PanelGeometry(name, mask, (float(dx), float(dy)), origin, g, np.where(mask, node, 0.0),
                         warp, weft, quarter.sum(axis=2), p, lat, uv)


def _row_crossings(poly, j: int, nx: int) -> list[tuple[float, float]]:
    """The stretches [u0, u1] (lattice units) of the row v = j inside the polygon ``poly``; a row
    beyond the polygon's extent in v (its nodes there for the sliver of outline within half a
    cell) takes the stretches at the middle of that sliver."""
    import shapely

    _, lo, _, hi = poly.bounds
    v = float(j)
    if v > hi:
        v = 0.5 * (max(v - 0.5, lo) + hi)
    elif v < lo:
        v = 0.5 * (lo + min(v + 0.5, hi))
    cut = shapely.intersection(poly, shapely.LineString([(-1.0, v), (nx + 1.0, v)]))
    out = []
    for part in shapely.get_parts(cut):
        if part.is_empty:
            continue
        x0, _, x1, _ = part.bounds
        out.append((float(x0), float(x1)))
    return out


def _row_ends_on_outline(poly, mask: np.ndarray) -> np.ndarray:
    """(nx+1, ny+1, 2) material points in lattice units: the lattice points, except each row's
    (each run of consecutive nodes along i at a given j) two end nodes, moved along the row to
    where the outline crosses it (the stretch of the row inside the outline that overlaps the run
    most; for a row beyond the outline's extent, the middle of the sliver it stands for), when
    that crossing lies within a cell of the node; the end spring keeps at least MIN_END_LENGTH
    cells. A crossing within SNAP of the node moves nothing. Nodes move along their row only (v
    stays j): the wales keep their lattice length except where they join a moved end."""
    nx1, ny1 = mask.shape
    ii, jj = np.meshgrid(np.arange(nx1, dtype=float), np.arange(ny1, dtype=float), indexing="ij")
    uv = np.stack([ii, jj], -1)
    for j in range(ny1):
        cols = np.nonzero(mask[:, j])[0]
        if cols.size < 2:
            continue
        segs = _row_crossings(poly, j, nx1 - 1)
        if not segs:
            continue
        cut = np.nonzero(np.diff(cols) > 1)[0]
        for i0, i1 in zip(np.r_[cols[0], cols[cut + 1]], np.r_[cols[cut], cols[-1]]):
            if i1 == i0:
                continue
            a, b = max(segs, key=lambda s: min(s[1], i1) - max(s[0], i0))
            if min(b, i1) - max(a, i0) <= 0:
                continue
            if SNAP < abs(a - i0) < 1.0:
                uv[i0, j, 0] = min(a, i0 + 1 - MIN_END_LENGTH)
            if SNAP < abs(b - i1) < 1.0:
                lo = uv[i0, j, 0] + MIN_END_LENGTH if i1 == i0 + 1 else -np.inf
                uv[i1, j, 0] = max(b, i1 - 1 + MIN_END_LENGTH, lo)
    return uv


def _carry_over(first: np.ndarray, second: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Band areas (nx, ny+1) of the springs along axis 0 of ``mask`` (nx+1, ny+1), given the
    part of each band at its first and at its second node. Where a spring does not exist (one of
    its nodes is missing), the part at the node that exists goes to that node's other spring on
    the same line, so the band's stiffness stays in the membrane."""
    exists = mask[:-1, :] & mask[1:, :]
    band = np.where(exists, first + second, 0.0)
    lost_first = np.where(~exists & mask[:-1, :], first, 0.0)    # at node i: give to spring i-1
    lost_second = np.where(~exists & mask[1:, :], second, 0.0)   # at node i+1: give to spring i+1
    band[:-1, :] += np.where(exists[:-1, :], lost_first[1:, :], 0.0)
    band[1:, :] += np.where(exists[1:, :], lost_second[:-1, :], 0.0)
    return band


def _absorb_isolated(node, mask, warp, weft, name):
    """Nodes without a spring of positive width hand their area to the nearest node that has one."""
    node = node.copy()
    mask = mask.copy()
    for _ in range(8):
        has = np.zeros_like(mask)
        wk = mask[:-1, :] & mask[1:, :] & (warp > EMPTY)
        fk = mask[:, :-1] & mask[:, 1:] & (weft > EMPTY)
        has[:-1, :] |= wk
        has[1:, :] |= wk
        has[:, :-1] |= fk
        has[:, 1:] |= fk
        lone = mask & ~has
        if not lone.any():
            return node, mask
        keep = np.argwhere(mask & has)
        if keep.size == 0:
            raise PanelError(f"{name}: the outline is too small for its spacing (no lattice spring fits)")
        for i, j in np.argwhere(lone):
            d = np.abs(keep - [i, j]).sum(axis=1)
            ti, tj = keep[np.argmin(d)]
            node[ti, tj] += node[i, j]
            node[i, j] = 0.0
            mask[i, j] = False
    raise PanelError(f"{name}: could not attach every part of the outline to the lattice")
