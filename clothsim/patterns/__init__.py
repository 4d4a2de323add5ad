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

The modules, by job: :mod:`.dxf` (DXF files), :mod:`.svg` (SVG files), :mod:`.geometry` (the
:class:`Piece`, flattening, joining, checks); this one reads a file (:func:`read_pattern`) and
re-exports their names.
"""

from __future__ import annotations

import logging
import math
import os
import warnings
from pathlib import Path

import numpy as np

from .. import patternlimits as limits
from ..fileio import excerpt, read_input_bytes
from ..patternlimits import MIN_TOLERANCE, PatternError, PatternLimitError
from .dxf import _dxf_pieces
from .geometry import DEFAULT_TOLERANCE, PIECE_SPAN_RANGE, PatternWarning, Piece, UNITS, _finish
from .svg import _svg_pieces


# the rest of the readers' names, as the single module had them
from .dxf import (_CURVE_TYPES, _INSUNITS, _NAME_RE, _NOTCH_LAYERS, _aama_piece,  # noqa: F401
                  _assign_plain_grain, _detect_units, _entity_polylines, _expand,
                  _flatten_spline, _flatten_unclamped, _handle, _is_closed_entity, _piece_name,
                  _two_points, _xy)
from .geometry import (_MAX_DEPTH, _ZERO_AREA, _RawPiece, _bad, _chain, _dist_to_polygon,  # noqa: F401
                       _drop_repeats, _flatten_bezier, _flatten_ellipse, _hull_within, _join,
                       _perimeter, _signed_area, _snap, _split_half)
from .svg import (_INK_LABEL, _LEN_RE, _assign_svg_grain, _svg_arc, _svg_length_m,  # noqa: F401
                  _svg_subpaths)

__all__ = ["Piece", "PatternError", "PatternLimitError", "read_pattern", "DEFAULT_TOLERANCE",
           "MAX_PATTERN_BYTES", "UNITS"]


log = logging.getLogger(__name__)


MAX_PATTERN_BYTES = 64 * 1024 * 1024
"""Largest pattern file read [bytes]; a garment's pattern is a few hundred kB."""


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
    return read_input_bytes(label, PatternError, limit=MAX_PATTERN_BYTES, what="pattern file",
                            allow_empty=False)
