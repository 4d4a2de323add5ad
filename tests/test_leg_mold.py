"""The limb from a size chart (mold kind leg, clothsim.mold.leg).

Known answers: the closest point is exact (the residual p - c is along the normal to 1e-12 m
and no point of a dense sampling of the surface is nearer); the girth of the built surface at
each level is the chart's (checked on a 20 000-gon, independently of the series' own
perimeter); levels that are circles on a straight line give a cone (the distance to the
generator line in the meridian plane) and equal circles a cylinder; a segment enters where the
analytic cone says; bad specs are refused naming the field.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clothsim.config import SceneError, load_scene
from clothsim.mold import load_mold, mold_query_many, mold_segment_hit
from clothsim.mold.leg import leg_girth, leg_points, leg_radius

from conftest import ROOT

CHART = {"B": {"girth_cm": 22, "height_cm": 12, "aspect": 1.25, "medial_flat": 0.1, "crest": 0.05},
         "B1": {"girth_cm": 27, "height_cm": 22, "aspect": 1.2, "medial_flat": 0.08, "crest": 0.05},
         "C": {"girth_cm": 36, "height_cm": 33, "aspect": 1.15, "medial_flat": 0.05, "crest": 0.04},
         "D": {"girth_cm": 34, "height_cm": 42, "aspect": 1.1}}
CENTER = (-0.1, 0.03)


def _leg(levels=CHART, **kw):
    return load_mold({"leg": {"levels": levels, "center": list(CENTER), **kw}})


def _query(mold, P):
    P = np.ascontiguousarray(P, float)
    m = len(P)
    sd, cp, nrm = np.empty(m), np.empty((m, 3)), np.empty((m, 3))
    mold_query_many(mold.kernel_args(), P, sd, cp, nrm, np.empty((m, 2), np.int64))
    return sd, cp, nrm


def _near_points(mold, n, rng, lo=-0.01, hi=0.02):
    prm = mold.params
    z = rng.uniform(0.08, 0.48, n)
    t = rng.uniform(0, 2 * np.pi, n)
    S = np.empty((n, 3))
    leg_points(prm, z, t, S)
    d = rng.uniform(lo, hi, n)
    radial = np.column_stack([np.cos(t), np.sin(t), np.zeros(n)])
    return S + d[:, None] * radial + np.column_stack([np.zeros((n, 2)), rng.uniform(-0.01, 0.01, n)])


@pytest.mark.slow
def test_closest_point_is_exact_against_dense_sampling():
    """Points from 1 cm inside to 2 cm outside a shaped leg (ellipses, a flat medial side, a
    tibial crest): p - c is along the unit normal to 1e-12 m, the normal is the surface's
    (orthogonal to finite-difference tangents), the sign is inside/outside, and a dense
    sampling of the surface round c (0.1 mm by 0.02 degrees) has no point nearer than |sd|
    and one within 1e-6 m of it."""
    mold = _leg()
    prm = mold.params
    rng = np.random.default_rng(7)
    P = _near_points(mold, 40, rng)
    sd, cp, nrm = _query(mold, P)
    w = P - cp
    along = (w * nrm).sum(1)
    assert np.abs(np.abs(along) - np.linalg.norm(w, axis=1)).max() < 1e-12
    assert np.abs(along - sd).max() < 1e-12
    assert np.linalg.norm(w - along[:, None] * nrm, axis=1).max() < 1e-12
    for p, c, s, n in zip(P, cp, sd, nrm):
        zc = c[2]
        tc = math.atan2(c[1] - CENTER[1], c[0] - CENTER[0])
        # the normal is orthogonal to the surface's tangents (finite differences, h = 1e-6)
        h = 1e-6
        Q = np.empty((4, 3))
        leg_points(prm, np.array([zc + h, zc - h, zc, zc]), np.array([tc, tc, tc + h, tc - h]), Q)
        assert abs((Q[0] - Q[1]) @ n) / np.linalg.norm(Q[0] - Q[1]) < 1e-8
        assert abs((Q[2] - Q[3]) @ n) / np.linalg.norm(Q[2] - Q[3]) < 1e-8
        # the sign: inside iff nearer the axis than the surface at p's own height and angle
        tp = math.atan2(p[1] - CENTER[1], p[0] - CENTER[0])
        rp = math.hypot(p[0] - CENTER[0], p[1] - CENTER[1])
        assert (s < 0) == (rp < leg_radius(prm, p[2], tp)[0])
        zz, tt = np.meshgrid(zc + np.linspace(-0.03, 0.03, 601), tc + np.radians(np.linspace(-12, 12, 1201)),
                             indexing="ij")
        S = np.empty((zz.size, 3))
        leg_points(prm, zz.ravel(), tt.ravel(), S)
        dmin = np.linalg.norm(S - p, axis=1).min()
        assert dmin >= abs(s) - 1e-12
        assert dmin - abs(s) < 1e-6


def test_girth_at_each_level_is_the_charts():
    """The girth of the built surface's section at each level's height, as a tape measures it
    (the convex hull's perimeter, measured here with shapely on a 20 000-gon of surface
    points), equals the chart's to 1e-6 (asked: 1e-3); on the convex sections that is the
    outline's own length, on a concave one (a medial side flattened by 0.45: the tape bridges
    the hollow) the outline is longer."""
    from shapely.geometry import MultiPoint

    chart = dict(CHART, D={"girth_cm": 34, "height_cm": 42, "medial_flat": 0.45})
    mold = _leg(chart)
    prm = mold.params
    for name, lv in chart.items():
        z = lv["height_cm"] / 100
        t = np.linspace(0, 2 * np.pi, 20001)
        S = np.empty((len(t), 3))
        leg_points(prm, np.full(len(t), z), t, S)
        poly = np.linalg.norm(np.diff(S, axis=0), axis=1).sum()
        hull = MultiPoint([tuple(p) for p in S[:, :2]]).convex_hull.length
        assert hull == pytest.approx(lv["girth_cm"] / 100, rel=1e-6), name
        assert leg_girth(prm, z) == pytest.approx(lv["girth_cm"] / 100, rel=1e-9), name
        if name == "D":
            assert poly > hull * (1 + 1e-4)
        else:
            assert poly == pytest.approx(hull, rel=1e-9), name


def test_circular_levels_give_a_cone_and_a_cylinder():
    """Circular levels on a straight line (three of them: the natural spline through collinear
    points is the line) give a cone: the signed distance of any point between the levels is
    its distance to the generator line in its meridian plane, to 1e-12 m; equal girths give a
    cylinder of radius girth / 2 pi. A segment enters the cone where the analytic answer says
    (within 1e-9 m)."""
    r0, r1, z0, z1 = 0.035, 0.055, 0.1, 0.4
    g = lambda r: 2 * math.pi * r * 100  # noqa: E731
    levels = {"B": {"girth_cm": g(r0), "height_cm": z0 * 100},
              "C": {"girth_cm": g(0.5 * (r0 + r1)), "height_cm": 50 * (z0 + z1)},
              "D": {"girth_cm": g(r1), "height_cm": z1 * 100}}
    mold = _leg(levels)
    rng = np.random.default_rng(3)
    n = 200
    z = rng.uniform(z0 + 0.03, z1 - 0.03, n)
    t = rng.uniform(0, 2 * np.pi, n)
    rho = r0 + (r1 - r0) * (z - z0) / (z1 - z0) + rng.uniform(-0.01, 0.02, n)
    P = np.column_stack([CENTER[0] + rho * np.cos(t), CENTER[1] + rho * np.sin(t), z])
    sd, cp, nrm = _query(mold, P)
    L = math.hypot(r1 - r0, z1 - z0)
    expect = ((rho - r0) * (z1 - z0) - (z - z0) * (r1 - r0)) / L
    assert np.abs(sd - expect).max() < 1e-12
    # the normal leans out by the cone's half-angle
    assert np.abs(nrm[:, 2] + (r1 - r0) / L).max() < 1e-12
    # a radial segment at height 0.25 m from 0.1 m out towards the axis enters at r(0.25)
    rz = r0 + (r1 - r0) * (0.25 - z0) / (z1 - z0)
    p0 = np.array([CENTER[0] + 0.1, CENTER[1], 0.25])
    p1 = np.array([CENTER[0], CENTER[1], 0.25])
    t_hit = mold_segment_hit(mold.kernel_args(), p0, p1)
    assert (0.1 - t_hit * 0.1) == pytest.approx(rz, abs=1e-9)
    # equal girths: a cylinder
    cyl = _leg({"B": {"girth_cm": g(0.04), "height_cm": 10}, "C": {"girth_cm": g(0.04), "height_cm": 40}})
    P2 = P.copy()
    sd2, _, _ = _query(cyl, P2)
    assert np.abs(sd2 - (np.hypot(P2[:, 0] - CENTER[0], P2[:, 1] - CENTER[1]) - 0.04)).max() < 1e-12


def test_leg_spec_errors_name_the_field():
    base = ROOT / "configs" / "tube_on_leg_cone.yaml"
    bad = {"mold={leg: {levels: {B: {girth_cm: 22, height_cm: 10}, C: {girth_cm: 27, height_cm: 5}}}}":
           "mold.leg.levels.C.height_cm",
           "mold={leg: {levels: {B: {girth_cm: -2, height_cm: 10}, C: {girth_cm: 27, height_cm: 15}}}}":
           "mold.leg.levels.B.girth_cm",
           "mold={leg: {levels: {B: {girth_cm: 22, height_cm: 10}}}}": "mold.leg.levels",
           "mold={leg: {levels: {B: {girth_cm: 22, height_cm: 10}, C: {girth_cm: 27, height_cm: 15}},"
           " medial: [1, 1]}}": "medial",
           "mold={leg: {levels: {B: {girth_cm: 22, height_cm: 10, aspect: 9}, C: {girth_cm: 27, height_cm: 15}}}}":
           "mold.leg.levels.B.aspect"}
    for over, field in bad.items():
        with pytest.raises(SceneError) as e:
            load_scene(base, [over])
        assert field in str(e.value), (over, str(e.value))
    sc = load_scene(base, ["mold={leg: {levels: {B: {girth_cm: 22, height_cm: 0}, C: {girth_cm: 27, height_cm: 16}}},"
                           " friction: 0.4}"])
    assert sc.mold.friction == 0.4 and sc.mold.kind == "leg"


def test_leg_draws_as_a_closed_mesh_whose_sections_have_the_girths():
    """The display mesh (also what a scan-style measurement would cut) is closed and its
    sections at the levels measure the chart's girths to 0.1 % (a 96-gon)."""
    import trimesh

    mold = _leg()
    V, F = mold.surface_mesh(resolution=96)
    m = trimesh.Trimesh(V, F, process=False)
    assert m.is_watertight and m.volume > 0
    for name, lv in CHART.items():
        sec = m.section(plane_origin=[0, 0, lv["height_cm"] / 100], plane_normal=[0, 0, 1])
        L = sum(np.linalg.norm(np.diff(np.vstack([e, e[:1]]), axis=0), axis=1).sum() for e in sec.discrete)
        assert L == pytest.approx(lv["girth_cm"] / 100, rel=1e-3), name
