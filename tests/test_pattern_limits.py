"""Hostile and extreme pattern files (issue 28, items 1, 2, 11, 12): every file here is built by the
test, small, and must be refused with a clear message naming the file (and the piece or entity)
before the work it describes is done -- or, for the outlines that are valid, read to their known
answer.

Refusals are checked through the reader (``read_pattern``) and through ``python app.py run``
(exit 2, one message line, no traceback). The subprocess has a generous time-out: on the code
before these bounds, the same files ran for minutes and grew to gigabytes, so they fail it."""

from __future__ import annotations

import math
import random
import subprocess
import sys
import warnings

import ezdxf
import numpy as np
import pytest
import yaml
from conftest import ROOT

from clothsim.patterns import PatternError, PatternWarning, read_pattern

BOMB_SVG = b'<svg xmlns="http://www.w3.org/2000/svg"><path d="M0 0 C1e20 0 1e20 1e20 0 1e20 Z"/></svg>'
RUN_TIMEOUT = 120  # [s] a liveness bound for the subprocess (start-up included), not a speed test


# ---------------------------------------------------------------------------------------------
# the hostile files
# ---------------------------------------------------------------------------------------------

def _save(doc, path):
    doc.saveas(path)
    return path


def nested_inserts(path, fan=10, levels=8):
    """Blocks that insert the level below `fan` times, `levels` deep: fan**levels squares (26 KB)."""
    doc = ezdxf.new("R2000", units=4)
    doc.layers.add("1")
    doc.blocks.new("L0").add_lwpolyline([(0, 0), (100, 0), (100, 100), (0, 100)], close=True,
                                        dxfattribs={"layer": "1"})
    for k in range(1, levels + 1):
        b = doc.blocks.new(f"L{k}")
        for i in range(fan):
            b.add_blockref(f"L{k - 1}", (i * 200.0, 0))
    doc.modelspace().add_blockref(f"L{levels}", (0, 0))
    return _save(doc, path)


def self_insert(path):
    doc = ezdxf.new("R2000", units=4)
    doc.layers.add("1")
    b = doc.blocks.new("LOOP")
    b.add_lwpolyline([(0, 0), (100, 0), (100, 100)], close=True, dxfattribs={"layer": "1"})
    b.add_blockref("LOOP", (10, 10))
    doc.modelspace().add_blockref("LOOP", (0, 0))
    return _save(doc, path)


def use_fanout(path, fan=10, levels=6):
    """``<use>`` of a group of `fan` uses of the level below, `levels` deep (2 KB; 10^6 copies)."""
    s = ['<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink"><defs>',
         '<path id="g0" d="M0 0 L10 0 L10 10 Z"/>']
    for k in range(1, levels + 1):
        s.append(f'<g id="g{k}">' + "".join(f'<use xlink:href="#g{k - 1}" x="{i}"/>' for i in range(fan)) + "</g>")
    s.append(f'</defs><use xlink:href="#g{levels}"/></svg>')
    path.write_text("".join(s))
    return path


def use_cycle(path):
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink">'
                    '<g id="a"><path d="M0 0 L10 0 L10 10 Z"/><use xlink:href="#a"/></g></svg>')
    return path


def many_circles(path, n=100_000):
    """A plain DXF of n small circles, written as text (ezdxf would take minutes to write it)."""
    head = "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n4\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n"
    body = "".join(f"0\nCIRCLE\n8\nC\n10\n{i * 10}.0\n20\n0.0\n30\n0.0\n40\n3.0\n" for i in range(n))
    path.write_text(head + body + "0\nENDSEC\n0\nEOF\n")
    return path


def long_path(path, n=150_000):
    """One SVG path of n segments (about 3 MB)."""
    d = " ".join(f"L{i % 977} {i % 991}" for i in range(n))
    path.write_text(f'<svg xmlns="http://www.w3.org/2000/svg"><path d="M0 0 {d} Z"/></svg>')
    return path


def plain(path, draw, units=6):
    doc = ezdxf.new("R2000", units=units)
    draw(doc.modelspace())
    return _save(doc, path)


def square(size):
    return lambda msp: msp.add_lwpolyline([(0, 0), (size, 0), (size, size), (0, size)], close=True)


