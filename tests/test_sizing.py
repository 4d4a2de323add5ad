"""Sizing a garment (clothsim.sizing, the scene field ``garment``): panel scale, reduction at
measuring levels, grading, and ``fit`` varying them.

Known answers: a graded tube's circumference at a level changes by exactly the rule's increment
per size step and the level's height by the length increment; a two-panel graded tube has the
one-panel tube's circumference and lattice area; a reduction r gives the circumference girth x
(1 - r / 100) at the level; the girth of a cylinder is 2 pi r, of an N-gon prism's section its
perimeter 2 N r sin(pi / N); a tube fitted by its reduction on a cylinder meets Laplace's T / r
(the width w* = nx 2 R sin(pi / nx) / (1 + e*), tests/test_sweep_fit.py) and ``run fitted.yaml``
reproduces the reading.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

import clothsim
from clothsim.compile import design_outlines, scene_panels
from clothsim.config import SceneError, load_scene, scene_from_dict
from clothsim.sizing import body_girth, mesh_girth, sizing_table

from conftest import ROOT

CLASS2 = ROOT / "configs" / "class2_sleeve.yaml"
STOCKING = ROOT / "configs" / "garments" / "stocking.yaml"
# a tapered panel (half a leg's tube, hem at v = 0) with vertices at the levels' heights
HALF = [[0.02, 0.0], [0.10, 0.0], [0.11, 0.05], [0.12, 0.15], [0.0, 0.15], [0.01, 0.05]]
WHOLE = [[0.04, 0.0], [0.20, 0.0], [0.22, 0.05], [0.24, 0.15], [0.0, 0.15], [0.02, 0.05]]
LEVELS = [{"name": "B", "at": 0.05}, {"name": "C", "at": 0.15}]
RULES = {"B": {"girth_cm": 1.5, "length_cm": 1.0}, "C": {"girth_cm": 2.5, "length_cm": 2.0}}


def _tube(outlines: list, garment: dict) -> dict:
    panels = [{"name": f"p{k}", "outline": o, "divisions": [8, 6]} for k, o in enumerate(outlines)]
    return {"fabric": {"warp": {"preset": "compression_knit_est"}, "weft": {"preset": "compression_knit_est"}},
            "panels": panels, "garment": garment}


def _table(data: dict) -> dict:
    scene = scene_from_dict(data)
    return {r["name"]: r for r in sizing_table(scene, *design_outlines(scene))}


COURSE = ROOT / "static" / "materials" / "compression_knit_course.csv"


def _laplace_width(R: float, p_mmhg: float, nx: int = 34, wale: float = 0.05) -> float:
    """The tube's width that reads p on a cylinder of radius R (tests/test_sweep_fit.py's known
    answer): w = nx 2 R sin(pi / nx) / (1 + e), e the course strain at T = p R (1 + wale)."""
    from clothsim.compression import MMHG

    d = np.loadtxt(COURSE, delimiter=",", comments="#", skiprows=4)
    e = float(np.interp(p_mmhg * MMHG * R * (1 + wale), d[:, 1], d[:, 0] / 100.0))
    return nx * 2 * R * math.sin(math.pi / nx) / (1 + e)


@pytest.mark.parametrize("size,steps", [("S", -1), ("M", 0), ("L", 1), ("XL", 2)])
def test_a_graded_tube_changes_by_the_rules_increment(size, steps):
    """Circumference at B and C: the base's plus steps x girth_cm, exactly; the levels' heights
    move by steps x length_cm."""
    g = {"levels": LEVELS, "grading": {"sizes": ["S", "M", "L", "XL"], "base": "M", "size": size, "rules": RULES}}
    t = _table(_tube([HALF, HALF], g))
    for name, base in (("B", 0.20), ("C", 0.24)):
        assert t[name]["design_m"] == pytest.approx(base, abs=1e-12)
        assert t[name]["garment_m"] == pytest.approx(base + steps * RULES[name]["girth_cm"] / 100, abs=1e-12)
    panels = scene_panels(scene_from_dict(_tube([HALF, HALF], g)))
    top = max(float(np.ptp(p.geometry.outline @ [0.0, 1.0])) for p in panels)
    assert top == pytest.approx(0.15 + steps * 0.02, abs=1e-12)  # C (the top) moved by 2 cm a step


def test_a_two_panel_graded_tube_equals_a_one_panel_tube():
    """The same tube cut as one panel or as two halves: equal circumferences at every level and
    equal lattice area, graded (size XL) or reduced."""
    g = {"levels": LEVELS, "grading": {"sizes": ["S", "M", "L", "XL"], "base": "M", "size": "XL", "rules": RULES}}
    for garment in (g, {"levels": [{**lv, "girth": 0.3} for lv in LEVELS], "reduction": 20}):
        one, two = _table(_tube([WHOLE], garment)), _table(_tube([HALF, HALF], garment))
        for name in ("B", "C"):
            assert one[name]["garment_m"] == pytest.approx(two[name]["garment_m"], abs=1e-12)
        areas = [sum(p.geometry.node_area().sum() for p in scene_panels(scene_from_dict(_tube(o, garment))))
                 for o in ([WHOLE], [HALF, HALF])]
        assert areas[0] == pytest.approx(areas[1], rel=1e-12)


def test_a_reduction_sets_the_circumference_at_each_level():
    """reduction r: circumference = girth (1 - r / 100) at B and C (girths given; C's own
    reduction overrides the garment's); a width and length scale multiply the design."""
    levels = [{"name": "B", "at": 0.05, "girth": 0.23}, {"name": "C", "at": 0.15, "girth": 0.36, "reduction": 15}]
    t = _table(_tube([HALF, HALF], {"levels": levels, "reduction": 22.5}))
    assert t["B"]["garment_m"] == pytest.approx(0.23 * 0.775, abs=1e-12)
    assert t["C"]["garment_m"] == pytest.approx(0.36 * 0.85, abs=1e-12)
    assert t["B"]["reduction_pct"] == pytest.approx(22.5, abs=1e-9)
    t = _table(_tube([HALF, HALF], {"levels": levels[:1], "scale": {"width": 1.1, "length": 0.9}}))
    assert t["B"]["garment_m"] == pytest.approx(0.20 * 1.1, abs=1e-12)
    assert t["B"]["reduction_pct"] == pytest.approx(100 * (1 - 0.22 / 0.23), abs=1e-9)


def test_without_a_garment_the_lattice_is_the_design():
    """No garment field, or one that changes nothing: the panels' outlines and lattices are the
    design's, to the bit (every example's result stays)."""
    data = _tube([HALF, HALF], None)
    del data["garment"]
    ref = scene_panels(scene_from_dict(data))
    same = scene_panels(scene_from_dict(_tube([HALF, HALF], {"levels": LEVELS})))
    for a, b in zip(ref, same):
        assert np.array_equal(a.geometry.outline, b.geometry.outline)
        assert np.array_equal(a.geometry.node_frac, b.geometry.node_frac)


def test_a_spacing_lattice_keeps_its_node_count_under_a_scale():
    """A panel given by spacing: its spacing scales with the outline, so the node count stays."""
    data = _tube([HALF], {"scale": {"width": 1.3}})
    data["panels"][0].pop("divisions")
    data["panels"][0]["spacing"] = 0.01
    base = dict(data, garment=None)
    n = [int(p.geometry.mask.sum()) for d in (base, data) for p in scene_panels(scene_from_dict(d))]
    assert n[0] == n[1]


def test_the_girth_of_a_cylinder_is_2_pi_r():
    s = load_scene(CLASS2, ["garment={levels: [{name: B, height: 0.01}]}"])
    assert body_girth(s, 0) == pytest.approx(2 * math.pi * 0.035, rel=1e-14)
    s = load_scene(CLASS2, ["garment={levels: [{name: B, height: 0.2}]}"])
    with pytest.raises(Exception, match="beyond the cylinder's length"):
        body_girth(s, 0)


@pytest.mark.slow  # trimesh's section imports its graph tools: about 3 s on a loaded machine
def test_the_girth_of_a_mesh_section():
    """A 24-gon prism mesh: the section's convex hull perimeter 2 N r sin(pi / N) at any
    height, the loop nearest garment.center chosen of two legs."""
    import trimesh

    legs = [trimesh.creation.cylinder(radius=r, height=0.4, sections=24) for r in (0.04, 0.05)]
    legs[0].apply_translation([-0.1, 0.0, 0.2])
    legs[1].apply_translation([0.1, 0.0, 0.2])
    both = trimesh.util.concatenate(legs)
    mesh = (both.vertices, both.faces)
    for c, r in (((-0.1, 0.0, 0.0), 0.04), ((0.1, 0.0, 0.0), 0.05)):
        assert mesh_girth(mesh, np.array([0.0, 0.0, 1.0]), 0.13, c) == pytest.approx(
            2 * 24 * r * math.sin(math.pi / 24), rel=1e-12)


@pytest.mark.parametrize("garment,field,words", [
    ("{levels: [{name: B, at: 0.05}], reduction: 95}", "garment.reduction", "from -50 to 90"),
    ("{scale: {width: 0}}", "garment.scale.width", "from 0.2 to 5"),
    ("{levels: [{name: B, at: 0.05}], grading: {sizes: [S, M], base: M, size: XL}}", "garment.grading",
     "'XL' is not one of the sizes"),
    ("{levels: [{name: B, at: 0.05}], grading: {sizes: [S, M], base: M, rules: {C: {girth_cm: 1}}}}",
     "garment.grading", "no level named 'C'"),
    ("{levels: [{name: B, at: 0.05}], reduction: 20, scale: {width: 1.1}}", "garment", "not both"),
    ("{reduction: 20}", "garment", "needs levels"),
])
def test_bad_garment_fields_name_file_line_and_field(tmp_path, garment, field, words):
    text = STOCKING.read_text().replace("../../", str(ROOT) + "/").split("\ngarment:")[0]  # its own levels out
    p = tmp_path / "g.yaml"
    p.write_text(text + f"\ngarment: {garment}\n")
    with pytest.raises(SceneError) as e:
        load_scene(p)
    line = len(p.read_text().splitlines())
    assert f"{p}:{line}: {field}" in str(e.value) and words in str(e.value), str(e.value)


def test_a_level_outside_the_pattern_is_refused_at_compile(tmp_path):
    from clothsim.cli import main

    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump(_tube([HALF], {"levels": [{"name": "B", "at": 0.4, "girth": 0.2}],
                                              "reduction": 20})))
    with pytest.raises(SceneError, match=r"garment.levels.0: at 0.4 m above the hem the pattern has no width"):
        scene_panels(load_scene(p))
    assert main(["run", str(p), "--out", str(tmp_path / "o")]) == 2


