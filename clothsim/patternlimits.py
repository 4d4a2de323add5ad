"""Bounds on the work of reading a pattern file (clothsim.patterns), and the indexed boundary join.

A pattern file of a few kilobytes can describe unbounded work: a curve a light-year long flattened
to half a millimetre, INSERTs of blocks that insert blocks ten times each, SVG ``<use>`` fan-out,
a path of millions of segments. Every such file is refused, quickly (before the work), with a
:class:`PatternLimitError` naming the file (and the piece and entity where the reader knows them):

* :func:`prescan_dxf` / :func:`prescan_svg` bound the file before its parser runs (DXF tags; SVG
  elements, ``<use>`` expansion and the numbers of path data, ``<use>`` expansion counted);
* :func:`insert_weight` bounds what a DXF's INSERTs expand to (nested INSERTs multiply), and
  their nesting depth, before anything is expanded;
* a :class:`Work` context (one per read, per thread) holds the file's point budget and checks
  coordinates: every point handed to the flattening lies within :data:`MAX_COORDINATE` of the
  origin (the bound scene coordinates and molds are held to), and no flattening allocates more
  than :data:`MAX_POINTS` points in all (a circle of radius 10^6 m at the default tolerance needs
  about 10^5).

:func:`join` joins a boundary's open pieces end to end through a grid of their endpoints (cells of
the join tolerance), so that n pieces cost O(n), not O(n^2): 4,000 shuffled LINEs took 55 s.
"""

from __future__ import annotations

import contextvars
import math
import re
import xml.etree.ElementTree as ET
from collections import deque

import numpy as np

#: smallest ``tolerance`` [m] (1 um): below it chord errors drown in round-off at garment sizes
MIN_TOLERANCE = 1e-6
#: largest coordinate magnitude [m] of a pattern point after units and transforms (as for scenes and molds)
MAX_COORDINATE = 1e6
#: most pattern pieces in one file
MAX_PIECES = 1000
#: most DXF tags (code/value pairs) in a file; a garment's DXF-AAMA export has a few 10,000
MAX_DXF_TAGS = 500_000
#: most entities a DXF's INSERTs expand to, nested INSERTs multiplied out
MAX_INSERTED = 50_000
#: deepest nesting of DXF INSERTs and of SVG ``<use>`` references
MAX_DEPTH = 16
#: most SVG elements, ``<use>`` references expanded
MAX_SVG_ELEMENTS = 50_000
#: most ``<use>`` references an SVG expands to (each is a copy of what it names)
MAX_SVG_USES = 1000
#: most numbers in an SVG's shape data (``d``, ``points``), ``<use>`` references expanded
MAX_SVG_NUMBERS = 200_000
#: most points of all flattened outlines of one file (a garment's pieces have a few thousand)
MAX_POINTS = 200_000


class PatternError(ValueError):
    """A pattern file cannot be used. ``str(err)`` names the file, the piece and the reason."""


class PatternLimitError(PatternError):
    """A pattern file over one of the work bounds: the whole file is refused, whatever piece is asked."""


# --------------------------------------------------------------------------------------------
# the work of one read
# --------------------------------------------------------------------------------------------

class Work:
    """The point budget and coordinate bound of one read. ``where`` names what is being read
    ("piece FRONT, CIRCLE 2A") for messages; :meth:`spend` counts points before they are made."""

    def __init__(self, label: str, tol: float):
        self.label, self.tol = label, tol
        self.where = ""
        self.points = 0

    def _at(self) -> str:
        return f"{self.label}: {self.where}: " if self.where else f"{self.label}: "

    def spend(self, n: float) -> None:
        """Count n more outline points; PatternLimitError past MAX_POINTS (n may be inf)."""
        self.need(n)
        self.points += int(n)

    def need(self, n: float) -> None:
        """PatternLimitError if n more points (an estimate; not counted) would pass MAX_POINTS."""
        if not n <= MAX_POINTS - self.points:
            raise PatternLimitError(
                f"{self._at()}flattening the curves at a tolerance of {self.tol:g} m would make more than "
                f"{MAX_POINTS:,} points (a garment needs a few thousand): check the units, or give a "
                f"larger tolerance")

    def check(self, pts, what: str = "a point") -> np.ndarray:
        """pts (..., 2) [m] as float64; PatternError (of the piece) for non-finite coordinates or
        one beyond MAX_COORDINATE."""
        with np.errstate(all="ignore"):
            p = np.asarray(pts, dtype=np.float64)
            m = float(np.max(np.abs(p))) if p.size else 0.0
        if not math.isfinite(m):
            raise PatternError(f"{self._at()}{what} has non-finite coordinates (an overflowing "
                               f"transform or value)")
        if m > MAX_COORDINATE:
            raise PatternError(f"{self._at()}{what} has a coordinate of {m:.3g} m, beyond the bound of "
                               f"{MAX_COORDINATE:.0e} m (check the units)")
        return p


