"""Tests of clothsim.patterns: pattern pieces read from DXF (AAMA blocks, plain) and SVG files.

References: the tests write their own files (ezdxf for DXF, SVG text), so every outline is known
exactly. Polygons must come back with their exact area and perimeter (1e-12 relative); curves are
checked against the chord-error guarantee -- every vertex on the true curve, every point of the
curve (densely sampled, independently of the reader: ezdxf's B-spline evaluator, the circle's
equation, the Bezier polynomial) within the tolerance of the outline -- and a circle's area error
against its bound 0 < pi r^2 - A <= P * tol. Every error message is checked for file, piece and reason.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import ezdxf
import numpy as np
import pytest
from ezdxf.math import BSpline

from clothsim import patterns
from clothsim.patterns import DEFAULT_TOLERANCE, PatternError, Piece, read_pattern

ROOT = Path(__file__).resolve().parents[1]
PATTERNS = ROOT / "static" / "patterns"


# ---------------------------------------------------------------------------------------------
# independent references
# ---------------------------------------------------------------------------------------------

def shoelace(p) -> float:
    p = np.asarray(p, float)
    return 0.5 * sum(p[i, 0] * p[(i + 1) % len(p), 1] - p[(i + 1) % len(p), 0] * p[i, 1] for i in range(len(p)))


def perimeter(p) -> float:
    p = np.asarray(p, float)
    return sum(math.dist(p[i], p[(i + 1) % len(p)]) for i in range(len(p)))


def dist_to_outline(q, outline) -> float:
    """Distance from q to the closed polygon's boundary (segment by segment; not the module's code)."""
    a = np.asarray(outline, float)
    ab = np.roll(a, -1, axis=0) - a
    t = np.clip(((q - a) * ab).sum(axis=1) / (ab * ab).sum(axis=1), 0.0, 1.0)
    return float(np.min(np.hypot(*(a + t[:, None] * ab - q).T)))


def assert_piece_shape(piece: Piece):
    """The documented contract: (K, 2) float64, K >= 3, counter-clockwise, first point not repeated."""
    assert piece.outline.dtype == np.float64 and piece.outline.ndim == 2 and piece.outline.shape[1] == 2
    assert len(piece.outline) >= 3
    assert shoelace(piece.outline) > 0
    assert not np.allclose(piece.outline[0], piece.outline[-1])
    assert not piece.outline.flags.writeable
    if piece.grain is not None:
        assert piece.grain.shape == (2,) and abs(np.hypot(*piece.grain) - 1) < 1e-15


def aama_doc(units=4):
    doc = ezdxf.new("R2000", units=units)
    for layer in ("1", "4", "7"):
        doc.layers.add(layer)
    return doc


def add_piece(doc, name, boundary, grain=None, text=True, at=(0.0, 0.0), **insert_kw):
    """A block `name` with a closed layer-1 LWPOLYLINE (or a callable drawing the boundary), an
    optional layer-7 grain LINE and a ``Piece Name:`` text; inserted at `at`."""
    blk = doc.blocks.new(name=f"B_{name}")
    if callable(boundary):
        boundary(blk)
    else:
        blk.add_lwpolyline(boundary, close=True, dxfattribs={"layer": "1"})
    if grain is not None:
        blk.add_line(grain[0], grain[1], dxfattribs={"layer": "7"})
    if text:
        blk.add_text(f"Piece Name: {name}", dxfattribs={"layer": "1", "insert": (1, 1), "height": 2})
    doc.modelspace().add_blockref(f"B_{name}", at, dxfattribs=insert_kw)
    return blk


def write_svg(path: Path, body: str, head: str = 'width="200mm" height="100mm" viewBox="0 0 200 100"') -> Path:
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" '
                    'xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" ' + head + ">\n"
                    + body + "\n</svg>\n")
    return path


# ---------------------------------------------------------------------------------------------
# DXF-AAMA
# ---------------------------------------------------------------------------------------------

def test_aama_polygon_exact_area_perimeter_grain_name(tmp_path):
    """AAMA blocks: the polygon comes back exact (area and perimeter within 1e-12), counter-clockwise
    (given clockwise here), named by its ``Piece Name:`` text, grain read from layer 7, mm from $INSUNITS,
    the insert's position on the marker dropped."""
    doc = aama_doc(units=4)
    front_mm = [(0, 0), (0, 300), (220, 310), (240, 0)]           # clockwise on purpose
    back_mm = [(0, 0), (250, 0), (230, 280), (10, 300)]
    g = math.radians(30)
    add_piece(doc, "FRONT", front_mm, grain=((50, 50), (50 + 100 * math.cos(g), 50 + 100 * math.sin(g))))
    add_piece(doc, "BACK", back_mm, at=(400.0, 50.0))
    path = tmp_path / "pattern.dxf"
    doc.saveas(path)
    front, back = read_pattern(path)
    assert (front.name, back.name) == ("FRONT", "BACK")
    for piece, mm in ((front, front_mm), (back, back_mm)):
        assert_piece_shape(piece)
        ref = np.array(mm, float) * 1e-3
        assert piece.area == pytest.approx(abs(shoelace(ref)), rel=1e-12)
        assert piece.perimeter == pytest.approx(perimeter(ref), rel=1e-12)
        assert piece.outline.min(axis=0) == pytest.approx([0.0, 0.0], abs=1e-15)
        assert "$INSUNITS" in piece.notes[0] and "mm" in piece.notes[0]
        assert "B_" in piece.source and str(path) in piece.source
    np.testing.assert_allclose(front.grain, [math.cos(g), math.sin(g)], rtol=0, atol=1e-15)
    assert back.grain is None