def test_fit_starts_garment_fields_from_the_design():
    """--vary garment.scale.width on a scene without garment starts from 1; an omitted
    garment.reduction from the design's own reduction at the first level; the fitted value is
    printed with its unit."""
    from clothsim.compression.fit import FitResult, Target, Vary, fitted_lines, start_value
    from clothsim.config import read_yaml

    data, _ = read_yaml(CLASS2)
    assert start_value(data, "garment.scale.width") == 1.0
    data["garment"] = {"levels": [{"name": "B", "height": 0.0}], "hem": -0.04}
    assert start_value(data, "garment.reduction") == pytest.approx(100 * (1 - 0.1668 / (2 * math.pi * 0.035)),
                                                                   abs=1e-6)
    res = FitResult(True, "", [24.2, 0.17], [25.0])
    lines = fitted_lines(res, [Vary("garment.reduction"), Vary("fabric.size.0")], [Target("ankle", 25.0)])
    assert lines[:2] == ["  garment.reduction = 24.2 %", "  fabric.size.0 = 0.17 m"]


@pytest.mark.slow  # the scan's section (trimesh) takes about 2 s
def test_the_stocking_is_sized_by_garment_fields_not_fabric_size():
    """The issue's command (--vary fabric.size.0 on the stocking) is refused with the way to size
    panels; garment.reduction starts from the design's own reduction at B (17.60 cm on a girth of
    22.39 cm measured on the scan: 21.39 %)."""
    from clothsim.compression.fit import FitError, start_value
    from clothsim.config import read_yaml

    stocking, _ = read_yaml(STOCKING)
    scene = scene_from_dict(stocking, STOCKING)
    with pytest.raises(FitError, match="a garment of panels has no fabric.size .* vary garment.scale.width"):
        start_value(stocking, "fabric.size.0", scene)
    assert start_value(stocking, "garment.reduction", scene) == pytest.approx(21.39, abs=0.01)


