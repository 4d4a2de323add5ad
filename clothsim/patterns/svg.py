"""SVG pattern files, read with svgelements (imported when an SVG file is read): closed shapes
are pieces, ``grain`` elements their grainlines, transforms applied, y turned up, units from
``units=`` or the root's width/height over its viewBox. See :mod:`clothsim.patterns`."""

from __future__ import annotations

import io
import math
import re

import numpy as np

from .. import patternlimits as limits
from ..fileio import excerpt
from ..patternlimits import MAX_PIECES, PatternError, PatternLimitError
from .geometry import UNITS, _RawPiece, _bad, _chain, _flatten_bezier, _flatten_ellipse


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