def test_aama_boundary_of_lines_arc_and_spline_within_tolerance(tmp_path):
    """A layer-1 boundary drawn as LINEs, an ARC and a cubic SPLINE (entities in no particular
    order or direction) is joined into one loop; every outline vertex lies on the true boundary and
    every point of the true curves (sampled with ezdxf's own evaluators) lies within the tolerance
    of the outline."""
    ctrl = [(200, 0), (150, -60), (50, 60), (0, 0)]               # cubic bottom edge, right to left
    tol = 0.2e-3

    def draw(blk):
        blk.add_line((0, 0), (0, 250), dxfattribs={"layer": "1"})
        blk.add_line((200, 250), (200, 0), dxfattribs={"layer": "1"})
        # top edge: half circle of radius 100 bulging up, centre (100, 250), drawn CCW from 0 to 180 deg
        blk.add_arc((100, 250), 100, 0, 180, dxfattribs={"layer": "1"})
        blk.add_open_spline(ctrl, degree=3, dxfattribs={"layer": "1"})

    doc = aama_doc(units=4)
    add_piece(doc, "SHAPED", draw, grain=((100, 20), (100, 200)))
    doc.saveas(tmp_path / "shaped.dxf")
    (piece,) = read_pattern(tmp_path / "shaped.dxf", tolerance=tol)
    assert_piece_shape(piece)
    np.testing.assert_allclose(piece.grain, [0.0, 1.0], atol=1e-15)
    bs = BSpline([ezdxf.math.Vec3(x, y) for x, y in ctrl], order=4)
    curve = np.array([(p.x, p.y) for p in bs.points(np.linspace(0, bs.max_t, 4001))]) * 1e-3
    ang = np.linspace(0, math.pi, 4001)
    arc = np.column_stack([0.1 + 0.1 * np.cos(ang), 0.25 + 0.1 * np.sin(ang)])
    for q in np.vstack([curve, arc]):
        assert dist_to_outline(q, piece.outline) <= tol * (1 + 1e-9)
    # every vertex on the true boundary: arc vertices on the circle, spline vertices on the spline
    on_arc = piece.outline[piece.outline[:, 1] > 0.25 + 1e-12]
    np.testing.assert_allclose(np.hypot(on_arc[:, 0] - 0.1, on_arc[:, 1] - 0.25), 0.1, rtol=1e-12)
    on_spline = piece.outline[piece.outline[:, 1] < -1e-12]
    dense = np.array([(p.x, p.y) for p in bs.points(np.linspace(0, bs.max_t, 200001))]) * 1e-3
    for v in on_spline:
        assert np.min(np.hypot(*(dense - v).T)) < 1e-6     # sampling resolution of `dense`
    # fewer points with a coarser tolerance, still within it
    (coarse,) = read_pattern(tmp_path / "shaped.dxf", tolerance=2e-3)
    assert len(coarse.outline) < len(piece.outline)
    for q in np.vstack([curve, arc])[::10]:
        assert dist_to_outline(q, coarse.outline) <= 2e-3 * (1 + 1e-9)


def test_aama_rational_spline_quarter_circle(tmp_path):
    """A rational (NURBS) quarter circle on layer 1: flattened in homogeneous coordinates, every
    vertex on the circle (1e-12), every chord's sagitta within the tolerance."""
    r = 100.0
    w = math.sqrt(0.5)

    def draw(blk):
        blk.add_rational_spline([(r, 0), (r, r), (0, r)], [1.0, w, 1.0], degree=2, dxfattribs={"layer": "1"})
        blk.add_line((0, r), (0, 0), dxfattribs={"layer": "1"})
        blk.add_line((0, 0), (r, 0), dxfattribs={"layer": "1"})

    doc = aama_doc(units=4)
    add_piece(doc, "QUARTER", draw)
    doc.saveas(tmp_path / "q.dxf")
    (piece,) = read_pattern(tmp_path / "q.dxf")
    rad = np.hypot(*piece.outline.T)
    curved = rad > 1e-9
    np.testing.assert_allclose(rad[curved & (piece.outline.min(axis=1) > 1e-12)], 0.1, rtol=1e-12)
    ang = np.sort(np.arctan2(piece.outline[curved, 1], piece.outline[curved, 0]))
    sagitta = 0.1 * (1 - np.cos(np.diff(ang) / 2))
    assert sagitta.max() <= DEFAULT_TOLERANCE
    exact = math.pi * 0.1**2 / 4
    assert 0 < exact - piece.area <= 0.1 * math.pi / 2 * DEFAULT_TOLERANCE


