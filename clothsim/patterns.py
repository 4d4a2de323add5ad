"""Pattern pieces read from DXF (DXF-AAMA / ASTM D6673 or plain) and SVG files.

A garment starts from flat pattern pieces: :func:`read_pattern` turns a pattern file into a list of
:class:`Piece`, each a closed, simple, counter-clockwise polygon in the piece's own plane [m] with
its grainline, ready for a panel lattice to be clipped to it.

**DXF** (read with ezdxf). Two layouts are recognised:

* *DXF-AAMA / ASTM D6673*: one BLOCK per piece, placed by an INSERT in modelspace (the INSERT's
  transform is applied, so a mirrored insert gives the mirrored piece). Inside the block the layers
  are numbered: layer ``1`` holds the piece boundary (one closed LWPOLYLINE/POLYLINE, or LINE, ARC,
  SPLINE, ELLIPSE and open polylines joined end to end), layer ``7`` the grainline (a LINE, or a
  polyline whose first and last points are taken), layer ``4`` notches (a LINE whose end nearer the
  boundary is the notch, or a POINT). The piece is named by its piece system text ``Piece Name: X``
  (TEXT or MTEXT), else by the block name. Entities on layer ``0`` in a block take the INSERT's layer,
  as in DXF.
* *Plain*: when no INSERT carries a layer-1 boundary, every closed entity in modelspace (closed
  LWPOLYLINE/POLYLINE, CIRCLE, full ELLIPSE, closed SPLINE) is a piece, named by its layer (by
  ``layer:handle`` when a layer holds several); a LINE on layer ``7`` or on a layer whose name
  contains ``grain`` is the grainline of the piece holding its midpoint.

Geometry is read in the XY plane (z is dropped). Units: ``units=`` when given, else the ``$INSUNITS``
header (1 inch, 2 foot, 4 mm, 5 cm, 6 m, 14 dm), else detected from size: the largest piece spans
100-5000 units -> mm, 0.02-3 units -> m; anything else (cm and inch cannot be told apart) is refused
with a request to declare the units. How the units were found is in every piece's ``notes``.

**SVG** (read with svgelements). Every closed ``<path>``, ``<polygon>``, ``<rect>``, ``<circle>``,
``<ellipse>`` (or a ``<polyline>``/path whose last point meets its first) is a piece, named by its
``inkscape:label``, else its ``id``, else its group's label or id, else ``<tag><n>``. Transforms are
applied. An element whose ``id``, ``class`` or label contains ``grain`` (any case), or that sits in
a group so named, is a grainline (a ``<line>``, polyline or path: first to last point), given to
the piece of its own group (the one holding its midpoint when the group has several or none). SVG's y axis points down; outlines are returned
with y up (y -> -y), so a piece looks as it did on screen. Units: ``units=`` declares the length of
one user unit (the root ``viewBox``'s unit); else the root ``width``/``height`` with an absolute unit
(mm, cm, in, pt, pc, px, Q) over the ``viewBox`` give it; else user units are CSS px (1/96 in).

**Flattening.** Curves become polylines whose chord error -- the largest distance between the
curve and the polyline -- is at most ``tolerance`` [m] (default 0.5 mm), guaranteed, not estimated:
circles and circular arcs by the sagitta ``r (1 - cos(phi/2)) <= tolerance`` (vertices on the
circle); elliptical arcs by the interpolation bound ``h^2 / 8 * max|p''| <= tolerance``; Bezier
curves (SVG quadratic/cubic, DXF splines through their exact Bezier decomposition, rational ones in
homogeneous coordinates) by subdividing until every control point lies within ``tolerance`` of the
chord (the convex-hull property); unclamped (periodic) DXF splines of degree <= 3 by the
interpolation bound with max |p''| taken per knot span. Endpoints of boundary pieces are joined
when they lie within ``tolerance`` of each other.

**Validation** (shapely): a piece with fewer than 3 points, zero area (|A| <= 1e-9 P^2), or an outline
that crosses itself is refused, as is a file without pieces, a missing, empty, non-regular or
oversized (> :data:`MAX_PATTERN_BYTES`) file and an unreadable one: :class:`PatternError`, whose
message names the file, the piece and the reason, e.g.
``pattern.dxf: piece FRONT: outline crosses itself near (0.12, 0.30) m``. With ``piece=`` only that
piece must be valid (another is left out with a :class:`PatternWarning`).

**Limits** (:mod:`clothsim.patternlimits`): coordinates, tolerance, flattened points, pieces, DXF
tags and INSERT expansion, SVG elements, ``<use>`` copies and path numbers are bounded; a file over
a bound is refused (:class:`PatternLimitError`) before the work it describes is done.
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Iterable, Mapping

import numpy as np

from . import patternlimits as limits
from .fileio import excerpt
from .patternlimits import MAX_COORDINATE, MAX_PIECES, MIN_TOLERANCE, PatternError, PatternLimitError

__all__ = ["Piece", "PatternError", "PatternLimitError", "read_pattern", "DEFAULT_TOLERANCE",
           "MAX_PATTERN_BYTES", "UNITS"]

log = logging.getLogger(__name__)

DEFAULT_TOLERANCE = 0.5e-3
"""Default chord error of flattened curves [m] (0.5 mm)."""

MAX_PATTERN_BYTES = 64 * 1024 * 1024
"""Largest pattern file read [bytes]; a garment's pattern is a few hundred kB."""