_WORK: contextvars.ContextVar[Work | None] = contextvars.ContextVar("clothsim_pattern_work", default=None)


def current() -> Work:
    """The Work of the read in progress (a lenient one outside :func:`begin`, for direct calls)."""
    w = _WORK.get()
    return w if w is not None else Work("pattern", 1.0)


def begin(label: str, tol: float):
    """Start a read's Work; returns the token for :func:`end`."""
    return _WORK.set(Work(label, tol))


def end(token) -> None:
    _WORK.reset(token)


# --------------------------------------------------------------------------------------------
# before the parsers
# --------------------------------------------------------------------------------------------

def prescan_dxf(label: str, data: bytes) -> None:
    """Refuse a DXF of more than MAX_DXF_TAGS tags before ezdxf reads it (ezdxf reads about
    15,000 entities a second: a 36 MB file of a million circles took minutes)."""
    if data.startswith(b"AutoCAD Binary DXF"):
        tags = len(data) // 8          # a binary tag takes at least about 8 bytes
    else:
        tags = max(data.count(b"\n"), data.count(b"\r")) // 2   # (a file may end its lines with CR alone)
    if tags > MAX_DXF_TAGS:
        raise PatternLimitError(f"{label}: about {tags:,} DXF tags, more than {MAX_DXF_TAGS:,} (a garment "
                                f"pattern has a few 10,000): not read")


def insert_weight(label: str, doc, inserts) -> None:
    """Refuse INSERTs that expand to more than MAX_INSERTED entities or nest deeper than MAX_DEPTH,
    or a block that inserts itself, before anything is expanded: each block's weight (its entities,
    polyline vertices counted, and its INSERTs' blocks times their MINSERT counts) once."""
    memo: dict[str, int] = {}
    busy: set[str] = set()

    def weight(name: str, depth: int) -> int:
        if name in memo:
            return memo[name]
        if depth > MAX_DEPTH:
            raise PatternLimitError(f"{label}: INSERTs of block {name!r} nest deeper than {MAX_DEPTH} levels")
        if name in busy:
            raise PatternLimitError(f"{label}: block {name!r} inserts itself")
        blk = doc.blocks.get(name)
        if blk is None:
            return 0
        busy.add(name)
        w = 0
        for e in blk:
            w += _entity_weight(e, lambda n: weight(n, depth + 1))
            if w > MAX_INSERTED:
                break
        busy.discard(name)
        memo[name] = w
        return w

    total = 0
    for ins in inserts:
        total += _entity_weight(ins, lambda n: weight(n, 1))
        if total > MAX_INSERTED:
            raise PatternLimitError(f"{label}: the INSERTs expand to more than {MAX_INSERTED:,} entities "
                                    f"(INSERT {ins.dxf.handle} of block {ins.dxf.name!r}, nested INSERTs "
                                    f"multiplied out): not read")


def _entity_weight(e, block_weight) -> int:
    t = e.dxftype()
    if t == "INSERT":
        count = max(1, int(getattr(e, "mcount", 1) or 1))
        return count * (1 + block_weight(e.dxf.name)) + len(getattr(e, "attribs", ()))
    if t == "LWPOLYLINE":
        return max(1, len(e))
    if t == "POLYLINE":
        return max(1, len(e.vertices))
    return 1


_NUM_RE = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_SVG_NS = "{http://www.w3.org/2000/svg}"
_HREFS = ("href", "{http://www.w3.org/1999/xlink}href")


def _count_numbers(text: str, cap: int) -> int:
    """The numbers in text, counting stopped past cap (a 40 MB path costs no more than cap)."""
    n = 0
    for _ in _NUM_RE.finditer(text):
        n += 1
        if n > cap:
            break
    return n