@pytest.mark.slow
def test_fit_by_reduction_meets_laplace_and_run_reproduces_it(tmp_path, capsys):
    """The class II tube on a 3.5 cm cylinder fitted by garment.reduction to 25 mmHg from 15 %:
    within 0.1 mmHg, the reduction is Laplace's (width w* of tests/test_sweep_fit.py) within
    0.1 % of the girth, fit prints it with its unit and the level's table, and the fitted scene
    run again reads the same."""
    from clothsim.cli import main

    out = tmp_path / "fit"
    rc = main(["fit", str(CLASS2), "--set", "garment={hem: -0.04, levels: [{name: B, height: 0.0}], reduction: 15}",
               "--set", "solver.e=1e-9", "--vary", "garment.reduction=5:40", "--target", "ankle=25mmHg", "--tol", "0.02",
               "--out", str(out), "--quiet"])
    assert rc == 0
    printed = capsys.readouterr().out
    info = json.loads((out / "fit.json").read_text())
    assert f"  garment.reduction = {info['fields']['garment.reduction']:.10g} %\n" in printed
    assert "  level B (at 0 m on the body): girth 21.99 cm, garment " in printed and " relaxed (design 16.68 cm), " \
        f"reduction {info['fields']['garment.reduction']:.2f} %" in printed, printed
    assert abs(info["readings_mmhg"]["ankle"] - 25.0) <= 0.1 and info["units"] == {"garment.reduction": "%"}
    R = 0.035
    girth = 2 * math.pi * R
    expected = 100 * (1 - _laplace_width(R, 25.0) / girth)
    assert info["fields"]["garment.reduction"] == pytest.approx(expected, abs=0.1)
    level = info["levels"][0]
    assert level["girth_m"] == pytest.approx(girth, rel=1e-12)
    assert level["reduction_pct"] == pytest.approx(info["fields"]["garment.reduction"], abs=1e-9)
    again = clothsim.solve(load_scene(out / "fitted.yaml"))
    assert again.compression()["probes"][0]["pressure_mmhg"] == pytest.approx(info["readings_mmhg"]["ankle"],
                                                                               abs=1e-3)