UNITS: Mapping[str, float] = MappingProxyType({
    "m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 1e-3, "in": 0.0254, "inch": 0.0254, "ft": 0.3048,
    "pt": 0.0254 / 72.0, "pc": 0.0254 / 6.0, "px": 0.0254 / 96.0, "q": 0.25e-3,
})
"""Length of one unit [m] by name, for ``units=`` (and SVG length units)."""

_INSUNITS = {1: "in", 2: "ft", 4: "mm", 5: "cm", 6: "m", 14: "dm"}
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


# --------------------------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------------------------

def read_pattern(path: str | os.PathLike, *, units: str | None = None,
                 tolerance: float = DEFAULT_TOLERANCE, piece: str | None = None) -> list[Piece]:
    """Read the pattern pieces of a ``.dxf`` or ``.svg`` file.

    Args:
        path: the pattern file; its suffix (``.dxf``/``.svg``, any case) chooses the reader.
        units: the length of one drawing unit, a key of :data:`UNITS` (``"mm"``, ``"cm"``, ``"in"``,
            ``"m"``, ``"px"``, ...); overrides what the file says. None: read or detect it (see
            the module docstring).
        tolerance: chord error of flattened curves and endpoint-join distance [m], at least
            :data:`~clothsim.patternlimits.MIN_TOLERANCE` (1 um).
        piece: the name of the piece wanted. None: every piece must be valid. Given: only that one
            must; another invalid piece is left out of the list with a :class:`PatternWarning`
            saying why.

    Returns:
        The (valid) pieces in file order (names made unique with `` (2)``, `` (3)`` suffixes).

    Raises:
        PatternError: the file cannot be read, holds no piece, or a piece is invalid; the message
            names the file, the piece and the reason. PatternLimitError (a PatternError): the
            file is over one of the bounds on the work of reading it (clothsim.patternlimits).
    """
    label = str(path)
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise PatternError(f"{label}: tolerance must be a positive length in metres (got {tolerance!r})")
    if not MIN_TOLERANCE <= tolerance <= 1.0:
        raise PatternError(f"{label}: tolerance must be between {MIN_TOLERANCE:g} m and 1 m (got {tolerance!r} m)")
    unit_m = None
    if units is not None:
        key = str(units).strip().lower()
        if key not in UNITS:
            raise PatternError(f"{label}: unknown units {units!r} (known: {', '.join(UNITS)})")
        unit_m = (key, UNITS[key])
    data = _read_bytes(label)
    suffix = Path(label).suffix.lower()
    if suffix not in (".dxf", ".svg"):
        raise PatternError(f"{label}: unknown pattern format '{suffix or '(none)'}' (expected .dxf or .svg)")
    token = limits.begin(label, tolerance)
    try:
        if suffix == ".dxf":
            limits.prescan_dxf(label, data)
            raw, notes = _dxf_pieces(label, data, unit_m, tolerance)
        else:
            limits.prescan_svg(label, data)
            raw, notes = _svg_pieces(label, data, unit_m, tolerance)
    except PatternError:
        raise
    except Exception as exc:   # a file that parses but holds broken entities: one clear message
        raise PatternError(f"{label}: cannot read the pattern ({type(exc).__name__}: "
                           f"{excerpt(exc, 80, quote=False)})") from exc
    finally:
        limits.end(token)
    if not raw:
        raise PatternError(f"{label}: no pattern pieces found" + (f" ({notes[-1]})" if notes else ""))
    ext = max((float(np.ptp(p.outline, axis=0).max()) for p in raw if p.error is None and len(p.outline)),
              default=0.0)
    lo, hi = PIECE_SPAN_RANGE
    if not lo <= ext <= hi and any(p.error is None for p in raw):
        # a metre file read as millimetres makes a garment of specks that "converges" (found by a
        # garment engineer's pass): say so where the run prints its warnings
        how = next((n for n in notes if "unit" in n.lower()), "")
        note = (f"largest piece spans {ext:.4g} m ({'under 5 mm' if ext < lo else 'over 5 m'}): check the "
                f"units" + (f" ({how})" if how else "") + "; panels.N.pattern.units sets them")
        notes.append(note)
        warnings.warn(PatternWarning(f"{label}: {note}"), stacklevel=2)
    for note in notes:
        log.info("%s: %s", label, note)
    pieces, seen = [], {}
    for rp in raw:
        name = rp.name
        seen[name] = seen.get(name, 0) + 1
        if seen[name] > 1:
            name = f"{name} ({seen[name]})"
        try:
            if rp.error is not None:
                raise PatternError(rp.error)
            with np.errstate(all="ignore"):
                pieces.append(_finish(label, name, rp, tolerance, tuple(notes)))
        except PatternError as exc:
            if piece is None or name == piece:
                raise
            warnings.warn(PatternWarning(f"{exc} (left out: the piece used is {piece!r})"), stacklevel=2)
    return pieces


