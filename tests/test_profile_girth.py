"""A profile's girth mean (clothsim/compression/probes.py, read_profile): the integral of the
contact pressure round a slice over the fabric's length on the body (nodes in contact or within
ON_BODY_GAP_M of the mold), what a tape-and-sensor engineer averages round a limb.

Known answers, each a knit tube sewn to itself (160 x 32), its cuffs held along the axis,
frictionless, on an extruded section: round a closed convex course of uniform hoop tension T the
integral of the pressure is the integral of T kappa, T 2 pi, so the girth mean is T 2 pi / girth.
On a circle every node presses and it equals the contact mean, T / r. On a stadium (two
half-circles joined by flats) the flats carry no pressure (kappa = 0): the girth mean is
T 2 pi / (2 pi r + 4 l), while the contact mean, whose contact length leaves out the flat stretch
the solver finds without reaction, reads up to T / r."""

from __future__ import annotations

import csv
import io
import math

import numpy as np
import pytest
import trimesh

import clothsim
from clothsim.compression.levels import read_level
from clothsim.compression.probes import ON_BODY_GAP_M, on_body, profiles_csv
from clothsim.config import scene_from_dict
from conftest import ROOT

MATERIALS = ROOT / "static" / "materials"
WIDTH, NX = 0.25, 160