def aama_lines(path, n, radius_mm, seed=0, units=4):
    """An AAMA block whose boundary is n LINEs of a regular n-gon, shuffled, every other one reversed."""
    doc = ezdxf.new("R2000", units=units)
    doc.layers.add("1")
    b = doc.blocks.new("P")
    pts = [(radius_mm * math.cos(2 * math.pi * i / n), radius_mm * math.sin(2 * math.pi * i / n)) for i in range(n)]
    segs = [(pts[i], pts[(i + 1) % n]) if i % 2 else (pts[(i + 1) % n], pts[i]) for i in range(n)]
    random.Random(seed).shuffle(segs)
    for a, c in segs:
        b.add_line(a, c, dxfattribs={"layer": "1"})
    b.add_text("Piece Name: RING", dxfattribs={"layer": "1", "insert": (0, 0), "height": 2})
    doc.modelspace().add_blockref("P", (0, 0))
    return _save(doc, path), pts


HOSTILE = {
    # item 1/2: the 89-byte cubic 10^20 px long
    "bomb.svg": (lambda p: (p.write_bytes(BOMB_SVG), p)[1], r"piece path1.*coordinate of 2\.65e\+16 m, beyond the bound of 1e\+06 m"),
    "nested.dxf": (nested_inserts, r"INSERTs expand to more than 50,000 entities .*block 'L8'"),
    "loop.dxf": (self_insert, r"block 'LOOP' inserts itself"),
    "fanout.svg": (use_fanout, r"<use> references expand to more than 1,000 copies"),
    "cycle.svg": (use_cycle, r"<use> of '#a' refers to itself"),
    "circles.dxf": (many_circles, r"DXF tags, more than 500,000"),
    "segments.svg": (long_path, r"more than 200,000 numbers of path data"),
    # a circle of radius 10^12 m used 5 GB; a 10^12 m square ran with a units warning
    "circle12.dxf": (lambda p: plain(p, lambda m: m.add_circle((0, 0), 1e12)),
                     r"piece 0, CIRCLE [0-9A-F]+: the curve has a coordinate of 1e\+12 m, beyond the bound"),
    "square12.dxf": (lambda p: plain(p, square(1e12)), r"piece 0, LWPOLYLINE [0-9A-F]+: a point has a coordinate of 1e\+12 m"),
    # item 11: ZeroDivisionError, LinAlgError, "zero area (... area inf m^2)"
    "circle16.dxf": (lambda p: plain(p, lambda m: m.add_circle((0, 0), 1e16)), r"CIRCLE [0-9A-F]+: the curve has a coordinate of 1e\+16 m"),
    "scale308.svg": (lambda p: (p.write_text('<svg xmlns="http://www.w3.org/2000/svg"><g transform="scale(1e308)">'
                                             '<circle id="c" cx="10" cy="10" r="5"/></g></svg>'), p)[1],
                     r"piece c, <circle>: an arc has non-finite coordinates"),
    "square300.dxf": (lambda p: plain(p, square(1e300)), r"a point has a coordinate of 1e\+300 m"),
}


@pytest.mark.parametrize("name", list(HOSTILE))
def test_hostile_file_refused_by_the_reader(tmp_path, name):
    build, message = HOSTILE[name]
    path = build(tmp_path / name)
    assert path.stat().st_size < 8 * 2**20
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # numpy's overflow warnings must not leak
        with pytest.raises(PatternError, match=message) as err:
            read_pattern(path)
    assert str(err.value).startswith(f"{path}: ")


def test_refusals_leave_the_budget_of_the_next_read_alone(tmp_path):
    """The work context is per read: a refused read does not poison the next one."""
    with pytest.raises(PatternError):
        read_pattern(HOSTILE["bomb.svg"][0](tmp_path / "bomb.svg"))
    path = plain(tmp_path / "ok.dxf", lambda m: m.add_circle((0, 0), 0.05))
    (p,) = read_pattern(path)
    assert 0 < math.pi * 0.05**2 - p.area <= p.perimeter * 0.5e-3
    from clothsim import patternlimits as limits

    assert limits._WORK.get() is None


def _scene(tmp_path, pattern: dict, **panel) -> str:
    d = {"name": "t", "fabric": {"warp": {"preset": "isotropic_paper"}, "weft": {"preset": "isotropic_paper"}},
         "panels": [{"name": "p", "pattern": pattern, "divisions": [4, 4], **panel}],
         "constraints": [{"nodes": "outline", "axes": "xyz"}]}
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return str(path)


