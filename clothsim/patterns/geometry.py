"""The geometry of pattern pieces, whatever file they came from: the :class:`Piece` (outline,
grainline, notches) and its checks (closed, simple, counter-clockwise, non-zero area), curve
flattening within a chord tolerance (elliptical arcs, Bezier curves), joining boundary parts
end to end, snapping notches, and the units and bounds they are read in (units: m)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from .. import patternlimits as limits
from ..patternlimits import PatternError, PatternLimitError


DEFAULT_TOLERANCE = 0.5e-3
"""Default chord error of flattened curves [m] (0.5 mm)."""


UNITS: Mapping[str, float] = MappingProxyType({
    "m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 1e-3, "in": 0.0254, "inch": 0.0254, "ft": 0.3048,
    "pt": 0.0254 / 72.0, "pc": 0.0254 / 6.0, "px": 0.0254 / 96.0, "q": 0.25e-3,
})
"""Length of one unit [m] by name, for ``units=`` (and SVG length units)."""


_ZERO_AREA = 1e-9          # |area| <= _ZERO_AREA * perimeter^2 is a zero-area piece


_MAX_DEPTH = 30            # Bezier subdivision depth cap (2^-30 of a parameter span)


class PatternWarning(UserWarning):
    """A pattern file is usable but suspect: its largest piece spans under 5 mm or over 5 m (the
    wrong units?)."""


#: the span [m] of a pattern's largest piece outside which reading it warns (PatternWarning)
PIECE_SPAN_RANGE = (0.005, 5.0)


@dataclass(frozen=True, eq=False)
class Piece:
    """One pattern piece, flat, in its own plane.

    Attributes:
        name: the piece's name (AAMA ``Piece Name:`` text, block name, SVG label or id, DXF layer).
        outline: (K, 2) float64 [m], K >= 3, the boundary polygon, counter-clockwise (positive
            area), closed implicitly (the first point is not repeated), simple (does not cross
            itself). Read-only.
        grain: (2,) float64 unit vector in the outline's plane, the warp direction drawn in the
            file (its sign as drawn), or None when the file gives no grainline.
        vertex_names: name -> index into ``outline`` of named vertices (DXF notches, ``notch1``,
            ``notch2``, ... in outline order; a notch on an edge becomes a vertex). Empty when the
            file names none.
        source: ``file: block/element`` the piece came from, for messages.
        notes: what the reader decided that a user should know (how units were found, ...).
    """

    name: str
    outline: np.ndarray
    grain: np.ndarray | None
    vertex_names: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    source: str = ""
    notes: tuple[str, ...] = ()

    @property
    def area(self) -> float:
        """Polygon area [m^2] (shoelace), positive."""
        return _signed_area(self.outline)

    @property
    def perimeter(self) -> float:
        """Polygon perimeter [m]."""
        return _perimeter(self.outline)


@dataclass
class _RawPiece:
    """A piece before validation: outline and grain in metres, not yet oriented."""

    name: str
    source: str
    outline: np.ndarray                      # (K, 2) [m], first point not repeated
    grain: tuple[np.ndarray, np.ndarray] | None = None   # (start, end) [m]
    notches: list[np.ndarray] = field(default_factory=list)   # points [m]
    error: str | None = None   # why the piece cannot be used (the message), else None


def _bad(label: str, name: str, source: str, exc: PatternError) -> _RawPiece:
    """A piece that failed while being read: kept (by name) so that a scene asking for another
    piece of the file is not refused for it; a PatternLimitError refuses the whole file."""
    if isinstance(exc, PatternLimitError):
        raise exc
    return _RawPiece(name, source, np.zeros((0, 2)), error=str(exc))


def _finish(label: str, name: str, rp: _RawPiece, tol: float, notes: tuple[str, ...]) -> Piece:
    """Validate, orient counter-clockwise, snap notches and freeze one piece."""
    where = f"{label}: piece {name}"
    pts = np.asarray(rp.outline, dtype=np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(pts)):
        raise PatternError(f"{where}: outline has non-finite coordinates")
    pts = _drop_repeats(pts, 1e-6 * tol)
    if len(pts) < 3:
        raise PatternError(f"{where}: outline has {len(pts)} distinct point{'s' if len(pts) != 1 else ''}, fewer than 3")
    area, perim = _signed_area(pts), _perimeter(pts)
    import shapely

    poly = shapely.Polygon(pts)
    # a figure-eight's lobes cancel in the signed area: it crosses itself, it is not flat
    lobes = float(shapely.make_valid(poly).area) if not poly.is_valid else abs(area)
    if max(abs(area), lobes) <= _ZERO_AREA * perim * perim:
        raise PatternError(f"{where}: outline has zero area (perimeter {perim:.6g} m, area {area:.3g} m^2)")
    if not poly.is_valid:
        reason = shapely.is_valid_reason(poly)
        m = re.search(r"\[\s*([-+0-9.eE]+)\s+([-+0-9.eE]+)", reason)
        if "self-intersection" in reason.lower() and m:
            raise PatternError(f"{where}: outline crosses itself near "
                               f"({float(m.group(1)):.4g}, {float(m.group(2)):.4g}) m")
        raise PatternError(f"{where}: invalid outline ({reason})")
    if area < 0:
        pts = np.concatenate([pts[:1], pts[:0:-1]])
    grain = None
    pnotes = list(notes)
    if rp.grain is not None:
        d = np.asarray(rp.grain[1], float) - np.asarray(rp.grain[0], float)
        n = float(np.hypot(d[0], d[1]))
        if n > 0 and math.isfinite(n):
            grain = d / n
            grain.flags.writeable = False
        else:
            pnotes.append("grainline has zero length: ignored")
    names: dict[str, int] = {}
    if rp.notches:
        pts, idx, skipped = _snap(pts, rp.notches, tol)
        for k, i in enumerate(sorted(set(idx)), 1):
            names[f"notch{k}"] = i
        if skipped:
            pnotes.append(f"{skipped} notch(es) farther than {tol:g} m from the outline: ignored")
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    pts.flags.writeable = False
    return Piece(name=name, outline=pts, grain=grain, vertex_names=MappingProxyType(names),
                 source=rp.source, notes=tuple(pnotes))


def _signed_area(p: np.ndarray) -> float:
    """Shoelace area [m^2] of the implicitly closed polygon p (K, 2); positive if counter-clockwise."""
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _perimeter(p: np.ndarray) -> float:
    """Perimeter [m] of the implicitly closed polygon p (K, 2)."""
    d = np.roll(p, -1, axis=0) - p
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


def _drop_repeats(p: np.ndarray, eps: float) -> np.ndarray:
    """Drop consecutive points within eps [m] of the one kept before them, and closing repeats of
    the first point (round-off of joined or transformed curves, never a real vertex)."""
    if len(p) == 0:
        return p
    keep = [0]
    for i in range(1, len(p)):
        if math.hypot(*(p[i] - p[keep[-1]])) > eps:
            keep.append(i)
    p = p[keep]
    while len(p) > 1 and math.hypot(*(p[-1] - p[0])) <= eps:
        p = p[:-1]
    return p


def _snap(pts: np.ndarray, notches: list[np.ndarray], tol: float) -> tuple[np.ndarray, list[int], int]:
    """Snap notch points [m] onto the outline pts (K, 2): onto the nearest vertex within tol, else
    onto the nearest edge within tol (a vertex is inserted there). Returns (new outline, the notch
    vertex indices in it, the number of notches farther than tol, skipped)."""
    a, b = pts, np.roll(pts, -1, axis=0)
    ab = b - a
    L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    keys: list[tuple[int, float]] = []          # (edge index, parameter on the edge; 0 = vertex)
    feet: dict[tuple[int, float], np.ndarray] = {}
    skipped = 0
    for q in notches:
        q = np.asarray(q, float)[:2]
        dv = np.hypot(*(pts - q).T)
        iv = int(np.argmin(dv))
        if dv[iv] <= tol:
            keys.append((iv, 0.0))
            continue
        t = np.clip(np.einsum("ij,ij->i", q - a, ab) / L2, 0.0, 1.0)
        foot = a + t[:, None] * ab
        de = np.hypot(*(foot - q).T)
        ie = int(np.argmin(de))
        if de[ie] <= tol and 0.0 < t[ie] < 1.0:
            keys.append((ie, float(t[ie])))
            feet[(ie, float(t[ie]))] = foot[ie]
        else:
            skipped += 1
    rows, index = [], {}
    for i in range(len(pts)):
        index[(i, 0.0)] = len(rows)
        rows.append(pts[i])
        for key in sorted(k for k in feet if k[0] == i):
            index[key] = len(rows)
            rows.append(feet[key])
    return np.array(rows), [index[k] for k in keys], skipped


# --------------------------------------------------------------------------------------------
# flattening (all in metres)
# --------------------------------------------------------------------------------------------


def _flatten_ellipse(c, a, b, t0: float, sweep: float, tol: float) -> np.ndarray:
    """Points of p(t) = c + cos(t) a + sin(t) b for t from t0 over sweep [rad] (signed), chord error <= tol.

    c, a, b: (2,) [m]. Circle (|a| = |b|, a . b = 0): steps of at most 2 acos(1 - tol/r), the sagitta
    bound, vertices on the circle. Otherwise steps h with h^2/8 * s_max <= tol, s_max = the largest
    singular value of [a b] = max |p''|. Returns (n+1, 2) including both ends."""
    work = limits.current()
    c, a, b = (np.asarray(v, float)[:2] for v in (c, a, b))
    work.check(c, "a curve's centre")
    work.check(np.abs(c) + np.hypot(*a) + np.hypot(*b), "a curve")
    if not (math.isfinite(t0) and math.isfinite(sweep)):
        raise PatternError(f"{work.label}: {work.where}: a curve has non-finite angles")
    smax = float(np.linalg.svd(np.column_stack([a, b]), compute_uv=False)[0])
    ra, rb = float(np.hypot(*a)), float(np.hypot(*b))
    if smax == 0.0:
        return np.array([c, c])
    if abs(ra - rb) <= 1e-12 * smax and abs(float(a @ b)) <= 1e-12 * smax * smax:
        step = 2.0 * math.acos(1.0 - tol / ra) if tol < ra else math.pi
    else:
        step = math.sqrt(8.0 * tol / smax)
    step = min(step, math.pi / 2)
    n = max(1, math.ceil(abs(sweep) / step)) if step > 0 else math.inf
    work.spend(n + 1)
    t = t0 + sweep * np.arange(n + 1) / n
    return c + np.cos(t)[:, None] * a + np.sin(t)[:, None] * b


def _flatten_bezier(ctrl: np.ndarray, tol: float) -> np.ndarray:
    """Points of a Bezier curve of any degree, chord error <= tol (control points within tol of the chord).

    ctrl: (m, 2) control points [m], or (m, 3) homogeneous (x w, y w, w), w > 0, for a rational curve.
    Returns (n+1, 2) including both ends."""
    work = limits.current()
    ctrl = np.asarray(ctrl, float)
    if ctrl.shape[1] == 2:
        ctrl = np.column_stack([ctrl, np.ones(len(ctrl))])
    work.check(ctrl[:, :2] / ctrl[:, 2:3], "a curve's control point")
    # subdivision makes about as many points as uniform steps would need by the interpolation
    # bound, sqrt(d (d-1) max|second difference| / (8 tol)): a curve far over the budget is
    # refused before it is subdivided (the points made are counted as they come, too)
    if len(ctrl) > 2:
        p0 = ctrl[:, :2] / ctrl[:, 2:3]
        d = len(p0) - 1
        dd = float(np.max(np.hypot(*np.diff(p0, n=2, axis=0).T)))
        work.need(0.5 * math.sqrt(d * (d - 1) * dd / (8.0 * tol)))
    # plain floats: a cubic's arrays are too small for numpy to pay (3x faster, the same arithmetic)
    tol2 = tol * tol
    first = [tuple(r) for r in ctrl.tolist()]
    out = [(first[0][0] / first[0][2], first[0][1] / first[0][2])]
    stack = [(first, 0)]
    while stack:
        cp, depth = stack.pop()
        p = [(x / w, y / w) for x, y, w in cp]
        if depth >= _MAX_DEPTH or _hull_within(p, tol2):
            out.append(p[-1])
            work.spend(1)
            continue
        left, right = _split_half(cp)
        stack.append((right, depth + 1))
        stack.append((left, depth + 1))
    return np.array(out)


def _hull_within(p: list[tuple[float, float]], tol2: float) -> bool:
    """True if every inner control point of p lies within sqrt(tol2) of the segment p[0] p[-1]."""
    ax, ay = p[0]
    abx, aby = p[-1][0] - ax, p[-1][1] - ay
    L2 = abx * abx + aby * aby
    for x, y in p[1:-1]:
        qx, qy = x - ax, y - ay
        t = min(max((qx * abx + qy * aby) / L2, 0.0), 1.0) if L2 > 0 else 0.0
        dx, dy = qx - t * abx, qy - t * aby
        if dx * dx + dy * dy > tol2:
            return False
    return True


def _split_half(cp: list[tuple]) -> tuple[list[tuple], list[tuple]]:
    """De Casteljau split of a Bezier control polygon (tuples of equal length) at t = 1/2."""
    left, right = [cp[0]], [cp[-1]]
    row = cp
    while len(row) > 1:
        row = [tuple(0.5 * (u + v) for u, v in zip(a, b)) for a, b in zip(row[:-1], row[1:])]
        left.append(row[0])
        right.append(row[-1])
    return left, right[::-1]


def _join(curves: list[np.ndarray], tol: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Join open polylines end to end into closed loops (:func:`clothsim.patternlimits.join`)."""
    return limits.join(curves, tol)