def _read_bytes(label: str) -> bytes:
    """The file's bytes, refusing missing, non-regular, empty and oversized files and links out of
    their folder before reading (:func:`clothsim.fileio.read_input_bytes`)."""
    from .fileio import read_input_bytes

    return read_input_bytes(label, PatternError, limit=MAX_PATTERN_BYTES, what="pattern file",
                            allow_empty=False)


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


# --------------------------------------------------------------------------------------------
# DXF
# --------------------------------------------------------------------------------------------

_CURVE_TYPES = {"LINE", "ARC", "CIRCLE", "ELLIPSE", "SPLINE", "LWPOLYLINE", "POLYLINE"}
_NOTCH_LAYERS = {"4", "80", "81", "82", "83"}


def _dxf_pieces(label: str, data: bytes, unit_m, tol: float) -> tuple[list[_RawPiece], list[str]]:
    """Read the pieces of a DXF file (AAMA blocks, else plain closed entities), in metres."""
    import ezdxf
    from ezdxf import bbox

    try:
        doc = ezdxf.readfile(label)
    except Exception as exc:   # ezdxf raises many types on corrupt input; the user needs one message
        raise PatternError(f"{label}: not a readable DXF file ({type(exc).__name__}: "
                           f"{excerpt(exc, 80, quote=False)})") from None
    msp = doc.modelspace()
    work = limits.current()
    limits.insert_weight(label, doc, msp.query("INSERT"))
    groups: list[tuple[str, str, list]] = []   # (name, source, [(layer, entity)])
    for ins in msp.query("INSERT"):
        ents = list(_expand(ins, ins.dxf.layer))
        ox, oy = _xy(ins.dxf.insert)
        for _, e in ents:        # virtual copies: move them into the piece's own plane, in file units
            try:
                e.translate(-ox, -oy, 0.0)
            except (AttributeError, NotImplementedError, TypeError):
                pass
        if not any(lay == "1" and e.dxftype() in _CURVE_TYPES for lay, e in ents):
            continue
        name = _piece_name(ents) or ins.dxf.name
        groups.append((name, f"{label}: block {ins.dxf.name}", ents))
        if len(groups) > MAX_PIECES:
            raise PatternLimitError(f"{label}: more than {MAX_PIECES:,} pieces (INSERTs of blocks with a "
                                    f"layer-1 boundary): not read")
    notes: list[str] = []
    if groups:
        layout = "AAMA blocks"
        geo_all = [e for g in groups for lay, e in g[2] if lay == "1" and e.dxftype() in _CURVE_TYPES]
    else:
        layout = "plain modelspace"
        closed = [e for e in msp if _is_closed_entity(e)]
        geo_all = closed
        if len(closed) > MAX_PIECES:
            raise PatternLimitError(f"{label}: {len(closed):,} closed entities in modelspace, more than "
                                    f"{MAX_PIECES:,} pieces: not read")
    # ---- units
    if unit_m is not None:
        scale, how = unit_m[1], f"units: {unit_m[0]} (declared)"
    else:
        code = int(doc.header.get("$INSUNITS", 0) or 0)
        if code in _INSUNITS:
            scale, how = UNITS[_INSUNITS[code]], f"units: {_INSUNITS[code]} ($INSUNITS = {code})"
        elif code != 0:
            raise PatternError(f"{label}: $INSUNITS = {code} is not a garment unit; declare units "
                               f"(mm, cm, in, m)")
        else:
            scale, how = _detect_units(label, geo_all, bbox)
    notes.append(how + f"; {layout}")
    pieces: list[_RawPiece] = []
    if groups:
        for name, source, ents in groups:
            work.where = f"piece {name}"
            try:
                pieces.append(_aama_piece(label, name, source, ents, scale, tol))
            except PatternError as exc:
                pieces.append(_bad(label, name, source, exc))
    else:
        per_layer: dict[str, int] = {}
        for e in closed:
            per_layer[e.dxf.layer] = per_layer.get(e.dxf.layer, 0) + 1
        for e in closed:
            lay = e.dxf.layer
            name = lay if per_layer[lay] == 1 else f"{lay}:{e.dxf.handle}"
            source = f"{label}: {e.dxftype()} {e.dxf.handle} on layer {lay}"
            work.where = f"piece {name}, {e.dxftype()} {e.dxf.handle}"
            try:
                pts = _chain([p for p in _entity_polylines(label, name, e, scale, tol)])
            except PatternError as exc:
                pieces.append(_bad(label, name, source, exc))
                continue
            if len(pts) > 1 and np.hypot(*(pts[-1] - pts[0])) <= tol:
                pts = pts[:-1]
            pieces.append(_RawPiece(name, source, pts))
        work.where = ""
        _assign_plain_grain(msp, [p for p in pieces if p.error is None], scale)
        if not pieces:
            n_ins = len(msp.query("INSERT"))
            notes.append(f"no closed polyline/circle/spline in modelspace and no INSERT of a block with a "
                         f"layer-1 boundary ({n_ins} INSERT(s) seen)")
    return pieces, notes