def _run(scene: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "app.py"), "run", scene, "--out", scene + ".out"],
                          capture_output=True, text=True, timeout=RUN_TIMEOUT, cwd=ROOT)


@pytest.mark.parametrize("name", ["bomb.svg", "nested.dxf", "fanout.svg", "circles.dxf", "segments.svg",
                                  "circle12.dxf", "square300.dxf", "scale308.svg"])
@pytest.mark.slow
def test_hostile_pattern_refused_by_run_with_exit_2(tmp_path, name):
    build, message = HOSTILE[name]
    build(tmp_path / name)
    r = _run(_scene(tmp_path, {"file": name}))
    assert r.returncode == 2, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    assert f"panels.0.pattern: {tmp_path / name}: " in r.stderr
    assert __import__("re").search(message, r.stderr), r.stderr


def test_tiny_tolerance_refused_with_its_bound(tmp_path):
    """tolerance: 1e-300 gave ZeroDivisionError."""
    path = plain(tmp_path / "c.dxf", lambda m: m.add_circle((0, 0), 0.05))
    with pytest.raises(PatternError, match=r"tolerance must be between 1e-06 m and 1 m \(got 1e-300 m\)"):
        read_pattern(path, tolerance=1e-300)
    r = _run(_scene(tmp_path, {"file": "c.dxf", "tolerance": 1e-300}))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "panels.0.pattern: " in r.stderr and "tolerance must be between 1e-06 m and 1 m" in r.stderr
    (p,) = read_pattern(path, tolerance=1e-6)      # the bound itself is fine: about 1,000 points
    assert 0 < math.pi * 0.05**2 - p.area <= p.perimeter * 1e-6


def test_flattening_budget_refuses_before_allocating(tmp_path, monkeypatch):
    """A circle within the coordinate bound but needing more points than the budget is refused
    (it used to allocate them: 5 GB for radius 1e12 m before 'use fewer divisions')."""
    from clothsim import patternlimits as limits

    monkeypatch.setattr(limits, "MAX_POINTS", 10_000)
    path = plain(tmp_path / "c.dxf", lambda m: m.add_circle((0, 0), 1e5))   # ~ 2.5e5 points at 0.5 mm
    with pytest.raises(limits.PatternLimitError, match=r"piece 0, CIRCLE [0-9A-F]+: flattening the curves at a "
                                                       r"tolerance of 0.0005 m would make more than 10,000 points"):
        read_pattern(path)
    svg = tmp_path / "cubic.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg"><path id="c" d="M0 0 C9e5 0 9e5 9e5 0 9e5 Z"/></svg>')
    with pytest.raises(limits.PatternLimitError, match=r"piece c, <path>: flattening"):
        read_pattern(svg, units="m")


def test_boundary_of_segments_shorter_than_the_tolerance(tmp_path):
    """It said 'does not close, gap of 1.6e-05 m', a gap under the tolerance."""
    path, _ = aama_lines(tmp_path / "tiny.dxf", 200, 1.6, units=4)   # 0.05 mm segments
    with pytest.raises(PatternError, match=r"piece RING: no closed boundary on layer 1: its 200 segment\(s\) are at "
                                           r"most 5.03e-05 m long, not longer than the join tolerance of 0.0005 m"):
        read_pattern(path)
    (p,) = read_pattern(path, tolerance=1e-5)      # the advice works
    assert p.area == pytest.approx(0.5 * 200 * (1.6e-3) ** 2 * math.sin(2 * math.pi / 200), rel=1e-9)


def test_indexed_join_gives_the_exact_polygon_and_compares_neighbours_only(tmp_path, monkeypatch):
    """4,000 shuffled LINEs (half reversed) join into the n-gon, exactly; the join compares each
    chain end with the endpoints in its grid cells only (it compared with every piece: 55 s)."""
    from clothsim import patternlimits as limits

    path, pts = aama_lines(tmp_path / "ring.dxf", 4000, 500.0)
    calls = [0]
    dist = math.dist

    def counting(a, b):
        calls[0] += 1
        return dist(a, b)

    monkeypatch.setattr(limits.math, "dist", counting)
    (p,) = read_pattern(path)
    monkeypatch.undo()
    exact = 0.5 * 4000 * 0.5**2 * math.sin(2 * math.pi / 4000)
    assert p.area == pytest.approx(exact, rel=1e-12)
    assert len(p.outline) == 4000
    assert calls[0] < 40 * 4000, calls[0]