def test_aama_bulge_polyline_and_mirrored_insert(tmp_path):
    """A closed LWPOLYLINE with a bulge (a semicircular end) inserted mirrored (xscale = -1): the
    mirror is kept, the outline comes back counter-clockwise with the arc's vertices on its circle,
    and the area is within the circle bound of rectangle + half disc."""
    doc = aama_doc(units=4)

    def draw(blk):
        # rectangle 0..100 x 0..60 with its right end a half circle bulging outwards (bulge 1 = 180 deg)
        blk.add_lwpolyline([(0, 0, 0, 0, 0), (100, 0, 0, 0, 1.0), (100, 60, 0, 0, 0), (0, 60, 0, 0, 0)],
                           format="xyseb", close=True, dxfattribs={"layer": "1"})

    add_piece(doc, "TAB", draw, grain=((10, 30), (80, 30)), xscale=-1.0)
    doc.saveas(tmp_path / "tab.dxf")
    (piece,) = read_pattern(tmp_path / "tab.dxf")
    assert_piece_shape(piece)
    assert piece.outline[:, 0].max() <= 1e-15
    assert -0.13 - 1e-15 <= piece.outline[:, 0].min() <= -0.13 + DEFAULT_TOLERANCE
    np.testing.assert_allclose(piece.grain, [-1.0, 0.0], atol=1e-15)
    arc = piece.outline[piece.outline[:, 0] < -0.1 - 1e-12]
    np.testing.assert_allclose(np.hypot(arc[:, 0] + 0.1, arc[:, 1] - 0.03), 0.03, rtol=1e-12)
    exact = 0.1 * 0.06 + math.pi * 0.03**2 / 2
    assert 0 < exact - piece.area <= math.pi * 0.03 * DEFAULT_TOLERANCE


def test_aama_notches_name_vertices(tmp_path):
    """Layer-4 notches become named vertices (``notch1``, ... in outline order): a notch on an edge
    inserts a vertex there, a notch at a corner names the corner; the area stays exact."""
    doc = aama_doc(units=4)

    def draw(blk):
        blk.add_lwpolyline([(0, 0), (100, 0), (100, 80), (0, 80)], close=True, dxfattribs={"layer": "1"})
        blk.add_line((100, 40), (95, 40), dxfattribs={"layer": "4"})     # mid right side
        blk.add_line((0, 80), (3, 77), dxfattribs={"layer": "4"})        # top-left corner
        blk.add_point((50, 0), dxfattribs={"layer": "4"})                # mid bottom

    add_piece(doc, "P", draw)
    doc.saveas(tmp_path / "n.dxf")
    (piece,) = read_pattern(tmp_path / "n.dxf")
    named = {k: tuple(np.round(piece.outline[i] * 1e3, 9)) for k, i in piece.vertex_names.items()}
    assert named == {"notch1": (50.0, 0.0), "notch2": (100.0, 40.0), "notch3": (0.0, 80.0)}
    assert piece.area == pytest.approx(0.1 * 0.08, rel=1e-12)


def test_bundled_sleeve_panels():
    """static/patterns/sleeve_panels.dxf: FRONT and BACK, each the 0.125 x 0.08 m half of
    sewn_sleeve.yaml's panel, grain along x, a notch at mid-length of both sewn sides."""
    pieces = read_pattern(PATTERNS / "sleeve_panels.dxf")
    assert [p.name for p in pieces] == ["FRONT", "BACK"]
    for p in pieces:
        assert_piece_shape(p)
        assert p.area == pytest.approx(0.125 * 0.08, rel=1e-12)
        assert p.perimeter == pytest.approx(2 * (0.125 + 0.08), rel=1e-12)
        np.testing.assert_allclose(p.grain, [1.0, 0.0])
        assert sorted(tuple(p.outline[i]) for i in p.vertex_names.values()) == [(0.0, 0.04), (0.125, 0.04)]