def _expand(entity, layer: str, depth: int = 0) -> Iterable[tuple[str, object]]:
    """(effective layer, entity) of an INSERT's content in WCS, nested INSERTs expanded.
    Entities on layer 0 take the inserting entity's layer, as in DXF."""
    if depth > limits.MAX_DEPTH:
        raise PatternLimitError(f"INSERTs nest deeper than {limits.MAX_DEPTH} levels (block {entity.dxf.name!r})")
    for e in entity.virtual_entities():
        lay = e.dxf.layer if e.dxf.layer != "0" else layer
        if e.dxftype() == "INSERT":
            yield from _expand(e, lay, depth + 1)
        else:
            yield lay, e


_NAME_RE = re.compile(r"piece\s*name\s*:\s*(.+?)\s*$", re.IGNORECASE | re.MULTILINE)


def _piece_name(ents) -> str | None:
    """The AAMA piece system text ``Piece Name: X`` of a block, if any."""
    for _, e in ents:
        t = e.dxftype()
        if t == "TEXT":
            text = e.dxf.text
        elif t == "MTEXT":
            text = e.plain_text()
        else:
            continue
        m = _NAME_RE.search(text or "")
        if m and m.group(1):
            return m.group(1)
    return None


def _is_closed_entity(e) -> bool:
    t = e.dxftype()
    if t == "CIRCLE":
        return True
    if t == "LWPOLYLINE":
        return bool(e.closed) or (len(e) > 2 and tuple(e[0][:2]) == tuple(e[-1][:2]))
    if t == "POLYLINE":
        if not (e.is_2d_polyline or e.is_3d_polyline):
            return False
        pts = [v.dxf.location for v in e.vertices]
        return bool(e.is_closed) or (len(pts) > 2 and pts[0].isclose(pts[-1]))
    if t == "ELLIPSE":
        ct = e.construction_tool()
        return math.isclose(abs(ct.param_span), 2 * math.pi)
    if t == "SPLINE":
        return bool(e.closed)
    return False


def _entity_polylines(label: str, name: str, e, scale: float, tol: float) -> list[np.ndarray]:
    """Flattened (n, 2) polylines [m] of one DXF curve entity (several for a polyline's segments)."""
    from ezdxf.entities import Ellipse

    work = limits.current()
    t = e.dxftype()
    if t == "LINE":
        work.spend(2)
        return [work.check(np.array([_xy(e.dxf.start), _xy(e.dxf.end)], float) * scale, "a point")]
    if t in ("ARC", "CIRCLE", "ELLIPSE"):
        # the centre and radius in range before ezdxf's construction tool works with them
        r = abs(float(e.dxf.radius)) if t != "ELLIPSE" else float(np.hypot(*_xy(e.dxf.major_axis)))
        work.check((np.abs(_xy(e.dxf.center)) + r) * scale, "the curve")
        ct = (Ellipse.from_arc(e) if t != "ELLIPSE" else e).construction_tool()
        span = ct.param_span if t == "ELLIPSE" else (ct.end_param - ct.start_param) % (2 * math.pi)
        if t == "CIRCLE" or span == 0.0:
            span = 2 * math.pi
        pts = _flatten_ellipse(np.array(_xy(ct.center)) * scale, np.array(_xy(ct.major_axis)) * scale,
                               np.array(_xy(ct.minor_axis)) * scale, ct.start_param, span, tol)
        return [pts]
    if t in ("LWPOLYLINE", "POLYLINE"):
        work.need(len(e) if t == "LWPOLYLINE" else len(e.vertices))   # before ezdxf makes its segments
        parts = [p for v in e.virtual_entities() for p in _entity_polylines(label, name, v, scale, tol)]
        return [_chain(parts)] if parts else []
    if t == "SPLINE":
        return [_flatten_spline(label, name, e, scale, tol)]
    return []


