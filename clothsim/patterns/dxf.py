"""DXF pattern files (DXF-AAMA / ASTM D6673 blocks, or plain closed entities in modelspace),
read with ezdxf (imported when a DXF file is read): pieces, grainlines, notches, units from
``$INSUNITS`` or detected from size. The layouts are described in :mod:`clothsim.patterns`."""

from __future__ import annotations

import math
import re
from typing import Iterable

import numpy as np

from .. import patternlimits as limits
from ..fileio import excerpt
from ..patternlimits import MAX_PIECES, PatternError, PatternLimitError
from .geometry import (UNITS, _RawPiece, _bad, _chain, _dist_to_polygon, _flatten_bezier,
                       _flatten_ellipse, _join, _signed_area)


_INSUNITS = {1: "in", 2: "ft", 4: "mm", 5: "cm", 6: "m", 14: "dm"}


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
