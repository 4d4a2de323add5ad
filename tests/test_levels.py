"""Measuring levels and girths on a body, and the pressure read there as the standards read it
(clothsim.compression.levels).

Known answers: a compression tube on a leg built from a chart whose levels are circles reads,
at each level, Laplace's T cos(alpha) / r with T the course tension from that level's course
strain (the material table over the current wale width) and r the level's radius (girth / 2
pi), within 2 %; on circles the four sides read the girth mean; the gradient is each level's
mean over B's; a probe named by level and side reads what the level's side reads; the levels
found on the bundled scans are the ones the docs give (docs/guide/levels.md).
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

import clothsim
from clothsim.compression.levels import LEVELS_COLUMNS, find_levels, scan_girths
from clothsim.config import SceneError, load_scene

from conftest import ROOT
from levels_util import assert_level_reads_laplace  # noqa: E402

TUBE = ROOT / "configs" / "tube_on_leg_cone.yaml"
# circular levels: B 22 cm round at 2 cm, C 24.5 cm at 8 cm, D 23.5 cm at 14 cm (radii 3.50,
# 3.90, 3.74 cm), inside the tube's 4.55 cm start and its 0 to 0.16 m height
LEG = ("mold={leg: {levels: {B: {girth_cm: 22, height_cm: 2}, C: {girth_cm: 24.5, height_cm: 8},"
       " D: {girth_cm: 23.5, height_cm: 14}}}}")


@pytest.fixture(scope="module")
def tube(tmp_path_factory):
    over = [LEG, "solver.e=1e-7", "constraints.1.displacement=[0, 0, 0]",
            "levels={radius: 0.008, gradient: {C: [50, 80], D: [40, 100]}}",
            "probes=[{name: b_medial, level: B, side: medial, radius: 0.008}, {name: ankle, point: [0.045, 0, 0.015]}]",
            "classes={probe: b_medial}", "profiles=[]"]
    res = clothsim.solve(load_scene(TUBE, over))
    assert res.solve.converged, res.solve.message
    out = tmp_path_factory.mktemp("tube_leg")
    res.save(out)
    return res, out


@pytest.mark.slow
def test_each_levels_girth_mean_is_laplace_from_its_course_strain(tube):
    """Per level: mean = T cos(alpha) / r, T = table(course strain) / (1 + wale strain) [N/m],
    r = girth / 2 pi, alpha the meridian's slope (from the surface), within 2 %; the four
    sides read the mean within 3 % (a circle: uniform pressure round it, 8 mm discs on a
    lattice of 5 mm); the course strain reads the tube's rest width against the girth."""
    res, _ = tube
    lv = res.compression()["levels"]
    assert lv["source"] == "chart" and [r["level"] for r in lv["levels"]] == ["B", "C", "D"]
    rest = 0.1668   # the tube's cut width [m]
    for r in lv["levels"]:
        girth = r["girth_m"]
        assert girth == pytest.approx({"B": 0.22, "C": 0.245, "D": 0.235}[r["level"]], rel=1e-9)
        assert_level_reads_laplace(res, r, rest)
        assert r["reduction_pct"] == pytest.approx(100 * r["course_strain"] / (1 + r["course_strain"]))
    b = lv["levels"][0]["mean_mmhg"]
    for r in lv["levels"]:
        assert r["percent_of_b"] == pytest.approx(100 * r["mean_mmhg"] / b)
    # on this straight tube the pressure rises with the girth (the knit stiffens): C is over
    # 100 % of B, outside the 50-80 % asked
    c = next(r for r in lv["levels"] if r["level"] == "C")
    assert c["percent_of_b"] > 100 and c["gradient_ok"] is False and lv["gradient_ok"] is False


@pytest.mark.slow
def test_probe_by_level_and_side_and_levels_csv(tube):
    """A probe named {level: B, side: medial} reads the B level's medial sensor; the result
    folder's levels.csv holds one row per level with the columns LEVELS_COLUMNS."""
    res, out = tube
    comp = res.compression()
    probe = next(p for p in comp["probes"] if p["name"] == "b_medial")
    b = comp["levels"]["levels"][0]
    assert probe["pressure_mmhg"] == pytest.approx(b["sides"]["medial"], rel=1e-12)
    assert probe["level"] == "B" and probe["side"] == "medial"
    # the medial side is +x (the default), on the surface at B's height
    assert probe["center"][2] == pytest.approx(0.02, abs=1e-9) and probe["center"][0] > 0.03
    rows = list(csv.DictReader(open(out / "levels.csv")))
    assert list(rows[0]) == LEVELS_COLUMNS
    assert [r["level"] for r in rows] == ["B", "C", "D"]
    assert float(rows[1]["girth_cm"]) == pytest.approx(24.5, abs=0.005)
    assert float(rows[0]["mean_mmHg"]) == pytest.approx(b["mean_mmhg"], abs=1e-3)
    assert rows[1]["required_percent_of_B"] == "50-80" and rows[1]["gradient_ok"] == "0"
    # run's printout: a line per level with its girth, the gradient's verdict and B's classes
    from clothsim.cli import _print_compression

    lines = []
    _print_compression(comp, lines.append)
    text = "\n".join(lines)
    assert "girth  24.50 cm" in text and "(asked 50-80 %: outside)" in text
    assert "B's girth mean: RAL-GZ 387:" in text