def _handle(e) -> str:
    """An entity's handle for messages (a copy made by an INSERT: its source's), else its type's place."""
    h = e.dxf.handle
    if h is None:
        src = getattr(e, "source_of_copy", None)
        h = src.dxf.handle if src is not None else None
    return str(h) if h is not None else "(no handle)"


def _flatten_spline(label: str, name: str, e, scale: float, tol: float) -> np.ndarray:
    """A DXF SPLINE [m]: exact Bezier decomposition (clamped splines, rational ones homogeneously),
    each Bezier flattened by subdivision; unclamped splines by ezdxf's adaptive flattening."""
    from ezdxf.math import BSpline, Vec3

    try:
        bs = e.construction_tool()
    except Exception as exc:
        raise PatternError(f"{label}: piece {name}: unusable SPLINE {e.dxf.handle} "
                           f"({excerpt(exc, 80, quote=False)})") from None
    limits.current().check(np.array([_xy(v) for v in bs.control_points], float).reshape(-1, 2) * scale,
                           "a control point")
    if not bs.is_clamped:
        return _flatten_unclamped(label, name, e, bs, scale, tol)
    if bs.is_rational:
        w = np.asarray(bs.weights(), float)
        if not np.all(w > 0):
            raise PatternError(f"{label}: piece {name}: SPLINE {e.dxf.handle} has non-positive weights")
        cps = [Vec3(p.x * wi, p.y * wi, wi) for p, wi in zip(bs.control_points, w)]
        hom = BSpline(cps, order=bs.order, knots=bs.knots())
        segs = [np.array([(v.x * scale, v.y * scale, v.z) for v in seg]) for seg in hom.bezier_decomposition()]
    else:
        segs = [np.array([(v.x, v.y) for v in seg]) * scale for seg in bs.bezier_decomposition()]
    return _chain([_flatten_bezier(s, tol) for s in segs])


def _flatten_unclamped(label: str, name: str, e, bs, scale: float, tol: float) -> np.ndarray:
    """An unclamped (e.g. periodic, closed) non-rational B-spline of degree <= 3 [m], over its valid
    domain [u_p, u_(n+1)]: on each knot span p'' is a polynomial of degree <= 1, so max |p''| is at the
    span's ends, and steps h with h^2/8 max|p''| <= tol bound the chord error."""
    p = bs.degree
    if bs.is_rational or p > 3:
        raise PatternError(f"{label}: piece {name}: SPLINE {e.dxf.handle} is unclamped and "
                           f"{'rational' if bs.is_rational else f'of degree {p}'}: not supported")
    knots = np.asarray(bs.knots(), float)
    lo, hi = knots[p], knots[len(knots) - p - 1]
    ends = np.unique(knots[(knots >= lo) & (knots <= hi)])
    out = [np.array(_xy(bs.point(lo)))]
    work = limits.current()
    for u0, u1 in zip(ends[:-1], ends[1:]):
        d2 = max(math.hypot(*_xy(bs.derivative(u, n=2)[2])) for u in (u0, u1)) * scale
        n = 1 if d2 == 0 else max(1, (u1 - u0) / math.sqrt(8.0 * tol / d2))
        work.spend(n)
        n = math.ceil(n)
        out.extend(np.array(_xy(bs.point(u))) for u in u0 + (u1 - u0) * np.arange(1, n + 1) / n)
    return np.array(out) * scale


def _detect_units(label: str, ents, bbox) -> tuple[float, str]:
    """Units from the size of the largest piece, when the file does not say (see module docstring)."""
    sizes = []
    for e in ents:
        try:
            ext = bbox.extents([e], fast=True)
        except Exception:
            continue
        if ext.has_data:
            sizes.append(max(ext.size.x, ext.size.y))
    if not sizes:
        return 1.0, "units: none found (no geometry)"
    big = max(sizes)
    if 100.0 <= big <= 5000.0:
        return 1e-3, f"units: mm, detected from size (largest piece {big:.4g} units; no $INSUNITS)"
    if 0.02 <= big <= 3.0:
        return 1.0, f"units: m, detected from size (largest piece {big:.4g} units; no $INSUNITS)"
    raise PatternError(f"{label}: cannot tell the units: the largest piece spans {big:.4g} units and the "
                       f"file has no $INSUNITS; declare units (mm, cm, in, m)")


