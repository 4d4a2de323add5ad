"""Sweeps that run fits (``fit:`` in a sweep file): each run is an inverse sizing, so a sweep over
limb sizes is a size chart.

Known answer (the analytic limb: a sleeve sewn round a rigid cylinder of radius R): the probe reads
Laplace's p = T / R with T the course tension per current width (the wale stretched 5 % by the
4 mm lift of the top cuff), and the closed tube of nx chords on the limb has the hoop strain
e = nx 2 R sin(pi / nx) / w - 1 (tests/test_seams.py). So the width that gives the target p* is
w* = nx 2 R sin(pi / nx) / (1 + e*), e* the course table's strain at T* = p* R (1 + 0.05).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os

import numpy as np
import pytest
import yaml

from conftest import ROOT

from clothsim import sweep as sw
from clothsim.compression import MMHG

CLASS2 = ROOT / "configs" / "class2_sleeve.yaml"
COURSE = ROOT / "static" / "materials" / "compression_knit_course.csv"


def _fit_sweep(tmp_path, radii, fit, outputs=("fit:fabric.size.0", "probe:ankle_mmhg", "fit_converged", "fit_solves")):
    wrap = [round(r + 0.005, 6) for r in radii]
    start = [round(0.1668 * r / 0.035, 6) for r in radii]
    angle = [round(90 - math.degrees(w / 2 / rw), 6) for w, rw in zip(start, wrap)]
    p = tmp_path / "chart.yaml"
    p.write_text(yaml.safe_dump({
        "base": os.path.relpath(CLASS2, tmp_path),
        "set": {"solver.method": "newton", "solver.e": 1e-9},
        "sweep": {"mode": "zip", "parameters": {"mold.cylinder.radius": list(radii), "initial.wrap.radius": wrap,
                                                "initial.wrap.start_angle": angle, "fabric.size.0": start}},
        "fit": fit, "outputs": list(outputs)}, sort_keys=False))
    return p


def _laplace_width(R: float, p_mmhg: float, nx: int = 34, wale: float = 0.05) -> float:
    d = np.loadtxt(COURSE, delimiter=",", comments="#", skiprows=4)
    strain, tension = d[:, 0] / 100.0, d[:, 1]
    e = float(np.interp(p_mmhg * MMHG * R * (1 + wale), tension, strain))
    return nx * 2 * R * math.sin(math.pi / nx) / (1 + e)


@pytest.mark.slow
def test_size_chart_sweep_fits_the_laplace_width_per_limb(tmp_path):
    """A fitting sweep over three limb radii: the two reachable ones get the Laplace width within
    1e-3 relative and read the target within the tolerance; the third (a 6 cm limb needs about
    0.26 m, above the bound 0.23 m) is refused as out of reach with the reachable range and is
    not retried by a rerun; summary.csv is the chart."""
    radii = [0.03, 0.04, 0.06]
    p = _fit_sweep(tmp_path, radii, {"vary": ["fabric.size.0=0.13:0.23"], "target": ["ankle=25mmHg"],
                                     "tol_mmhg": 0.02})
    out = tmp_path / "out"
    rep = sw.run_sweep(p, out, workers=2, stream=io.StringIO(), plots=True)
    assert rep["ran"] == 3 and rep["statuses"] == {"converged": 2, "out_of_reach": 1}
    rows = list(csv.DictReader((out / "summary.csv").open()))
    for r, R in zip(rows[:2], radii[:2]):
        w = float(r["fit:fabric.size.0"])
        expect = _laplace_width(R, 25.0)
        print(f"R = {R} m: fitted width {w:.6f} m, Laplace {expect:.6f} m ({w / expect - 1:+.2e}), "
              f"{r['fit_solves']} solves")
        assert w == pytest.approx(expect, rel=1e-3)
        assert abs(float(r["probe:ankle_mmhg"]) - 25.0) <= 0.02
        assert r["fit_converged"] == "True" and r["status"] == "converged"
    assert float(rows[1]["fit:fabric.size.0"]) > float(rows[0]["fit:fabric.size.0"])
    bad = rows[2]
    assert bad["status"] == "out_of_reach" and "reachable range" in bad["message"]
    assert bad["fit:fabric.size.0"] == ""
    kept = (out / bad["run_id"] / "scene.yaml").read_text()   # no path: the files by name
    assert "csv: compression_knit_course.csv" in kept and "../" not in kept
    # each run folder holds the fitted scene, the tries and the fitted run's files
    d = out / rows[0]["run_id"]
    for f in ("fitted.yaml", "fit.csv", "fit.json", "result.npz", "probes.csv", "summary.json"):
        assert (d / f).is_file(), f
    fitted = yaml.safe_load((d / "fitted.yaml").read_text())
    assert fitted["fabric"]["size"][0] == pytest.approx(float(rows[0]["fit:fabric.size.0"]))
    s = json.loads((d / "summary.json").read_text())
    assert s["fit"]["converged"] and s["fit"]["solves"] == int(rows[0]["fit_solves"])
    assert len(list(csv.DictReader((d / "fit.csv").open()))) == s["fit"]["solves"]
    assert (out / "plots" / "fit_fabric.size.0__vs__mold.cylinder.radius.png").is_file()
    # a rerun keeps them all (out_of_reach is an answer, not an error to retry)
    assert sw.run_sweep(p, out, workers=2, stream=io.StringIO(), plots=False)["ran"] == 0
    # a new target is a new sweep: every run is redone
    p2 = _fit_sweep(tmp_path, radii[:2], {"vary": ["fabric.size.0=0.13:0.23"], "target": ["ankle=30mmHg"]})
    sw.load_sweep(p2)
    assert all(not sw.finished(out, r) for r in _validated(p2).runs)


def _validated(path):
    s = sw.load_sweep(path)
    assert sw.validate_runs(s) == []
    return s


def test_fit_sweep_is_validated_before_anything_runs(tmp_path):
    """A target naming no probe, a varied field that is not a number, a bad target, and fit outputs
    without a fit block are refused before any run, naming the run or the field."""
    p = _fit_sweep(tmp_path, [0.03], {"vary": ["fabric.size.0"], "target": ["knee=25mmHg"]})
    errors = sw.validate_runs(sw.load_sweep(p))
    assert len(errors) == 1 and "fit: target knee: the scene has no probe 'knee'" in errors[0], errors
    p = _fit_sweep(tmp_path, [0.03], {"vary": ["name"], "target": ["ankle=25mmHg"]}, outputs=("fit_solves",))
    errors = sw.validate_runs(sw.load_sweep(p))
    assert len(errors) == 1 and "not a number" in errors[0], errors
    with pytest.raises(sw.SweepError, match="fit.target"):
        sw.load_sweep(_fit_sweep(tmp_path, [0.03], {"vary": ["fabric.size.0"], "target": ["ankle=25psi"]}))
    with pytest.raises(sw.SweepError, match="needs a fit: block"):
        sw.load_sweep(_fit_sweep(tmp_path, [0.03], None))
    with pytest.raises(sw.SweepError, match="not a field the fit varies"):
        sw.load_sweep(_fit_sweep(tmp_path, [0.03], {"vary": ["fabric.size.0"], "target": ["ankle=25"]},
                                 outputs=("fit:fabric.size.1",)))


def test_example_size_chart_is_valid():
    """configs/sweeps/size_chart.yaml expands to five valid fitting runs."""
    s = _validated(ROOT / "configs" / "sweeps" / "size_chart.yaml")
    assert len(s.runs) == 5 and s.spec.fit is not None


def test_a_failed_runs_scene_yaml_names_its_files_without_a_path(tmp_path):
    """A run that ends without a result (an error, a fit out of reach) keeps its scene.yaml as a
    result folder does: file references by name (the sweep's relative ../static/... paths do not
    resolve from the run's folder), their SHA-256 in the header; with the files put beside it, it
    loads. A scene that does not load is kept as it was, headed by where its paths start."""
    import shutil

    from clothsim.config import load_scene
    from clothsim.sweep.worker import failed_scene_yaml

    raw = yaml.safe_load(CLASS2.read_text())
    text = failed_scene_yaml({"scene": raw, "source": str(CLASS2)}).decode()
    d = yaml.safe_load(text)
    assert d["fabric"]["warp"]["csv"] == "compression_knit_course.csv"
    assert d["fabric"]["weft"]["csv"] == "compression_knit_wale.csv"
    assert "../" not in text and str(ROOT) not in text
    assert "sha256" in text.splitlines()[3]
    (tmp_path / "scene.yaml").write_text(text)
    for name in ("compression_knit_course.csv", "compression_knit_wale.csv"):
        shutil.copy(ROOT / "static" / "materials" / name, tmp_path / name)
    assert load_scene(tmp_path / "scene.yaml").fabric.warp.csv == "compression_knit_course.csv"
    bad = dict(raw, solver={"method": "nonsense"})
    text = failed_scene_yaml({"scene": bad, "source": str(CLASS2)}).decode()
    assert text.startswith("# The run's scene did not load") and "class2_sleeve.yaml" in text
    assert yaml.safe_load(text) == bad