# ---------------------------------------------------------------------------------------------
# plain DXF and units
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("insunits,factor", [(4, 1e-3), (5, 1e-2), (1, 0.0254), (6, 1.0)])
def test_plain_dxf_units_from_header(tmp_path, insunits, factor):
    """Plain DXF: each closed polyline in modelspace is a piece named by its layer; $INSUNITS
    (mm, cm, inch, m) scales it exactly; a layer-7 LINE inside a piece is its grain."""
    doc = ezdxf.new("R2000", units=insunits)
    msp = doc.modelspace()
    quad = [(0, 0), (40, 0), (35, 30), (5, 28)]
    msp.add_lwpolyline(quad, close=True, dxfattribs={"layer": "FRONT"})
    msp.add_lwpolyline([(x + 50, y) for x, y in quad], close=True, dxfattribs={"layer": "BACK"})
    msp.add_line((20, 5), (20, 25), dxfattribs={"layer": "7"})
    msp.add_line((0, 50), (50, 50), dxfattribs={"layer": "0"})                 # stray line: ignored
    doc.saveas(tmp_path / "plain.dxf")
    front, back = read_pattern(tmp_path / "plain.dxf")
    assert (front.name, back.name) == ("FRONT", "BACK")
    ref = np.array(quad, float) * factor
    for p in (front, back):
        assert_piece_shape(p)
        assert p.area == pytest.approx(shoelace(ref), rel=1e-12)
        assert p.perimeter == pytest.approx(perimeter(ref), rel=1e-12)
        assert f"$INSUNITS = {insunits}" in p.notes[0]
    np.testing.assert_allclose(front.grain, [0.0, 1.0])
    assert back.grain is None


def test_plain_dxf_units_detected_declared_and_refused(tmp_path):
    """No $INSUNITS: a piece of 100-5000 units is read as mm and the note says so; declared units
    override; a size that could be cm or inches is refused with a request to declare units."""
    def write(name, size):
        doc = ezdxf.new("R2000")
        doc.header["$INSUNITS"] = 0
        doc.modelspace().add_lwpolyline([(0, 0), (size, 0), (size, size / 2)], close=True)
        doc.saveas(tmp_path / name)
        return tmp_path / name

    (p,) = read_pattern(write("mm.dxf", 400.0))
    assert p.area == pytest.approx(0.5 * 0.4 * 0.2, rel=1e-12)
    assert "detected from size" in p.notes[0] and "mm" in p.notes[0]
    (p,) = read_pattern(write("m.dxf", 0.4))
    assert p.area == pytest.approx(0.5 * 0.4 * 0.2, rel=1e-12)
    (p,) = read_pattern(write("cm.dxf", 40.0), units="cm")
    assert p.area == pytest.approx(0.5 * 0.4 * 0.2, rel=1e-12) and "declared" in p.notes[0]
    (p,) = read_pattern(write("in.dxf", 40.0), units="in")
    assert p.area == pytest.approx(0.5 * (40 * 0.0254) ** 2 / 2, rel=1e-12)
    with pytest.raises(PatternError, match=r"cm\.dxf: cannot tell the units: the largest piece spans 40 units"):
        read_pattern(tmp_path / "cm.dxf")


def test_plain_dxf_circle_flattening_within_tolerance(tmp_path):
    """A CIRCLE piece: vertices on the circle, each chord's sagitta <= tolerance, and the area error
    0 < pi r^2 - A <= P tol."""
    doc = ezdxf.new("R2000", units=4)
    doc.modelspace().add_circle((10, 20), 50.0, dxfattribs={"layer": "BLANK"})
    doc.saveas(tmp_path / "c.dxf")
    for tol in (0.5e-3, 0.05e-3, 1e-6):
        (p,) = read_pattern(tmp_path / "c.dxf", tolerance=tol)
        assert p.name == "BLANK"
        rad = np.hypot(p.outline[:, 0] - 0.01, p.outline[:, 1] - 0.02)
        np.testing.assert_allclose(rad, 0.05, rtol=1e-12)
        chord = np.hypot(*(np.roll(p.outline, -1, axis=0) - p.outline).T)
        sagitta = 0.05 - np.sqrt(0.05**2 - (chord / 2) ** 2)
        assert sagitta.max() <= tol * (1 + 1e-9)
        assert 0 < math.pi * 0.05**2 - p.area <= 2 * math.pi * 0.05 * tol