def _chain(parts: list[np.ndarray]) -> np.ndarray:
    """Concatenate polylines drawn in sequence (each oriented to start where the previous ended)."""
    out: list[np.ndarray] = []
    parts = [p for p in parts if len(p) >= 2]
    if len(parts) > 1:
        # the first part's direction from the second: its end is the one that touches it (an
        # LWPOLYLINE's clockwise arc comes as a counter-clockwise ARC, drawn end to start)
        p0, p1 = parts[0], parts[1]
        d_end = min(np.hypot(*(p0[-1] - p1[0])), np.hypot(*(p0[-1] - p1[-1])))
        d_start = min(np.hypot(*(p0[0] - p1[0])), np.hypot(*(p0[0] - p1[-1])))
        if d_start < d_end:
            parts[0] = p0[::-1]
    for p in parts:
        if out:
            end = out[-1]
            if np.hypot(*(p[-1] - end)) < np.hypot(*(p[0] - end)):
                p = p[::-1]
            out.extend(p[1:])
        else:
            out.extend(p)
    return np.array(out) if out else np.zeros((0, 2))


def _dist_to_polygon(q: np.ndarray, poly: np.ndarray) -> float:
    """Distance from q (2,) to the boundary of the closed polygon poly (K, 2)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
    return float(np.min(np.hypot(*(a + t[:, None] * ab - q).T)))
