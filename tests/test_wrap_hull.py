"""The start round a body slab (clothsim.hullwrap; issue 12 item 4, issue 11 item 1).

Known answers: round an axis-aligned box the grown hull is the box's rectangle offset by the
clearance c (perimeter 2 (a + b) + 2 pi c, every point at distance c from the rectangle; shapely's
16-segment quarter circles put points between their vertices down to c cos(pi / 64)); the
sheet's rows then lie on it at equal arc-length steps. On the scanned body no start node is inside
the mold, at the waist and at the calf (where a cylinder would touch the other leg or miss the
ankle by centimetres).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from conftest import ROOT

from clothsim.compile import compile_model, compile_scene
from clothsim.config import SceneError, scene_from_dict
from clothsim.hullwrap import row_extent, slab_points
from clothsim.mold import mold_from_arrays, mold_query_many

MAN = str(ROOT / "static" / "bodies" / "smpl_man.stl")
TABLE = {"strain": [0, 1], "tension": [0, 250]}


def _sheet(wrap_hull, size=(0.5, 0.1), div=(40, 10), mold=None, **extra):
    d = {"name": "hull", "fabric": {"size": list(size), "divisions": list(div), "warp": TABLE, "weft": TABLE},
         "initial": {"wrap_hull": wrap_hull}, "solver": {"method": "newton"}}
    if mold is not None:
        d["mold"] = mold
    d.update(extra)
    return scene_from_dict(d, ROOT / "configs" / "x.yaml")


def _signed(mold, P):
    n = len(P)
    sd = np.empty(n)
    mold_query_many(mold.kernel_args(), np.ascontiguousarray(P), sd, np.empty((n, 3)), np.empty((n, 3)),
                    np.empty((n, 2), np.int64))
    return sd


def _rect_distance(xy, a, b):
    dx = np.maximum(np.abs(xy[:, 0]) - a / 2, 0.0)
    dy = np.maximum(np.abs(xy[:, 1]) - b / 2, 0.0)
    return np.hypot(dx, dy)


def test_round_a_box_every_node_is_clearance_away_at_equal_arc_steps():
    a, b, c = 0.12, 0.08, 0.01
    box = trimesh.creation.box(extents=[a, b, 0.4])
    mold = mold_from_arrays(box.vertices, box.faces)
    scene = _sheet({"center": [0, 0, 0], "clearance": c, "start_angle": 30.0})
    model, state = compile_scene(scene, mold=mold)
    P = state.positions
    d = _rect_distance(P[:, :2], a, b)
    assert d.min() >= c * math.cos(math.pi / 64) - 1e-12 and d.max() <= c + 1e-12
    # heights: the sheet's middle row at the centre, rows 1 cm apart
    np.testing.assert_allclose(np.unique(np.round(P[:, 2], 12)), np.linspace(-0.05, 0.05, 11), atol=1e-12)
    # one row: 41 nodes once round, first and last at the same point, equal arc steps
    ij = model.topology.node_ij
    row = P[ij[:, 1] == 3][np.argsort(ij[ij[:, 1] == 3, 0])]
    np.testing.assert_allclose(row[0], row[-1], atol=1e-12)
    steps = np.linalg.norm(np.diff(row, axis=0), axis=1)
    # the grown hull: the rectangle's sides and four quarter circles of 16 chords each
    perimeter = 2 * (a + b) + 64 * 2 * c * math.sin(math.pi / 64)
    straight = ((np.abs(row[:-1, 0]) <= a / 2) & (np.abs(row[1:, 0]) <= a / 2)
                & (np.sign(row[:-1, 1]) == np.sign(row[1:, 1])))
    straight |= ((np.abs(row[:-1, 1]) <= b / 2) & (np.abs(row[1:, 1]) <= b / 2)
                 & (np.sign(row[:-1, 0]) == np.sign(row[1:, 0])))
    assert straight.sum() > 20
    np.testing.assert_allclose(steps[straight], perimeter / 40, rtol=1e-9)
    assert (steps <= perimeter / 40 * (1 + 1e-9)).all()     # chords round a corner are shorter
    # counter-clockwise about +z (the warp goes round the axis as with initial.wrap)
    ang = np.unwrap(np.arctan2(row[:, 1], row[:, 0]))
    assert (np.diff(ang) > 0).all()
    # the left edge starts on the ray at start_angle (30 degrees) from the axis
    assert math.degrees(math.atan2(row[0, 1], row[0, 0])) == pytest.approx(30.0, abs=1e-6)


def test_round_a_mesh_cylinder_the_radius_is_r_plus_clearance():
    cyl = trimesh.creation.cylinder(radius=0.05, height=0.3, sections=256)
    mold = mold_from_arrays(cyl.vertices, cyl.faces)
    scene = _sheet({"center": [0, 0, 0], "clearance": 0.005, "fraction": 0.5, "offset": 0.25})
    _, state = compile_scene(scene, mold=mold)
    r = np.hypot(state.positions[:, 0], state.positions[:, 1])
    assert r.min() >= 0.055 * math.cos(math.pi / 64) - 1e-9 and r.max() <= 0.055 + 1e-9
    # fraction 0.5 from a quarter round: the sheet covers the left half (90 to 270 degrees)
    ang = np.degrees(np.arctan2(state.positions[:, 1], state.positions[:, 0])) % 360
    assert ang.min() >= 90 - 0.5 and ang.max() <= 270 + 0.5


@pytest.mark.parametrize("where", ["waist", "calf"])
def test_on_the_scanned_body_no_start_node_is_inside(where):
    if where == "waist":
        hull = {"center": [0.0, 0.0, 1.07], "clearance": 0.01}
        size = (0.9, 0.10)
    else:  # one leg: the region keeps the other leg out of the hull
        hull = {"center": [-0.104, 0.034, 0.0], "heights": [0.12, 0.42], "clearance": 0.01,
                "region": {"min": [-0.3, -0.3, 0.0], "max": [0.0, 0.3, 0.6]}}
        size = (0.3, 0.3)
    scene = _sheet(hull, size=size, div=(40, 30), mold={"path": MAN, "up": "y", "surface": "faceted"})
    model, state = compile_scene(scene)    # refuses a start that touches the mold
    sd = _signed(model.mold, state.positions)
    # clearance 1 cm across the axis; where the body's side slants the distance in 3D is less
    assert sd.min() > 0.005
    assert sd.max() < 0.03                  # close round the body, not a loose cylinder
    if where == "calf":
        z = state.positions[:, 2]
        assert z.min() == pytest.approx(0.12) and z.max() == pytest.approx(0.42)


def test_a_cylinder_round_the_calf_is_no_substitute():
    """The cylinder that clears the calf's hull everywhere is far off the ankle: the hull start
    follows the leg (the reason for the hull)."""
    scene = _sheet({"center": [-0.104, 0.034, 0.0], "heights": [0.12, 0.42], "clearance": 0.01,
                    "region": {"min": [-0.3, -0.3, 0.0], "max": [0.0, 0.3, 0.6]}},
                   size=(0.3, 0.3), div=(40, 30), mold={"path": MAN, "up": "y", "surface": "faceted"})
    model, state = compile_scene(scene)
    P = state.positions
    ankle = np.abs(P[:, 2] - 0.15) < 0.006
    sd = _signed(model.mold, P[ankle])
    assert sd.max() < 0.02
    c = np.array([-0.104, 0.034])
    r_cyl = np.hypot(*(P[:, :2] - c).T).max()     # a cylinder round the widest row
    assert r_cyl - np.hypot(*(P[ankle, :2] - c).T).min() > 0.03


def test_panels_round_a_body_meet_at_their_seams():
    """The stocking's two panels start as halves of each row's grown hull: the front's right
    edge meets the back's left edge (and the back's right the front's left) to within the lattice
    staircase of the cut sides; no node is inside the leg."""
    from clothsim.config import load_scene

    scene = load_scene(ROOT / "configs" / "garments" / "stocking.yaml")
    model, state = compile_scene(scene)
    seam = model.spring_family == 5
    ab = model.spring_nodes[seam]
    gap = np.linalg.norm(state.positions[ab[:, 0]] - state.positions[ab[:, 1]], axis=1)
    # a staircase node of a cut side lies up to half a cell beyond the outline, and a row's width
    # is stretched about 1.6 times round the half perimeter: a pair starts at most about two
    # spacings apart
    assert gap.max() < 2.5 * max(model.spacing)
    assert np.median(gap) < max(model.spacing)
    assert _signed(model.mold, state.positions).min() > 0.009


def test_slab_points_and_row_extent_known_answers():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1.0]])
    E = np.array([[0, 1], [1, 2], [0, 2]])
    P = slab_points(V, E, V[:, 2], 0.25, 0.5)
    # edges 1-2 and 0-2 cross z = 0.25 and z = 0.5; no vertex between
    want = np.array([[0.75, 0.25, 0.25], [0, 0.25, 0.25], [0.5, 0.5, 0.5], [0, 0.5, 0.5]])
    assert sorted(map(tuple, np.round(P, 12))) == sorted(map(tuple, want))
    lo, hi = row_extent(np.array([[0, 0], [4, 0], [3, 2], [1, 2]]), np.array([0.0, 1.0, 2.0, 5.0]))
    np.testing.assert_allclose(lo, [0, 0.5, 1, 1])
    np.testing.assert_allclose(hi, [4, 3.5, 3, 3])


def test_wrap_hull_errors_name_their_field():
    with pytest.raises(SceneError, match="initial.wrap_hull: needs a mold"):
        compile_model(_sheet({"center": [0, 0, 0]}))
    with pytest.raises(SceneError, match="initial.wrap_hull: needs a mesh mold"):
        compile_model(_sheet({"center": [0, 0, 0]}, mold={"sphere": {"center": [0, 0, 0], "radius": 0.05}}))
    with pytest.raises(SceneError, match="initial.wrap_hull: the mold has no part at height"):
        compile_model(_sheet({"center": [0, 0, 3.0]}, mold={"path": MAN, "up": "y", "surface": "faceted"}))
    with pytest.raises(SceneError, match="initial: give wrap or wrap_hull"):
        _sheet({"center": [0, 0, 0]}, initial={"wrap_hull": {"center": [0, 0, 0]},
                                               "wrap": {"radius": 0.1}})
    with pytest.raises(SceneError, match="heights"):
        _sheet({"center": [0, 0, 0], "heights": [0.4, 0.1]})
    with pytest.raises(SceneError, match="region"):
        _sheet({"center": [0, 0, 0], "region": {"min": [0, 0, 0], "max": [1, -1, 1]}})
    with pytest.raises(SceneError, match="clearance"):
        _sheet({"center": [0, 0, 0], "clearance": -0.01})


def test_wrap_hull_survives_the_resolved_yaml_round_trip():
    from clothsim.config import load_scene

    scene = load_scene(ROOT / "configs" / "garments" / "stocking.yaml")
    text = scene.resolved().to_yaml()
    import yaml

    again = scene_from_dict(yaml.safe_load(text))
    assert again.panels[1].placement.wrap_hull == scene.panels[1].placement.wrap_hull
    assert again.panels[1].placement.wrap_hull.offset == 0.25
    assert again.mold.up == "y"