def test_plain_dxf_periodic_spline_and_ellipse_within_tolerance(tmp_path):
    """A closed (periodic, unclamped) cubic SPLINE and a rotated ELLIPSE as plain pieces: every point
    of the true curves (ezdxf's evaluator over the spline's valid domain; the ellipse's equation)
    within the tolerance of the outline, every outline vertex on the curve."""
    doc = ezdxf.new("R2000", units=4)
    msp = doc.modelspace()
    sp = msp.add_spline(dxfattribs={"layer": "SPL"})
    sp.set_closed([(0, 0, 0), (100, 0, 0), (120, 80, 0), (50, 120, 0), (-20, 80, 0)], degree=3)
    msp.add_ellipse((500, 0), major_axis=(100, 20), ratio=0.5, dxfattribs={"layer": "ELL"})
    doc.saveas(tmp_path / "curves.dxf")
    tol = 0.2e-3
    spl, ell = read_pattern(tmp_path / "curves.dxf", tolerance=tol)
    assert (spl.name, ell.name) == ("SPL", "ELL")
    bs = sp.construction_tool()
    kn = bs.knots()
    ts = np.linspace(kn[3], kn[len(kn) - 4], 3001)
    curve = np.array([(p.x, p.y) for p in bs.points(ts)]) * 1e-3
    a = np.array([100.0, 20.0]) * 1e-3
    b = np.array([-20.0, 100.0]) * 0.5e-3
    t = np.linspace(0, 2 * math.pi, 3001)[:, None]
    ellipse = np.array([0.5, 0.0]) + np.cos(t) * a + np.sin(t) * b
    for piece, pts in ((spl, curve), (ell, ellipse)):
        assert_piece_shape(piece)
        for q in pts:
            assert dist_to_outline(q, piece.outline) <= tol * (1 + 1e-9)
    dense = np.array([(p.x, p.y) for p in bs.points(np.linspace(ts[0], ts[-1], 100001))]) * 1e-3
    for v in spl.outline:
        assert np.min(np.hypot(*(dense - v).T)) < 3e-6                     # sampling resolution
    uv = np.linalg.solve(np.column_stack([a, b]), (ell.outline - [0.5, 0.0]).T)
    np.testing.assert_allclose(np.hypot(*uv), 1.0, rtol=1e-12)
    ab = math.hypot(*a) * math.hypot(*b)
    assert 0 < math.pi * ab - ell.area <= 2 * math.pi * math.hypot(*a) * tol


# ---------------------------------------------------------------------------------------------
# SVG
# ---------------------------------------------------------------------------------------------

def test_svg_polygon_rect_exact_with_units_names_and_grain(tmp_path):
    """SVG in mm (width 200mm over a 200-unit viewBox): polygon and rotated rect exact (1e-12),
    y flipped to point up (counter-clockwise kept), names from inkscape:label then id, grain from the
    line in the piece's group."""
    body = """
    <g id="g1"><polygon inkscape:label="Front panel" id="poly" points="10,10 90,10 80,60 20,70"/>
       <line class="grainline" x1="50" y1="60" x2="50" y2="20"/></g>
    <g><rect id="back" x="100" y="10" width="50" height="30" transform="rotate(30 125 25)"/>
       <path id="back-grain" d="M 110 25 L 140 25"/></g>
    """
    path = write_svg(tmp_path / "p.svg", body)
    front, back = read_pattern(path)
    assert (front.name, back.name) == ("Front panel", "back")
    ref = np.array([(10, -10), (90, -10), (80, -60), (20, -70)], float) * 1e-3
    assert front.area == pytest.approx(abs(shoelace(ref)), rel=1e-12)
    assert front.perimeter == pytest.approx(perimeter(ref), rel=1e-12)
    assert back.area == pytest.approx(0.05 * 0.03, rel=1e-12)
    assert back.perimeter == pytest.approx(0.16, rel=1e-12)
    for p in (front, back):
        assert_piece_shape(p)
        assert "1 mm" in p.notes[0]
    np.testing.assert_allclose(front.grain, [0.0, 1.0], atol=1e-15)          # up the screen = +y
    np.testing.assert_allclose(back.grain, [1.0, 0.0], atol=1e-15)           # id "back-grain", a path