def _aama_piece(label: str, name: str, source: str, ents, scale: float, tol: float) -> _RawPiece:
    """One AAMA block: the layer-1 boundary joined into one loop, the layer-7 grain, layer-4 notches.

    ents are the INSERT's entities (file units), already moved so that the insertion point is the
    origin: the piece's own plane, with the insert's rotation, scale and mirror kept and its place
    on the marker dropped. The result is in metres."""
    curves = []
    work = limits.current()
    for lay, e in ents:
        if lay == "1" and e.dxftype() in _CURVE_TYPES:
            work.where = f"piece {name}, {e.dxftype()} {_handle(e)}"
            curves.extend(_entity_polylines(label, name, e, scale, tol))
    work.where = f"piece {name}"
    loops, left = _join(curves, tol)
    if not loops:
        gap = ""
        if left:
            ch = max(left, key=len)
            g = float(np.hypot(*(ch[-1] - ch[0])))
            if g <= tol:
                # the chain's ends are within the tolerance but it has fewer than 3 points: its
                # pieces are shorter than the tolerance, so their ends cannot be told apart
                span = max(float(np.hypot(*(c[-1] - c[0]))) for c in curves if len(c) >= 2)
                gap = (f": its {len(curves)} segment(s) are at most {span:.3g} m long, not longer than "
                       f"the join tolerance of {tol:g} m, so their ends cannot be told apart; give a "
                       f"smaller tolerance (panels.N.pattern.tolerance) or check the units")
            else:
                gap = (f": the boundary does not close, gap of {g:.4g} m near "
                       f"({ch[-1][0]:.4g}, {ch[-1][1]:.4g}) m")
        raise PatternError(f"{label}: piece {name}: no closed boundary on layer 1{gap}")
    outline = max(loops, key=lambda p: abs(_signed_area(p)))
    rp = _RawPiece(name, source, outline)
    grains = []
    for lay, e in ents:
        if lay == "7":
            g = _two_points(e)
            if g is not None:
                grains.append(g * scale)
        elif lay in _NOTCH_LAYERS:
            if e.dxftype() == "POINT":
                rp.notches.append(np.array(_xy(e.dxf.location), float) * scale)
            else:
                g = _two_points(e)
                if g is not None:
                    g = g * scale
                    d = [_dist_to_polygon(q, outline) for q in g]
                    rp.notches.append(g[int(np.argmin(d))])
    if grains:
        g = max(grains, key=lambda g: np.hypot(*(g[1] - g[0])))
        rp.grain = (g[0], g[1])
    return rp


def _xy(v) -> tuple[float, float]:
    """(x, y) of an ezdxf Vec3 (z dropped)."""
    return (float(v.x), float(v.y))


def _two_points(e) -> np.ndarray | None:
    """(2, 2) first and last point of a LINE or polyline (file units), else None."""
    t = e.dxftype()
    if t == "LINE":
        return np.array([_xy(e.dxf.start), _xy(e.dxf.end)], float)
    if t == "LWPOLYLINE" and len(e) >= 2:
        pts = e.get_points("xy")
        return np.array([pts[0], pts[-1]], float)
    if t == "POLYLINE":
        pts = [_xy(v.dxf.location) for v in e.vertices]
        if len(pts) >= 2:
            return np.array([pts[0], pts[-1]], float)
    return None


