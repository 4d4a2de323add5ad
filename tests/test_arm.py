"""An arm from an arm chart's measures (configs/garments/arm_sleeve.yaml): the chart limb of
clothsim.mold.leg with the arm's levels, named as arm-sleeve charts name them (cC the wrist, cD the
forearm, cE the elbow, cG the upper arm; docs/guide/levels.md, "An arm").

Known answer: a uniform compression tube on the arm, whose levels are circles, reads at each
level Laplace's T cos(alpha) / r, T the course tension from that level's course strain (the knit's
table over the current wale width), r = girth / 2 pi, within 2 %; the levels read are the arm's.
An arm has no level B: the readings that are per cent of B (and B's classes) are absent, and
nothing fails for it (the printout, levels.csv, the report).
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import clothsim
from clothsim.config import load_scene
from clothsim.mold.leg import leg_radius

from conftest import ROOT, cli_main
from levels_util import assert_level_reads_laplace  # noqa: E402

SCENE = ROOT / "configs" / "garments" / "arm_sleeve.yaml"
GIRTHS = {"cC": 0.16, "cD": 0.23, "cE": 0.24, "cG": 0.28}   # the scene's chart [m]


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    over = ["levels={radius: 0.01, gradient: {cE: [50, 100]}}",
            "probes=[{name: wrist_medial, level: cC, side: medial, radius: 0.01}]"]
    res = clothsim.solve(load_scene(SCENE, over))
    assert res.solve.converged, res.solve.message
    out = tmp_path_factory.mktemp("arm") / "run"
    res.save(out)
    return res, out


@pytest.mark.slow
def test_each_arm_levels_girth_mean_is_laplace_from_its_course_strain(arm):
    """Per level of the arm (cC, cD, cE, cG, from the wrist up): mean = T cos(alpha) / r, T =
    table(course strain) / (1 + wale strain) [N/m], r = girth / 2 pi, alpha the meridian's slope,
    within 2 %; the sections are circles (the radius the same all round) and the four sides read
    the mean within 3 %; the course strain reads the tube's rest width against the girth."""
    res, _ = arm
    lv = res.compression()["levels"]
    assert lv["source"] == "chart" and [r["level"] for r in lv["levels"]] == ["cC", "cD", "cE", "cG"]
    prm = res.model.mold.params
    rest = 0.142   # the tube's cut width [m]
    for r in lv["levels"]:
        z, girth = r["z_m"], r["girth_m"]
        assert girth == pytest.approx(GIRTHS[r["level"]], rel=1e-9)
        radii = [leg_radius(prm, z, t)[0] for t in np.linspace(0, 2 * math.pi, 13)]
        assert max(radii) - min(radii) < 1e-9 and radii[0] == pytest.approx(girth / (2 * math.pi), rel=1e-6)
        assert_level_reads_laplace(res, r, rest)
    # the uniform tube's pressure rises with the girth (docs: a graded sleeve needs a shaped pattern)
    means = [r["mean_mmhg"] for r in lv["levels"]]
    assert means == sorted(means)


@pytest.mark.slow
def test_an_arm_without_level_b_reads_no_per_cent_of_b(arm, capsys):
    """No level B on the arm: per cent of B, the gradient's verdict and B's classes are absent
    (None, no b_classes) with a note naming why; a probe named by the arm's level reads its side;
    levels.csv has the arm's rows with those columns empty; run's printout and the report from the
    folder are written without error."""
    res, out = arm
    comp = res.compression()
    lv = comp["levels"]
    assert all(r["percent_of_b"] is None and r["gradient_ok"] is None for r in lv["levels"])
    assert lv["gradient_ok"] is None and "b_classes" not in lv and "no level B" in lv["note"]
    cc = lv["levels"][0]
    probe = next(p for p in comp["probes"] if p["name"] == "wrist_medial")
    assert probe["level"] == "cC" and probe["pressure_mmhg"] == pytest.approx(cc["sides"]["medial"], rel=1e-12)
    rows = list(csv.DictReader(open(out / "levels.csv")))
    assert [r["level"] for r in rows] == ["cC", "cD", "cE", "cG"]
    assert all(r["percent_of_B"] == "" and r["gradient_ok"] == "" for r in rows)
    assert rows[2]["required_percent_of_B"] == "50-100"
    from clothsim.cli import _print_compression

    lines = []
    _print_compression(comp, lines.append)
    text = "\n".join(lines)
    assert "% of B" not in text and "B's girth mean" not in text and "no level B" in text
    rc, err = cli_main(capsys, "report", str(out))
    assert rc == 0, err
    page = (out / "report.html").read_text()
    # the report takes no level for B either: no "% of B" figure, no class, the first level's mean
    assert "id='girth-mean-b'" not in page and " % of B</b>" not in page
    first = page.index("id='girth-mean-first'>") + len("id='girth-mean-first'>")
    assert float(page[first:page.index("<", first)]) == pytest.approx(lv["levels"][0]["mean_mmhg"], abs=0.05)
    table = page[page.index("<table id='levels'>"):page.index("</table>", page.index("<table id='levels'>"))]
    assert table.count("<td class='n'>n/a</td>") >= 4 and "B: " not in table
    assert "no level B (an arm's levels are named otherwise)" in page