# ---------------------------------------------------------------------------------------------
# item 12: a clockwise arc first; one broken piece
# ---------------------------------------------------------------------------------------------

BULGE = -0.3   # a clockwise arc over the bottom edge of a 0.3 m square, into the square


def _bulge_square(path, first: bool, aama: bool):
    doc = ezdxf.new("R2000", units=6)
    verts = [(0, 0, BULGE), (0.3, 0, 0), (0.3, 0.3, 0), (0, 0.3, 0)]
    if not first:
        verts = verts[1:] + verts[:1]
    if aama:
        doc.layers.add("1")
        b = doc.blocks.new("P")
        b.add_lwpolyline(verts, format="xyb", close=True, dxfattribs={"layer": "1"})
        doc.modelspace().add_blockref("P", (0, 0))
    else:
        doc.modelspace().add_lwpolyline(verts, format="xyb", close=True, dxfattribs={"layer": "P"})
    return _save(doc, path)


@pytest.mark.parametrize("aama", [True, False])
def test_closed_polyline_starting_with_a_clockwise_arc(tmp_path, aama):
    """Refused before ('does not close, gap of 0.3 m' in a block; 'crosses itself' in modelspace);
    now its area is the other-vertex outline's, and within the flattening bound of the exact one."""
    (a,) = read_pattern(_bulge_square(tmp_path / "first.dxf", True, aama))
    (b,) = read_pattern(_bulge_square(tmp_path / "other.dxf", False, aama))
    assert a.area == pytest.approx(b.area, rel=1e-13)
    theta = 4 * math.atan(abs(BULGE))                 # the arc's angle
    r = 0.3 / (2 * math.sin(theta / 2))
    exact = 0.09 - 0.5 * r * r * (theta - math.sin(theta))   # the square less the circular segment
    assert 0 < a.area - exact <= r * theta * 0.5e-3   # vertices on the arc: the polygon cuts less
    assert a.perimeter == pytest.approx(b.perimeter, rel=1e-13)


def _two_pieces(path):
    """GOOD, a square, and BAD, a bow tie (crosses itself)."""
    doc = ezdxf.new("R2000", units=4)
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (100, 0), (100, 100), (0, 100)], close=True, dxfattribs={"layer": "GOOD"})
    msp.add_lwpolyline([(200, 0), (300, 100), (300, 0), (200, 100)], close=True, dxfattribs={"layer": "BAD"})
    return _save(doc, path)


def test_only_the_piece_used_must_be_valid(tmp_path):
    path = _two_pieces(tmp_path / "two.dxf")
    with pytest.raises(PatternError, match="piece BAD: outline crosses itself"):
        read_pattern(path)                                     # every piece wanted: refused
    with pytest.raises(PatternError, match="piece BAD: outline crosses itself"):
        read_pattern(path, piece="BAD")
    with pytest.warns(PatternWarning, match=r"piece BAD: outline crosses itself.*left out: the piece used is 'GOOD'"):
        pieces = read_pattern(path, piece="GOOD")
    assert [p.name for p in pieces] == ["GOOD"] and pieces[0].area == pytest.approx(0.01, rel=1e-12)


def test_scene_using_the_good_piece_builds(tmp_path):
    from clothsim.compile import _pattern_piece
    from clothsim.config import SceneError, load_scene

    _two_pieces(tmp_path / "two.dxf")
    scene = load_scene(_scene(tmp_path, {"file": "two.dxf", "piece": "GOOD"}))
    with pytest.warns(PatternWarning, match="piece BAD"):
        p = _pattern_piece(scene, 0)
    assert p.name == "GOOD"
    scene = load_scene(_scene(tmp_path, {"file": "two.dxf", "piece": "BAD"}))
    with pytest.raises(SceneError, match=r"panels\.0\.pattern: .*piece BAD: outline crosses itself"):
        _pattern_piece(scene, 0)
    # a piece beyond the coordinate bound is one bad piece: the other one is read
    path = tmp_path / "three.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg"><rect id="ok" width="100" height="50"/>'
                    '<path id="far" d="M0 0 C1e20 0 1e20 1e20 0 1e20 Z"/></svg>')
    with pytest.warns(PatternWarning, match=r"piece far, <path>: a curve's control point has a coordinate"):
        (p,) = read_pattern(path, piece="ok")
    assert p.area == pytest.approx(5000 * (0.0254 / 96) ** 2, rel=1e-12)