def prescan_svg(label: str, data: bytes) -> None:
    """Refuse an SVG whose elements, ``<use>`` copies or shape numbers (path data, points),
    ``<use>`` references expanded, pass MAX_SVG_ELEMENTS, MAX_SVG_USES or MAX_SVG_NUMBERS, or
    whose references nest deeper than MAX_DEPTH or refer to themselves, before svgelements
    builds them (a 1 KB file of nested ``<use>`` built 1.3 GB). An unparsable file passes (the
    SVG reader says why it cannot read it)."""
    try:
        root = ET.fromstring(data)
    except Exception:   # noqa: BLE001 - the SVG reader reports unreadable files
        return
    by_id = {}
    for el in root.iter():
        i = el.get("id")
        if i is not None:
            by_id.setdefault(i, el)
    memo: dict[int, tuple[int, int, int]] = {}
    busy: set[int] = set()

    def over(e: int, u: int, n: int) -> bool:
        return e > MAX_SVG_ELEMENTS or u > MAX_SVG_USES or n > MAX_SVG_NUMBERS

    def weight(el, depth: int) -> tuple[int, int, int]:
        key = id(el)
        if key in memo:
            return memo[key]
        if key in busy:
            raise PatternLimitError(f"{label}: <use> of '#{el.get('id')}' refers to itself")
        if depth > MAX_DEPTH:
            raise PatternLimitError(f"{label}: <use> references nest deeper than {MAX_DEPTH} levels")
        busy.add(key)
        e, u = 1, 0
        n = sum(_count_numbers(el.get(a) or "", MAX_SVG_NUMBERS) for a in ("d", "points"))
        tag = el.tag.removeprefix(_SVG_NS) if isinstance(el.tag, str) else ""
        if tag == "use":
            u += 1
            href = next((el.get(h) for h in _HREFS if el.get(h)), "")
            target = by_id.get(href[1:]) if href.startswith("#") else None
            if target is not None:
                we, wu, wn = weight(target, depth + 1)
                e, u, n = e + we, u + wu, n + wn
        for ch in el:
            if over(e, u, n):
                break
            we, wu, wn = weight(ch, depth)
            e, u, n = e + we, u + wu, n + wn
        busy.discard(key)
        memo[key] = (e, u, n)
        return e, u, n

    e, u, n = weight(root, 0)
    if u > MAX_SVG_USES:
        raise PatternLimitError(f"{label}: its <use> references expand to more than {MAX_SVG_USES:,} copies: not read")
    if e > MAX_SVG_ELEMENTS:
        raise PatternLimitError(f"{label}: more than {MAX_SVG_ELEMENTS:,} elements (<use> references expanded): "
                                f"not read")
    if n > MAX_SVG_NUMBERS:
        raise PatternLimitError(f"{label}: more than {MAX_SVG_NUMBERS:,} numbers of path data and points "
                                f"(<use> references expanded; a garment's pieces need a few 10,000): not read")


# --------------------------------------------------------------------------------------------
# joining boundary pieces
# --------------------------------------------------------------------------------------------

def join(curves: list[np.ndarray], tol: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Join open polylines (each (n, 2) [m]) end to end into closed loops.

    Endpoints within tol are joined (the earlier point kept). A chain grows from the first unused
    piece by the lowest-numbered unused piece with an end within tol of either of its ends, until
    its ends meet; the candidates come from a grid of the pieces' endpoints (cells of tol), so the
    join is linear in the number of pieces. Returns (loops, leftovers): loops are (K, 2) with the
    first point not repeated; leftovers are the chains that did not close."""
    curves = [c for c in curves if len(c) >= 2]
    grid: dict[tuple[int, int], list[int]] = {}

    def cell(p) -> tuple[int, int]:
        return (math.floor(p[0] / tol), math.floor(p[1] / tol))

    for k, c in enumerate(curves):
        for p in (c[0], c[-1]):
            grid.setdefault(cell(p), []).append(k)
    used = [False] * len(curves)

    def near(p, found: set[int]) -> None:
        cx, cy = cell(p)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for k in grid.get((cx + dx, cy + dy), ()):
                    if not used[k] and (math.dist(curves[k][0], p) <= tol or math.dist(curves[k][-1], p) <= tol):
                        found.add(k)

    loops, left = [], []
    for i, first in enumerate(curves):
        if used[i]:
            continue
        used[i] = True
        chain = deque(first)
        while math.dist(chain[-1], chain[0]) > tol:
            found: set[int] = set()
            near(chain[-1], found)
            near(chain[0], found)
            if not found:
                break
            k = min(found)
            c = curves[k]
            used[k] = True
            if math.dist(c[0], chain[-1]) <= tol:
                chain.extend(c[1:])
            elif math.dist(c[-1], chain[-1]) <= tol:
                chain.extend(c[-2::-1])
            elif math.dist(c[-1], chain[0]) <= tol:
                chain.extendleft(c[-2::-1])
            else:
                chain.extendleft(c[1:])
        arr = np.array(chain)
        if len(arr) >= 3 and math.dist(arr[-1], arr[0]) <= tol:
            loops.append(arr[:-1])
        else:
            left.append(arr)
    return loops, left