SIZES = ROOT / "configs" / "sweeps" / "stocking_sizes.yaml"


def test_the_stocking_sizes_sweep_is_valid():
    """configs/sweeps/stocking_sizes.yaml: four sizes, each a valid fitting run of garment.reduction."""
    from clothsim import sweep as sw

    s = sw.load_sweep(SIZES)
    assert sw.validate_runs(s) == [] and len(s.runs) == 4 and s.spec.fit is not None


@pytest.mark.slow
def test_the_stocking_sizes_sweep_fits_each_size_to_class_ii_at_b(tmp_path):
    """Each graded size reads 27.5 +- 0.1 mmHg at B, with the reduction Laplace's T / r gives on
    its cylinder (the wale strain of its graded height: 4 mm lift over 8 cm + 1 cm a size step)
    within 0.1 % of the girth: S 24.66, M 26.45, L 28.15, XL 29.76 % (measured 24.63, 26.43,
    28.13, 29.76)."""
    import csv
    import io

    from clothsim import sweep as sw

    out = tmp_path / "sizes"
    sw.run_sweep(SIZES, out, workers=2, stream=io.StringIO(), plots=False)
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["garment.grading.size"] for r in rows] == ["S", "M", "L", "XL"]
    for d, r in enumerate(rows, -1):
        R = float(r["mold.cylinder.radius"])
        assert r["fit_converged"] == "True" and abs(float(r["probe:ankle_mmhg"]) - 27.5) <= 0.1
        w = _laplace_width(R, 27.5, wale=0.004 / (0.08 + 0.01 * d))
        assert float(r["fit:garment.reduction"]) == pytest.approx(100 * (1 - w / (2 * math.pi * R)), abs=0.1)


def test_the_viewer_edits_the_reduction_through_the_draft():
    """The viewer's one garment control: the draft's set_reduction validates with the whole scene
    (a value out of range refused by name, the draft unchanged), and needs measuring levels."""
    from clothsim.viewer.draft import SceneDraft

    draft = SceneDraft(load_scene(CLASS2))
    assert draft.has_levels() and draft.reduction() is None
    assert draft.set_reduction(21.5).garment.reduction == 21.5 and draft.reduction() == 21.5
    with pytest.raises(ValueError, match=r"garment reduction \[%\]: must be between -50 and 90"):
        draft.set_reduction(95)
    assert draft.reduction() == 21.5
    plain = SceneDraft(load_scene(ROOT / "configs" / "sewn_sleeve.yaml"))
    with pytest.raises(SceneError, match="garment.levels: the scene has no measuring levels"):
        plain.set_reduction(20)