def _dist_to_polygon(q: np.ndarray, poly: np.ndarray) -> float:
    """Distance from q (2,) to the boundary of the closed polygon poly (K, 2)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
    return float(np.min(np.hypot(*(a + t[:, None] * ab - q).T)))


def _assign_plain_grain(msp, pieces: list[_RawPiece], scale: float) -> None:
    """Plain DXF: a LINE on layer 7 or a layer named *grain* is the grain of the piece holding its midpoint."""
    import shapely

    if not pieces:
        return
    polys = [shapely.Polygon(p.outline) if len(p.outline) >= 3 else None for p in pieces]
    for e in msp.query("LINE"):
        lay = e.dxf.layer
        if lay != "7" and "grain" not in lay.lower():
            continue
        g = _two_points(e) * scale
        mid = shapely.Point(*(0.5 * (g[0] + g[1])))
        for p, poly in zip(pieces, polys):
            if poly is not None and p.grain is None and poly.is_valid and poly.contains(mid):
                p.grain = (g[0], g[1])
                break


# --------------------------------------------------------------------------------------------
# SVG
# --------------------------------------------------------------------------------------------

_INK_LABEL = "{http://www.inkscape.org/namespaces/inkscape}label"
_LEN_RE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z%]*)\s*$")


def _svg_length_m(text: str | None) -> float | None:
    """An absolute SVG length in metres (mm, cm, in, pt, pc, px, Q or unitless px), None otherwise."""
    if not text:
        return None
    m = _LEN_RE.match(str(text))
    if not m:
        return None
    unit = m.group(2).lower() or "px"
    return float(m.group(1)) * UNITS[unit] if unit in UNITS else None


def _svg_pieces(label: str, data: bytes, unit_m, tol: float) -> tuple[list[_RawPiece], list[str]]:
    """Read the pieces of an SVG file, in metres, y up."""
    from svgelements import SVG, Group, Matrix, Shape

    try:
        svg = SVG.parse(io.BytesIO(data), reify=True, ppi=96.0)
    except Exception as exc:
        raise PatternError(f"{label}: not a readable SVG file ({type(exc).__name__}: "
                           f"{excerpt(exc, 80, quote=False)})") from None
    if not isinstance(svg, SVG):
        raise PatternError(f"{label}: not a readable SVG file (no <svg> root)")
    attrs = svg.values.get("attributes", {}) or {}
    # svgelements maps user units to px with its own mm constant; undo the root viewBox mapping
    # and apply the exact length of one user unit instead.
    root = Matrix(svg.viewbox.transform(svg)) if svg.viewbox is not None else Matrix()
    to_user = ~root
    vb = svg.viewbox
    if unit_m is not None:
        k, how = unit_m[1], f"units: user unit = 1 {unit_m[0]} (declared)"
    else:
        w, h = _svg_length_m(attrs.get("width")), _svg_length_m(attrs.get("height"))
        if vb is not None and (w or h) and vb.width and vb.height:
            ks = [x for x in (w / vb.width if w else None, h / vb.height if h else None) if x]
            k = min(ks)
            how = (f"units: user unit = {k * 1e3:.6g} mm (width {attrs.get('width')}, "
                   f"height {attrs.get('height')}, viewBox {attrs.get('viewBox')})")
        else:
            k = UNITS["px"]
            how = "units: px (1/96 in): the SVG has no viewBox with an absolute width or height"
    A = np.array([[to_user.a, to_user.c], [to_user.b, to_user.d]]) * np.array([[k], [-k]])
    off = np.array([to_user.e * k, -to_user.f * k])

    def to_m(pt) -> np.ndarray:
        return A @ np.array([pt[0], pt[1]], float) + off

    pieces: list[_RawPiece] = []
    group_of: list[int] = []
    grains: list[tuple[int, np.ndarray]] = []
    open_count = 0
    counter: dict[str, int] = {}
    gid = [0]

    def own(e) -> dict:
        return e.values.get("attributes", {}) or {}

    def ident_of(a: dict) -> str:
        return " ".join(str(a.get(x, "")) for x in ("id", "class", _INK_LABEL)).lower()

    def walk(g, gname: str | None, gkey: int, grain_group: bool):
        nonlocal open_count
        for e in g:
            if isinstance(e, Group):
                a = own(e)
                gid[0] += 1
                is_grain = grain_group or "grain" in ident_of(a)   # a grain group belongs to its parent's piece
                walk(e, a.get(_INK_LABEL) or a.get("id") or gname, gkey if is_grain else gid[0], is_grain)
                continue
            if not isinstance(e, Shape):
                continue
            a = own(e)
            tag = str(a.get("tag", type(e).__name__.lower()))
            guess = a.get(_INK_LABEL) or a.get("id") or gname or f"{tag}{counter.get(tag, 0) + 1}"
            work.where = f"piece {guess}, <{tag}>"
            try:
                subpaths = _svg_subpaths(e, to_m, tol)
            except PatternError as exc:
                if grain_group or "grain" in ident_of(a):
                    raise
                counter[tag] = counter.get(tag, 0) + 1
                pieces.append(_bad(label, str(guess), f"{label}: <{tag}> {a.get('id') or guess}", exc))
                group_of.append(gkey)
                continue
            if grain_group or "grain" in ident_of(a):
                pts = [p for p, _ in subpaths if len(p) >= 2]
                if pts:
                    grains.append((gkey, np.array([pts[0][0], pts[-1][-1]])))
                continue
            closed = [p for p, c in subpaths if c]
            if not closed:
                open_count += 1
                continue
            counter[tag] = counter.get(tag, 0) + 1
            name = a.get(_INK_LABEL) or a.get("id") or gname or f"{tag}{counter[tag]}"
            source = f"{label}: <{tag}> {a.get('id') or name}"
            if len(closed) > 1:
                pieces.append(_bad(label, str(name), source, PatternError(
                    f"{label}: piece {name}: <{tag}> holds {len(closed)} closed subpaths; a piece is one "
                    f"outline (holes and compound paths are not supported)")))
            else:
                pieces.append(_RawPiece(str(name), source, closed[0]))
            group_of.append(gkey)
            if len(pieces) > MAX_PIECES:
                raise PatternLimitError(f"{label}: more than {MAX_PIECES:,} pieces: not read")

    work = limits.current()
    walk(svg, None, 0, False)
    work.where = ""
    good = [i for i, p in enumerate(pieces) if p.error is None]
    _assign_svg_grain([pieces[i] for i in good], [group_of[i] for i in good], grains)
    notes = [how]
    if not pieces:
        notes.append(f"no closed <path>, <polygon>, <rect>, <circle> or <ellipse>; {open_count} open shape(s)")
    return pieces, notes


def _svg_subpaths(e, to_m, tol: float) -> list[tuple[np.ndarray, bool]]:
    """Flattened subpaths (points [m], closed?) of an svgelements shape (transform applied)."""
    from svgelements import Arc, Close, CubicBezier, Line, Move, Path, QuadraticBezier

    out: list[tuple[np.ndarray, bool]] = []
    cur: list[np.ndarray] = []
    closed = False

    def flush():
        nonlocal cur, closed
        if cur:
            pts = _chain(cur)
            if len(pts) >= 2:
                if not closed and len(pts) > 3 and np.hypot(*(pts[-1] - pts[0])) <= tol:
                    closed = True
                if closed and len(pts) > 1 and np.hypot(*(pts[-1] - pts[0])) <= tol:
                    pts = pts[:-1]
                out.append((pts, closed))
        cur, closed = [], False

    try:
        segs = list(Path(e).segments())
    except Exception:
        return out
    work = limits.current()
    for s in segs:
        if isinstance(s, Move):
            flush()
        elif isinstance(s, Close):
            if s.start is not None and s.end is not None:
                p0, p1 = work.check([to_m(s.start), to_m(s.end)], "a segment")
                if math.hypot(*(p1 - p0)) > 1e-6 * tol:
                    work.spend(2)
                    cur.append(np.array([p0, p1]))
            closed = True
        elif isinstance(s, Line):
            work.spend(2)
            cur.append(work.check([to_m(s.start), to_m(s.end)], "a segment"))
        elif isinstance(s, (QuadraticBezier, CubicBezier)):
            ctrl = [s.start, s.control, s.end] if isinstance(s, QuadraticBezier) else \
                [s.start, s.control1, s.control2, s.end]
            cur.append(_flatten_bezier(work.check([to_m(p) for p in ctrl], "a curve's control point"), tol))
        elif isinstance(s, Arc):
            cur.append(_svg_arc(s, to_m, tol))
    flush()
    return out


def _svg_arc(s, to_m, tol: float) -> np.ndarray:
    """Flatten an svgelements Arc: p(t) = c + cos t A + sin t B with A, B the (transformed)
    conjugate semi-diameters ``prx - center`` and ``pry - center``; the direction is the one that
    passes through svgelements' own midpoint of the arc."""
    c, p0, p1, prx, pry = limits.current().check([to_m(q) for q in (s.center, s.start, s.end, s.prx, s.pry)],
                                                 "an arc")
    A, B = prx - c, pry - c
    M = np.column_stack([A, B])
    if abs(np.linalg.det(M)) <= 1e-300:
        return np.array([p0, p1])

    def param(q):
        cs = np.linalg.solve(M, q - c)
        return math.atan2(cs[1], cs[0])

    t0, t1, tm = param(p0), param(p1), param(to_m(s.point(0.5)))
    d = (t1 - t0) % (2 * math.pi)
    if d == 0.0:
        d = 2 * math.pi
    sweep = d if (tm - t0) % (2 * math.pi) < d else d - 2 * math.pi
    pts = _flatten_ellipse(c, A, B, t0, sweep, tol)
    pts[0], pts[-1] = p0, p1
    return pts


def _assign_svg_grain(pieces: list[_RawPiece], group_of: list[int],
                      grains: list[tuple[int, np.ndarray]]) -> None:
    """Give each grainline to the piece of its group (the one holding its midpoint if several)."""
    import shapely

    for gkey, g in grains:
        cands = [i for i, k in enumerate(group_of) if k == gkey and pieces[i].grain is None]
        mid = shapely.Point(*(0.5 * (g[0] + g[-1])))
        if len(cands) != 1:
            pool = cands or [i for i in range(len(pieces)) if pieces[i].grain is None]
            cands = [i for i in pool if len(pieces[i].outline) >= 3
                     and shapely.Polygon(pieces[i].outline).buffer(0).contains(mid)]
        if len(cands) >= 1:
            pieces[cands[0]].grain = (g[0], g[-1])