def test_svg_grain_group_and_containment(tmp_path):
    """Grainlines in a group named *grain* inside a piece's group, and two pieces sharing one group
    with their grains told apart by containment."""
    body = """
    <g id="front"><path id="f" d="M 0 0 H 40 V 60 H 0 Z"/>
       <g id="grainlines"><line x1="20" y1="50" x2="20" y2="10"/></g></g>
    <polygon id="a" points="100,0 140,0 140,40 100,40"/>
    <polygon id="b" points="150,0 190,0 190,40 150,40"/>
    <line id="grain-b" x1="160" y1="20" x2="180" y2="20"/>
    <line id="grain-a" x1="110" y1="10" x2="130" y2="30"/>
    """
    f, a, b = read_pattern(write_svg(tmp_path / "g.svg", body))
    np.testing.assert_allclose(f.grain, [0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(a.grain, [math.sqrt(0.5), -math.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(b.grain, [1.0, 0.0], atol=1e-15)


def test_svg_px_default_and_declared_units(tmp_path):
    """No absolute width: user units are px (1/96 in); ``units=`` declares the user unit."""
    path = write_svg(tmp_path / "px.svg", '<polygon id="a" points="0,0 96,0 96,48"/>', head='viewBox="0 0 500 500"')
    (p,) = read_pattern(path)
    assert p.area == pytest.approx(0.5 * 0.0254 * 0.0127, rel=1e-12)
    assert "px" in p.notes[0]
    (p,) = read_pattern(path, units="cm")
    assert p.area == pytest.approx(0.5 * 0.96 * 0.48, rel=1e-12)
    path = write_svg(tmp_path / "in.svg", '<polygon id="a" points="0,0 4,0 4,2"/>',
                     head='width="8in" height="4in" viewBox="0 0 8 4"')
    (p,) = read_pattern(path)
    assert p.area == pytest.approx(0.5 * (4 * 0.0254) * (2 * 0.0254), rel=1e-12)


def test_svg_circle_and_arcs_within_tolerance(tmp_path):
    """A <circle> (arcs in svgelements), also under a mirroring transform, and a path of elliptical
    arcs: vertices on the curve, area error within its bound, correct orientation."""
    body = """<circle id="c" cx="60" cy="50" r="40"/>
              <circle id="m" cx="60" cy="50" r="40" transform="translate(200 0) scale(-1 1)"/>
              <path id="e" d="M 100 50 A 40 20 0 0 1 180 50 A 40 20 0 1 1 100 50 Z"/>"""
    path = write_svg(tmp_path / "c.svg", body, head='width="300mm" height="100mm" viewBox="0 0 300 100"')
    for tol in (0.5e-3, 1e-5):
        c, m, e = read_pattern(path, tolerance=tol)
        for p, cx in ((c, 0.06), (m, 0.14)):
            assert_piece_shape(p)
            np.testing.assert_allclose(np.hypot(p.outline[:, 0] - cx, p.outline[:, 1] + 0.05), 0.04, rtol=1e-12)
            assert 0 < math.pi * 0.04**2 - p.area <= 2 * math.pi * 0.04 * tol
        assert_piece_shape(e)
        u = (e.outline[:, 0] - 0.14) / 0.04
        v = (e.outline[:, 1] + 0.05) / 0.02
        np.testing.assert_allclose(u**2 + v**2, 1.0, rtol=1e-12)
        exact = math.pi * 0.04 * 0.02
        assert 0 < exact - e.area <= 2 * math.pi * 0.04 * tol


def test_svg_cubic_bezier_within_tolerance(tmp_path):
    """A closed path with cubic and quadratic Beziers: every point of the curves (evaluated from the
    Bernstein polynomials) within the tolerance of the outline; the straight part exact."""
    path = write_svg(tmp_path / "b.svg", '<path id="b" d="M 0 0 C 30 -40 70 40 100 0 Q 50 100 0 0 Z"/>',
                     head='width="100mm" height="100mm" viewBox="0 0 100 100"')
    tol = 0.1e-3
    (p,) = read_pattern(path, tolerance=tol)
    assert_piece_shape(p)
    t = np.linspace(0, 1, 5001)[:, None]
    P0, P1, P2, P3 = (np.array(v, float) for v in ((0, 0), (30, -40), (70, 40), (100, 0)))
    cubic = (1 - t) ** 3 * P0 + 3 * (1 - t) ** 2 * t * P1 + 3 * (1 - t) * t**2 * P2 + t**3 * P3
    Q1 = np.array((50, 100.0))
    quad = (1 - t) ** 2 * P3 + 2 * (1 - t) * t * Q1 + t**2 * P0
    for q in np.vstack([cubic, quad])[::5] * np.array([1e-3, -1e-3]):
        assert dist_to_outline(q, p.outline) <= tol * (1 + 1e-9)


def test_bundled_circle_blank():
    """static/patterns/circle_blank.svg: the 50 mm circle (area within its bound) and the trapezoid
    (exact), each with its grain."""
    circle, trap = read_pattern(PATTERNS / "circle_blank.svg")
    assert (circle.name, trap.name) == ("circle_blank", "trapezoid")
    assert 0 < math.pi * 0.05**2 - circle.area <= 2 * math.pi * 0.05 * DEFAULT_TOLERANCE
    assert trap.area == pytest.approx(0.5 * (0.08 + 0.04) * 0.1, rel=1e-12)
    np.testing.assert_allclose(circle.grain, [1.0, 0.0])
    np.testing.assert_allclose(trap.grain, [0.0, 1.0])


# ---------------------------------------------------------------------------------------------
# every error message
# ---------------------------------------------------------------------------------------------

def test_error_self_intersecting(tmp_path):
    doc = aama_doc(units=4)
    add_piece(doc, "FRONT", [(0, 0), (200, 300), (200, 0), (0, 200)])        # a bow tie
    path = tmp_path / "pattern.dxf"
    doc.saveas(path)
    with pytest.raises(PatternError) as err:
        read_pattern(path)
    assert str(err.value) == f"{path}: piece FRONT: outline crosses itself near (0.08, 0.12) m"
    svg = write_svg(tmp_path / "bow.svg", '<polygon id="bow" points="0,0 20,30 20,0 0,20"/>')
    with pytest.raises(PatternError, match=r"bow\.svg: piece bow: outline crosses itself near \(0\.008, -0\.012\) m"):
        read_pattern(svg)
    # a symmetric bow tie: its lobes cancel in the signed area, and it was called "zero area"
    svg = write_svg(tmp_path / "sym.svg", '<polygon id="sym" points="0,0 100,100 100,0 0,100"/>')
    with pytest.raises(PatternError, match=r"sym\.svg: piece sym: outline crosses itself near \(0\.05, -0\.05\) m"):
        read_pattern(svg)
    flat = write_svg(tmp_path / "flat.svg", '<polygon id="flat" points="0,0 50,0 100,0"/>')
    with pytest.raises(PatternError, match=r"flat\.svg: piece flat: outline has zero area"):
        read_pattern(flat)


def test_error_fewer_than_three_points(tmp_path):
    doc = ezdxf.new("R2000", units=4)
    doc.modelspace().add_lwpolyline([(0, 0), (100, 0)], close=True, dxfattribs={"layer": "SLIVER"})
    doc.saveas(tmp_path / "two.dxf")
    with pytest.raises(PatternError, match=r"two\.dxf: piece SLIVER: outline has 2 distinct points, fewer than 3"):
        read_pattern(tmp_path / "two.dxf")
    svg = write_svg(tmp_path / "two.svg", '<polygon id="p2" points="0,0 10,0 10,0"/>')
    with pytest.raises(PatternError, match=r"two\.svg: piece p2: outline has 2 distinct points, fewer than 3"):
        read_pattern(svg)


def test_error_zero_area(tmp_path):
    svg = write_svg(tmp_path / "flat.svg", '<polygon id="flat" points="0,0 10,0 20,0 5,0"/>')
    with pytest.raises(PatternError, match=r"flat\.svg: piece flat: outline has zero area"):
        read_pattern(svg)
    doc = aama_doc(units=4)
    add_piece(doc, "LINE", [(0, 0), (100, 100), (200, 200)])
    doc.saveas(tmp_path / "flat.dxf")
    with pytest.raises(PatternError, match=r"flat\.dxf: piece LINE: outline has zero area"):
        read_pattern(tmp_path / "flat.dxf")


def test_error_no_pieces(tmp_path):
    doc = ezdxf.new("R2000", units=4)
    doc.modelspace().add_line((0, 0), (100, 0))
    doc.modelspace().add_lwpolyline([(0, 0), (10, 0), (10, 10)])             # open
    doc.saveas(tmp_path / "none.dxf")
    with pytest.raises(PatternError, match=r"none\.dxf: no pattern pieces found \(no closed polyline"):
        read_pattern(tmp_path / "none.dxf")
    svg = write_svg(tmp_path / "none.svg", '<polyline points="0,0 10,0 10,10"/><line x1="0" y1="0" x2="5" y2="5"/>')
    with pytest.raises(PatternError, match=r"none\.svg: no pattern pieces found \(.*2 open shape"):
        read_pattern(svg)


def test_error_open_boundary(tmp_path):
    def draw(blk):
        blk.add_line((0, 0), (100, 0), dxfattribs={"layer": "1"})
        blk.add_line((100, 0), (100, 100), dxfattribs={"layer": "1"})
        blk.add_line((100, 100), (5, 100), dxfattribs={"layer": "1"})         # 18.7 mm short of closing
        blk.add_line((0, 82), (0, 0), dxfattribs={"layer": "1"})

    doc = aama_doc(units=4)
    add_piece(doc, "OPEN", draw)
    doc.saveas(tmp_path / "open.dxf")
    with pytest.raises(PatternError, match=r"open\.dxf: piece OPEN: no closed boundary on layer 1: the "
                                           r"boundary does not close, gap of 0\.01868 m near \(0\.005, 0\.1\) m"):
        read_pattern(tmp_path / "open.dxf")


def test_error_unreadable_files(tmp_path):
    bad = tmp_path / "bad.dxf"
    bad.write_bytes(b"\x00\x01 this is not a drawing \xff" * 10)
    with pytest.raises(PatternError, match=r"bad\.dxf: not a readable DXF file"):
        read_pattern(bad)
    bad = tmp_path / "bad.svg"
    bad.write_text("<svg this is not xml")
    with pytest.raises(PatternError, match=r"bad\.svg: not a readable SVG file"):
        read_pattern(bad)
    (tmp_path / "empty.svg").write_text("")
    with pytest.raises(PatternError, match=r"empty\.svg: empty file"):
        read_pattern(tmp_path / "empty.svg")
    with pytest.raises(PatternError, match=r"missing\.dxf: cannot open"):
        read_pattern(tmp_path / "missing.dxf")
    (tmp_path / "x.pdf").write_text("%PDF")
    with pytest.raises(PatternError, match=r"x\.pdf: unknown pattern format '\.pdf'"):
        read_pattern(tmp_path / "x.pdf")


def test_error_non_regular_files_refused_before_reading(tmp_path, monkeypatch):
    """/dev/zero (under its own name and through a .dxf link), a FIFO and a directory are refused
    without being opened (a FIFO would block, /dev/zero never ends); a file over the size cap too."""
    for p in ("/dev/zero",):
        with pytest.raises(PatternError, match=r"/dev/zero: not a regular file"):
            read_pattern(p)
    link = tmp_path / "zero.dxf"
    link.symlink_to("/dev/zero")
    with pytest.raises(PatternError, match=r"zero\.dxf: not a regular file"):
        read_pattern(link)
    fifo = tmp_path / "pipe.svg"
    os.mkfifo(fifo)
    with pytest.raises(PatternError, match=r"pipe\.svg: not a regular file"):
        read_pattern(fifo)
    (tmp_path / "dir.dxf").mkdir()
    with pytest.raises(PatternError, match=r"dir\.dxf: not a regular file"):
        read_pattern(tmp_path / "dir.dxf")
    monkeypatch.setattr(patterns, "MAX_PATTERN_BYTES", 100)
    with pytest.raises(PatternError, match=r"sleeve_panels\.dxf: too large \([0-9,]+ bytes; over the pattern file limit of 100 bytes\)"):
        read_pattern(PATTERNS / "sleeve_panels.dxf")


def test_error_arguments_and_header(tmp_path):
    with pytest.raises(PatternError, match=r"unknown units 'furlong'"):
        read_pattern(PATTERNS / "sleeve_panels.dxf", units="furlong")
    with pytest.raises(PatternError, match=r"tolerance must be a positive length"):
        read_pattern(PATTERNS / "sleeve_panels.dxf", tolerance=0.0)
    doc = ezdxf.new("R2000")
    doc.header["$INSUNITS"] = 3                                              # miles
    doc.modelspace().add_lwpolyline([(0, 0), (1, 0), (1, 1)], close=True)
    doc.saveas(tmp_path / "miles.dxf")
    with pytest.raises(PatternError, match=r"miles\.dxf: \$INSUNITS = 3 is not a garment unit"):
        read_pattern(tmp_path / "miles.dxf")
    svg = write_svg(tmp_path / "holes.svg", '<path id="ring" d="M 0 0 H 50 V 50 H 0 Z M 10 10 H 20 V 20 H 10 Z"/>')
    with pytest.raises(PatternError, match=r"holes\.svg: piece ring: <path> holds 2 closed subpaths"):
        read_pattern(svg)


def test_a_piece_in_the_wrong_units_warns(tmp_path):
    """A metre DXF read as millimetres (a 0.4 mm piece) or a millimetre one read as metres (400 m)
    warns (PatternWarning) naming the file and the span: a garment of specks otherwise
    "converged" to a class IV reading with no word (found by a garment engineer's pass). A
    piece of ordinary size does not warn."""
    import warnings

    from clothsim.patterns import PatternWarning

    doc = ezdxf.new("R2000")
    doc.header["$INSUNITS"] = 0
    doc.modelspace().add_lwpolyline([(0, 0), (0.4, 0), (0.4, 0.2)], close=True)
    doc.saveas(tmp_path / "m.dxf")
    with pytest.warns(PatternWarning, match=r"m\.dxf: largest piece spans 0\.0004 m \(under 5 mm\): check the units"):
        read_pattern(tmp_path / "m.dxf", units="mm")
    doc.modelspace().add_lwpolyline([(0, 0), (40, 0), (40, 20)], close=True)
    doc.saveas(tmp_path / "big.dxf")
    with pytest.warns(PatternWarning, match=r"largest piece spans 40 m \(over 5 m\)"):
        read_pattern(tmp_path / "big.dxf", units="m")
    with warnings.catch_warnings():
        warnings.simplefilter("error", PatternWarning)
        (p,) = read_pattern(tmp_path / "m.dxf")
    assert p.area == pytest.approx(0.5 * 0.4 * 0.2, rel=1e-12)
