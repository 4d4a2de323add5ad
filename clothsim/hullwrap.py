"""A start that wraps a sheet (or a panel) round a body slab, clear of it.

``initial.wrap`` rolls the sheet onto a cylinder; round a scanned body a cylinder that clears the
widest part is far from the narrow parts, and one that follows a limb hits the other limb, the
arms or the breasts. Here each row of the sheet (one height along the body axis) goes round the
convex hull of the mold's cross-section at that height, pushed out by a clearance:

- The *slab* of a row at height h is the part of the mold between the planes h - dh and h + dh
  across the axis (dh half the row spacing), restricted to an optional box ``region`` (one leg of
  two). Its points are the mesh vertices inside the slab and the points where mesh edges cross
  its two planes, so every point of the mold's surface between the planes (and so every point of
  the mold's cross-section at any height between them) projects into the convex hull of these
  points in the cross-section plane. The hull is grown by ``clearance`` [m] (shapely's buffer: a
  rounded offset, every point of it ``clearance`` from the hull).
- A row's width (its extent along the grain, from the panel's outline at that row) is laid round
  that grown hull by arc length: its left end at ``offset`` x the perimeter past the point where
  the ray at ``start_angle`` from the axis meets the hull, its right end ``fraction`` x the
  perimeter further on, counter-clockwise about the axis (the warp round the axis, as with
  ``initial.wrap``; its flat normal, z, points outward).
- Heights: the row at the panel's middle height (of its outline) sits at ``center``; with
  ``heights: [h0, h1]`` the outline's lowest row goes to h0 and its highest to h1 (heights along
  the axis measured from ``center``), rows between in proportion.

A node is then at least ``clearance`` from the hull, so outside the mold wherever the mold's
section at the node's height lies within the region (nodes only: a spring between two rows may
still cut a bulge of the mold between them). Shapes: points (n, 3) [m] throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .errors import SceneError
from .mold.record import MESH_KINDS, MOLD_LEG

if TYPE_CHECKING:
    from .config import WrapHull


def axis_frame(axis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, e1, e2): the unit axis and the cross-section frame ``initial.wrap`` uses (e1 from x,
    or from y when the axis is near x; e2 = a x e1), so ``start_angle`` means the same."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = t - a * (t @ a)
    e1 /= np.linalg.norm(e1)
    return a, e1, np.cross(a, e1)


def slab_points(vertices: np.ndarray, edges: np.ndarray, t: np.ndarray, lo: float, hi: float,
                region=None) -> np.ndarray:
    """Points (m, 3) [m] of a triangle mesh between the planes t = lo and t = hi: its vertices
    there and the crossings of its edges with the two planes (their convex hull is the hull of
    the mesh's part between the planes). vertices (V, 3) [m]; edges (E, 2) int (unique);
    t (V,) [m] each vertex's height along the axis; region: (min (3,), max (3,)) [m] or None,
    a box the points must lie in."""
    pts = [vertices[(t >= lo) & (t <= hi)]]
    ta, tb = t[edges[:, 0]], t[edges[:, 1]]
    for plane in (lo, hi):
        cross = (np.minimum(ta, tb) < plane) & (np.maximum(ta, tb) > plane)
        if cross.any():
            a, b = edges[cross, 0], edges[cross, 1]
            s = (plane - t[a]) / (t[b] - t[a])
            pts.append(vertices[a] + s[:, None] * (vertices[b] - vertices[a]))
    P = np.concatenate(pts)
    if region is not None:
        lo_b, hi_b = np.asarray(region[0], float), np.asarray(region[1], float)
        P = P[((P >= lo_b) & (P <= hi_b)).all(axis=1)]
    return P


def row_extent(outline_uv: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u_lo, u_hi) (n,) [m]: the extent along the grain of a closed polygon (K, 2) [m] (in the
    grain frame u, v) at each height v (n,) [m], clamped into the polygon's v range: the least and
    greatest u where the line v crosses its edges (vertices included)."""
    P = np.asarray(outline_uv, float)
    Q = np.roll(P, -1, axis=0)
    vmin, vmax = P[:, 1].min(), P[:, 1].max()
    v = np.clip(np.asarray(v, float), vmin, vmax)
    lo = np.full(v.shape, np.inf)
    hi = np.full(v.shape, -np.inf)
    for (u0, v0), (u1, v1) in zip(P, Q):
        a, b = min(v0, v1), max(v0, v1)
        on = (v >= a) & (v <= b)
        if not on.any():
            continue
        if b > a:
            u = u0 + (v[on] - v0) / (v1 - v0) * (u1 - u0)
            lo[on] = np.minimum(lo[on], u)
            hi[on] = np.maximum(hi[on], u)
        else:  # a horizontal edge: both ends
            lo[on] = np.minimum(lo[on], min(u0, u1))
            hi[on] = np.maximum(hi[on], max(u0, u1))
    return lo, hi


@dataclass(frozen=True, eq=False)
class HullWrap:
    """The placement of one panel round the hull of a mold's slab (see the module docstring).

    spec: the config record (axis, center, clearance, heights, region, start_angle, offset,
    fraction); vertices (V, 3) [m] and edges (E, 2) of the mold's mesh; outline_uv (K, 2) [m]:
    the panel's outline in its grain frame (u along the grain from the panel's origin, v across);
    dh [m]: half the thickness of the slab each row's hull is taken over; where: the config path
    for messages (``initial.wrap_hull`` or ``panels.N.placement.wrap_hull``)."""

    spec: WrapHull
    vertices: np.ndarray
    edges: np.ndarray
    outline_uv: np.ndarray
    dh: float
    where: str = "initial.wrap_hull"
    _rings: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        a, e1, e2 = axis_frame(self.spec.axis)
        c = np.asarray(self.spec.center, float)
        object.__setattr__(self, "_frame", (a, e1, e2, c))
        object.__setattr__(self, "_t", (self.vertices - c) @ a)

    # ---------------------------------------------------------------------------------- heights
    def heights(self, v: np.ndarray) -> np.ndarray:
        """Height along the axis from ``center`` [m] (n,) of rows at v (n,) [m]."""
        vmin, vmax = float(self.outline_uv[:, 1].min()), float(self.outline_uv[:, 1].max())
        if self.spec.heights is None:
            return np.asarray(v, float) - 0.5 * (vmin + vmax)
        h0, h1 = self.spec.heights
        span = vmax - vmin
        return h0 + (np.asarray(v, float) - vmin) / (span if span > 0 else 1.0) * (h1 - h0)

    def ring(self, h: float):
        """(the grown hull's boundary, a shapely LinearRing counter-clockwise in (e1, e2), and its
        start distance along it [m]) at height h [m] (cached)."""
        key = round(float(h), 12)
        got = self._rings.get(key)
        if got is not None:
            return got
        import shapely
        from shapely.geometry import LineString, MultiPoint, Point
        from shapely.geometry.polygon import orient

        a, e1, e2, c = self._frame
        reg = None if self.spec.region is None else (self.spec.region.min, self.spec.region.max)
        P = slab_points(self.vertices, self.edges, self._t, h - self.dh, h + self.dh, reg)
        if len(P) < 3:
            raise SceneError(
                f"{self.where}: the mold has no part at height {h:.4g} m along the axis from the "
                f"centre (between {h - self.dh:.4g} and {h + self.dh:.4g} m"
                + (", inside the region" if reg is not None else "")
                + "): move the centre, the heights or the region so the sheet's rows lie on the body")
        xy = np.stack([(P - c) @ e1, (P - c) @ e2], 1)
        hull = MultiPoint(xy).convex_hull
        poly = orient(hull.buffer(self.spec.clearance, quad_segs=16), 1.0) if self.spec.clearance > 0 else (
            orient(hull, 1.0) if hull.geom_type == "Polygon" else None)
        if poly is None or poly.area <= 0:
            raise SceneError(f"{self.where}: the mold's section at height {h:.4g} m is flat (no area): "
                             f"give a clearance > 0")
        ring = poly.exterior
        o = Point(0.0, 0.0) if poly.contains(Point(0.0, 0.0)) else poly.centroid
        ang = math.radians(self.spec.start_angle)
        far = 4.0 * (poly.length + abs(o.x) + abs(o.y))
        ray = LineString([(o.x, o.y), (o.x + far * math.cos(ang), o.y + far * math.sin(ang))])
        hit = ray.intersection(ring)
        pts = list(getattr(hit, "geoms", [hit]))
        best = max(pts, key=lambda q: q.distance(o))  # the ray leaves the (convex) ring once
        s0 = float(shapely.line_locate_point(ring, best))
        got = (ring, s0)
        self._rings[key] = got
        return got

    # -------------------------------------------------------------------------------- placement
    def place(self, u: np.ndarray, v: np.ndarray, dz: np.ndarray) -> np.ndarray:
        """Points (n, 3) [m] of flat panel coordinates u, v (n,) [m] (grain frame, from the
        panel's origin) and dz (n,) [m] (out of the panel's plane: outward)."""
        import shapely

        a, e1, e2, c = self._frame
        u, v, dz = (np.asarray(x, float) for x in (u, v, dz))
        h = self.heights(v)
        lo, hi = row_extent(self.outline_uv, v)
        width = hi - lo
        frac = np.divide(u - lo, width, out=np.zeros_like(u), where=width > 0)
        out = np.empty((u.size, 3))
        keys = np.round(h, 12)
        for hk in np.unique(keys):
            sel = np.nonzero(keys == hk)[0]
            ring, s0 = self.ring(float(hk))
            L = ring.length
            s = np.mod(s0 + (self.spec.offset + self.spec.fraction * frac[sel]) * L, L)
            p = shapely.get_coordinates(shapely.line_interpolate_point(ring, s))
            eps = 1e-6 * L
            t = (shapely.get_coordinates(shapely.line_interpolate_point(ring, np.mod(s + eps, L)))
                 - shapely.get_coordinates(shapely.line_interpolate_point(ring, np.mod(s - eps, L))))
            t /= np.linalg.norm(t, axis=1)[:, None]
            nrm = np.stack([t[:, 1], -t[:, 0]], 1)  # outward for a counter-clockwise ring
            xy = p + dz[sel, None] * nrm
            out[sel] = c + h[sel, None] * a + xy[:, :1] * e1 + xy[:, 1:] * e2
        return out


def hull_wrap(spec, mold, outline_uv: np.ndarray, row_spacing: float, where: str) -> HullWrap:
    """The HullWrap of a panel (outline_uv (K, 2) [m] in its grain frame, row_spacing [m] its
    lattice spacing across the grain) round ``mold`` (a loaded mesh Mold); SceneError naming
    ``where`` when there is no mesh mold."""
    if mold is None:
        raise SceneError(f"{where}: needs a mold (the sheet is wrapped round the mold's hull)")
    if mold.kind not in MESH_KINDS and mold.kind != MOLD_LEG:
        raise SceneError(f"{where}: needs a mesh mold or a leg (a primitive: use wrap, a cylinder)")
    # a leg from a size chart: round its drawn mesh (96 sides, rings as fine)
    V, F = (mold.vertices, mold.faces) if mold.kind in MESH_KINDS else mold.surface_mesh(resolution=96)
    F = np.asarray(F, np.int64)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    E = np.unique(E, axis=0)
    scale = 1.0
    if spec.heights is not None:
        span = float(np.ptp(outline_uv[:, 1]))
        scale = abs(spec.heights[1] - spec.heights[0]) / span if span > 0 else 1.0
    dh = max(0.5 * row_spacing * scale, 1e-9)
    return HullWrap(spec, np.asarray(V, float), E, np.asarray(outline_uv, float), dh, where)