def _tube_on(stl, x_half: float) -> clothsim.Result:
    """The knit tube on the extruded section ``stl``, rolled on a cylinder 5 mm clear of the
    section's half-width ``x_half`` [m], with 1 cm slices from z = -0.06 to -0.02 m (the tube spans -0.08 to 0.004)."""
    R0 = x_half + 0.005
    return clothsim.solve(scene_from_dict({
        "name": "girth-tube",
        "fabric": {"size": [WIDTH, 0.08], "divisions": [NX, 32],
                   "warp": {"csv": str(MATERIALS / "compression_knit_course.csv")},
                   "weft": {"csv": str(MATERIALS / "compression_knit_wale.csv")}},
        "seams": [{"a": "left", "b": "right"}],
        "constraints": [{"nodes": "bottom", "axes": "z"},
                        {"nodes": "top", "axes": "z", "displacement": [0.0, 0.0, 0.004]},
                        {"nodes": {"i": NX // 2}, "axes": "x"}],
        "initial": {"wrap": {"center": [0.0, 0.0, -0.04], "axis": [0, 0, 1], "radius": R0,
                             "start_angle": 90.0 - math.degrees(WIDTH / 2 / R0)}},
        "mold": {"path": str(stl), "surface": "faceted"},
        # 1e-6 N: 1e-4 of a node's contact force here (about 8e-3 N)
        "solver": {"method": "newton", "e": 1e-6, "time_limit_s": 300},
        "profiles": [{"name": "tube", "axis": "z", "from": -0.06, "to": -0.02, "step": 0.01}],
    }))


def _hoop_tension(res) -> float:
    """The hoop (course) tension per current width [N/m] off the cuffs (median over the springs)."""
    eps_weft = float(np.median(res.strain_weft[:, 4:-4]))
    return float(np.median(res.tension_warp[:, 4:-4])) / (0.08 / 32 * (1 + eps_weft))


def _section(tmp_path, name: str, xy: np.ndarray):
    """The prism of the closed convex polygon xy (K, 2), counter-clockwise, z from -0.15 to 0.15 m,
    its caps fans from the centre (trimesh writes the STL)."""
    k = len(xy)
    V = [[x, y, z] for z in (-0.15, 0.15) for x, y in xy] + [[0, 0, -0.15], [0, 0, 0.15]]
    F = []
    for i in range(k):
        a, b = i, (i + 1) % k
        F += [[a, b, k + b], [a, k + b, k + a], [2 * k, b, a], [2 * k + 1, k + a, k + b]]
    trimesh.Trimesh(np.array(V), np.array(F), process=False).export(tmp_path / name)
    return tmp_path / name


@pytest.mark.slow
def test_girth_mean_on_an_ellipse_and_a_stadium_integrates_laplace(tmp_path):
    """Ellipse (semi-axes 6 and 4 cm): the local pressure T kappa varies by (a / b)^3 = 3.4 round
    the section, every node presses, and each slice's girth mean is T 2 pi / girth (1 %; measured 4e-4),
    the girth the ellipse's perimeter (1 %; measured 1e-4). Stadium (half-circles of 3 cm joined by 2 x 3 cm flats):
    the girth mean is T 2 pi / girth (1 %; measured 1e-4), the girth the stadium's perimeter (1 %);
    on the flats the fabric lies on the body without reaction, out of the contact set."""
    a, b = 0.06, 0.04
    cyl = trimesh.creation.cylinder(radius=1.0, height=0.3, sections=256)
    trimesh.Trimesh(cyl.vertices * [a, b, 1.0], cyl.faces).export(tmp_path / "ellipse.stl")
    ell = _tube_on(tmp_path / "ellipse.stl", a)
    assert ell.solve.converged, ell.solve.message
    T = _hoop_tension(ell)
    h = (a - b) ** 2 / (a + b) ** 2
    perimeter = np.pi * (a + b) * (1 + 3 * h / (10 + math.sqrt(4 - 3 * h)))   # Ramanujan
    for sl in ell.compression()["profiles"][0]["slices"]:
        assert sl["girth_m"] == pytest.approx(perimeter, rel=0.01)
        assert sl["girth_mean_pa"] == pytest.approx(T * 2 * np.pi / sl["girth_m"], rel=0.01)
        assert sl["max_mmhg"] > 2.5 * sl["min_mmhg"]           # kappa's (a / b)^3 round the section

    r, l = 0.03, 0.03                                           # half-circles, half the flat's length
    arc = np.linspace(-np.pi / 2, np.pi / 2, 129)
    xy = np.vstack([np.column_stack([l + r * np.cos(arc), r * np.sin(arc)]),
                    np.column_stack([-l - r * np.cos(arc), -r * np.sin(arc)])])
    st = _tube_on(_section(tmp_path, "stadium.stl", xy), l + r)
    assert st.solve.converged, st.solve.message
    T = _hoop_tension(st)
    X = st.state.positions
    body = on_body(st.model, X, st.state.in_contact)
    flat = (np.abs(X[:, 0]) < l - 0.005) & (np.abs(X[:, 2] + 0.04) < 0.025)
    assert body[flat].all()                                    # the flats' fabric lies on the body
    for sl in st.compression()["profiles"][0]["slices"]:
        assert sl["girth_m"] == pytest.approx(2 * np.pi * r + 4 * l, rel=0.01)
        assert sl["girth_mean_pa"] == pytest.approx(T * 2 * np.pi / sl["girth_m"], rel=0.01)
        # the flats' fabric (5.6 of 30.8 cm) is out of the contact set: the contact mean reads 22 % higher
        assert sl["mean_pa"] > 1.1 * sl["girth_mean_pa"]
        # a measuring level there reads the girth mean too (it read the contact mean, 22 % high)
        lv = read_level(st.model, X, st.state.in_contact, st._f()[3],  # pressure per node [Pa]
                        {"name": "L", "z_m": sl["height_m"], "height_m": sl["height_m"], "girth_m": sl["girth_m"],
                         "loop_m": sl["girth_m"], "how": "given", "sides": {}}, 0.01, sides=False)
        assert lv["mean_mmhg"] == pytest.approx(sl["girth_mean_mmhg"], rel=1e-12)
    rows = list(csv.DictReader(io.StringIO(profiles_csv(st.compression()["profiles"]))))
    assert float(rows[2]["girth_mean_Pa"]) == pytest.approx(st.compression()["profiles"][0]["slices"][2]["girth_mean_pa"],
                                                             rel=1e-5)
    assert ON_BODY_GAP_M == 0.5e-3