def test_probe_needs_a_point_or_a_level_and_side():
    for bad in ("probes=[{name: a}]", "probes=[{name: a, level: B}]",
                "probes=[{name: a, point: [0, 0, 0], level: B, side: medial}]",
                "probes=[{name: a, level: B, side: inner}]"):
        with pytest.raises(SceneError) as e:
            load_scene(TUBE, [bad])
        assert "probes.0" in str(e.value), bad


SCANS = {  # the levels found on the bundled scans' left legs (docs/guide/levels.md)
    "smpl_man": {"B": (0.150, 22.39), "C": (0.3625, 37.73), "D": (0.445, 35.85)},
    "smpl_neutral": {"B": (0.125, 21.61), "C": (0.345, 37.33), "D": (0.4225, 35.32)},
}


@pytest.mark.slow
@pytest.mark.parametrize("body", sorted(SCANS))
def test_levels_found_on_the_bundled_scans(body):
    """B (narrowest above the ankle), C (widest calf) and D (narrowest below the knee) on the
    left leg of each bundled scan (Y-up, turned Z-up), at the heights and convex-hull girths
    the docs give (to the 2.5 mm slice and 0.01 cm); C's girth is the largest of the lower
    leg."""
    import trimesh

    m = trimesh.load(ROOT / "static" / "bodies" / f"{body}.stl")
    V = np.asarray(m.vertices) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]]).T
    prof = scan_girths(V, m.faces, (-0.1, 0.03))
    idx = find_levels(prof["z"], prof["girth"])
    for name, (z, g) in SCANS[body].items():
        assert prof["z"][idx[name]] == pytest.approx(z, abs=1e-6), name
        assert prof["girth"][idx[name]] * 100 == pytest.approx(g, abs=0.006), name
    zb, zc, zd = (prof["z"][idx[k]] for k in "BCD")
    lower = (prof["z"] >= zb) & (prof["z"] <= zd)
    # found on the girths smoothed over 1 cm: the raw widest within 0.1 %
    assert prof["girth"][idx["C"]] == pytest.approx(prof["girth"][lower].max(), rel=1e-3)
    assert zb < zc < zd


@pytest.mark.slow
def test_level_set_of_a_scan_scene_places_the_sides_on_the_body():
    """levels on the stocking's scan: B, C, D found and B1 at a given height, sorted by height;
    each side's point lies on the mesh (a section point: within 1e-9 m of it), the medial side
    (+x, towards the body's middle from the left leg) beyond the centre and the lateral side
    short of it, the anterior one at the front (-y)."""
    from clothsim.compression.levels import level_set
    from clothsim.mold import load_mold, mold_query_many

    sc = load_scene(ROOT / "configs" / "garments" / "stocking.yaml",
                    ["levels={center: [-0.1, 0.03], heights: {B1: 0.25}}"])
    mold = load_mold(sc.mold, sc.base_dir)
    ls = level_set(sc, mold)
    assert [r["name"] for r in ls["levels"]] == ["B", "B1", "C", "D"]
    assert [r["how"] for r in ls["levels"]] == ["found", "given", "found", "found"]
    b = ls["levels"][0]
    assert b["girth_m"] == pytest.approx(0.2239, abs=6e-5)
    P = np.array([pt for r in ls["levels"] for pt in r["sides"].values()])
    sd = np.empty(len(P))
    mold_query_many(mold.kernel_args(), P, sd, np.empty((len(P), 3)), np.empty((len(P), 3)),
                    np.empty((len(P), 2), np.int64))
    assert np.abs(sd).max() < 1e-9
    for r in ls["levels"]:
        c, s = r["center"], r["sides"]
        assert s["medial"][0] > c[0] > s["lateral"][0]
        assert s["anterior"][1] < c[1] < s["posterior"][1]


def test_find_levels_on_a_known_girth_profile():
    """A girth profile with a foot below, its narrowest at 0.15 m, a calf widest at 0.36 m and
    the thigh rising above the knee: B, C and D (the narrowest between calf and thigh) are found
    where the profile has them (to two 2.5 mm slices: they are sought on the girths smoothed
    over 1 cm); a profile that only rises has B and no C or D."""
    z = np.arange(0.02, 0.80, 0.0025)
    g = (0.22 + 0.3 * np.exp(-((z - 0.02) / 0.05) ** 2) + 0.16 * np.exp(-((z - 0.36) / 0.09) ** 2)
         + 0.6 * np.clip(z - 0.45, 0, None) ** 1.5 - 0.02 * np.exp(-((z - 0.45) / 0.03) ** 2))
    idx = find_levels(z, g)
    zb = z[np.argmin(np.where(z < 0.3, g, np.inf))]
    assert z[idx["B"]] == pytest.approx(zb, abs=1e-9) and abs(zb - 0.15) < 0.02
    assert z[idx["C"]] == pytest.approx(z[np.argmax(np.where((z > 0.2) & (z < 0.42), g, 0))], abs=0.0051)
    above = (z > z[idx["C"]]) & (z < 0.7)
    assert z[idx["D"]] == pytest.approx(z[above][np.argmin(g[above])], abs=0.0051)
    rising = find_levels(z, 0.2 + 0.1 * z)
    assert set(rising) == {"B"} and rising["B"] == 0
