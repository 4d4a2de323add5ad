"""What a fit reads on each solve, and the folder it writes (clothsim.compression.fit).

Known answers: each solve of a fit reads its targets alone (Result.read: a probe's pressure, a
level's girth mean) by the code of the full readings, so every try's reading equals the full
reading of that try's equilibrium (Result.compression) to 1e-12 mmHg, and the full readings
(every probe, every level's side sensors) are computed once, for the fitted run, when it is
written. ``fitted.yaml`` carries the files it reads beside it, by name: the folder runs after it
is moved and the scene's own folder is gone, and reads what the fit read.
"""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

from conftest import ROOT

TUBE = ROOT / "configs" / "tube_on_leg_cone.yaml"
SLEEVE = ROOT / "configs" / "sewn_sleeve.yaml"
# the tube of tests/test_levels.py on a chart leg with circular levels, on a coarser lattice
# (18 x 16: its middle column i = 9 held in x)
TUBE_ON_CHART = ["mold={leg: {levels: {B: {girth_cm: 22, height_cm: 2}, C: {girth_cm: 24.5, height_cm: 8},"
                 " D: {girth_cm: 23.5, height_cm: 14}}}}",
                 "fabric.divisions=[18, 16]", "constraints.2.nodes={i: 9}", "solver.e=1e-7",
                 "constraints.1.displacement=[0, 0, 0]", "levels={radius: 0.008}", "profiles=[]",
                 "probes=[{name: b_medial, level: B, side: medial, radius: 0.008},"
                 " {name: ankle, point: [0.045, 0, 0.015]}]", "classes={probe: b_medial}"]


def _full(result, name):
    """The full readings' value of a probe or a level's mean (Result.compression)."""
    comp = result.compression()
    for p in comp.get("probes", []):
        if p["name"] == name:
            return p["pressure_mmhg"]
    row = next(r for r in comp["levels"]["levels"] if r["level"] == name)
    return 0.0 if row["mean_mmhg"] is None else row["mean_mmhg"]


@pytest.mark.slow
def test_each_fit_solve_reads_its_targets_alone_with_the_full_readings_numbers(tmp_path, monkeypatch):
    """A fit of the tube's width to B's girth mean on a chart leg: during the fit the full
    readings (Readings.evaluate) are never computed (they were on every solve: 22 sensor discs
    on the graded stocking, 20 s of a solve's 49 s); each try's reading is the full reading of
    its equilibrium to 1e-12 mmHg; writing the fitted run computes the full readings once, and
    fit.json's reading is summary.json's. Result.read gives a probe's and a level's reading as
    compression() does, and refuses a name that is neither."""
    from clothsim.compression import fit as fitmod
    from clothsim.compression.levels import LevelError
    from clothsim.compression.readings import Readings

    calls = []
    evaluate = Readings.evaluate
    monkeypatch.setattr(Readings, "evaluate", lambda self, *a, **k: calls.append(1) or evaluate(self, *a, **k))
    solvers = []
    init = fitmod._Solver.__init__

    def capture(self, *a, **k):
        init(self, *a, **k)
        solvers.append(self)

    monkeypatch.setattr(fitmod._Solver, "__init__", capture)
    data = yaml.safe_load(TUBE.read_text())
    from clothsim.config import apply_overrides
    data = apply_overrides(data, TUBE_ON_CHART)
    res = fitmod.fit_data(data, TUBE, [fitmod.Vary("fabric.size.0", 0.15, 0.18)], [fitmod.Target("B", 20.0)],
                          tol_mmhg=0.1, max_solves=6)
    assert calls == [], "the full readings were computed during the fit"
    f = solvers[0]
    assert len(f.tries) >= 2
    for t, r in zip(f.tries, f.results):
        assert t.readings_mmhg[0] == pytest.approx(_full(r, "B"), abs=1e-12)
    assert len(calls) == len(f.tries)            # one full reading per try, all by this check
    calls.clear()
    out = fitmod.write_outputs(res, tmp_path / "fit", [fitmod.Vary("fabric.size.0", 0.15, 0.18)],
                               [fitmod.Target("B", 20.0)])
    assert len(calls) <= 1                       # the fitted run's full readings, once (cached)
    info = json.loads((out / "fit.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    b = next(r for r in summary["levels"]["levels"] if r["level"] == "B")
    assert info["readings_mmhg"]["B"] == pytest.approx(b["mean_mmhg"], abs=1e-12)
    last = f.results[-1]
    names = ["ankle", "b_medial", "B", "C", "D"]
    got = last.read(names)
    for n in names:
        assert got[n] == pytest.approx(_full(last, n), abs=1e-12), n
    with pytest.raises(LevelError, match="'Q' is neither a probe nor a measuring level"):
        last.read(["Q"])


def test_fitted_yaml_runs_after_its_folder_is_moved_and_the_scene_is_gone(tmp_path):
    """The sewn sleeve, its two material tables in folders of their own (both named
    table.csv), fitted to 20 mmHg at its side probe: fitted.yaml names no path, its two tables
    are copied beside it (table.csv and table-2.csv, the second renamed), and after the fit's
    folder is moved and the scene's folder deleted, `run fitted.yaml` reads the fitted value
    (1e-3 mmHg). fitted.yaml used to hold the machine's absolute paths: moved to another
    machine (here: the scene's folder gone) it failed with "cannot open"."""
    from clothsim.cli import main

    src = tmp_path / "src"
    for part, csv in (("warp", "compression_knit_course.csv"), ("weft", "compression_knit_wale.csv")):
        (src / part).mkdir(parents=True)
        shutil.copy(ROOT / "static" / "materials" / csv, src / part / "table.csv")
    data = yaml.safe_load(SLEEVE.read_text())
    data["fabric"]["warp"] = {"csv": "warp/table.csv"}
    data["fabric"]["weft"] = {"csv": "weft/table.csv"}
    data["probes"] = [{"name": "side", "point": [0.06, 0.0, 0.0]}]
    (src / "sleeve.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "fit"
    assert main(["fit", str(src / "sleeve.yaml"), "--vary", "fabric.size.0", "--target", "side=20mmHg",
                 "--max-solves", "8", "--out", str(out), "--quiet"]) == 0
    info = json.loads((out / "fit.json").read_text())
    text = (out / "fitted.yaml").read_text()
    assert str(tmp_path) not in text and "/" not in "".join(
        str(v) for v in (yaml.safe_load(text)["fabric"]["warp"]["csv"], yaml.safe_load(text)["fabric"]["weft"]["csv"]))
    fitted = yaml.safe_load(text)
    assert {fitted["fabric"]["warp"]["csv"], fitted["fabric"]["weft"]["csv"]} == {"table.csv", "table-2.csv"}
    assert (out / fitted["fabric"]["warp"]["csv"]).read_bytes() == (src / "warp" / "table.csv").read_bytes()
    assert (out / fitted["fabric"]["weft"]["csv"]).read_bytes() == (src / "weft" / "table.csv").read_bytes()
    moved = tmp_path / "mailed" / "fit"
    moved.parent.mkdir()
    shutil.move(str(out), str(moved))
    shutil.rmtree(src)
    assert main(["run", str(moved / "fitted.yaml"), "--out", str(tmp_path / "again"), "--quiet"]) == 0
    again = json.loads((tmp_path / "again" / "summary.json").read_text())
    assert again["probes"][0]["pressure_mmhg"] == pytest.approx(info["readings_mmhg"]["side"], abs=1e-3)


@pytest.mark.slow  # about 4.5 s under load (the scene's validation, scipy's import)
def test_a_try_whose_node_count_changed_is_solved_from_the_scenes_own_start(monkeypatch):
    """A reduction per level changes a panel's row lengths, and its rows gain or lose nodes (the
    graded stocking: 778 nodes at reductions 19.14 / 18.31 % at B / C, 810 at 19.14 / 25 %): the
    fit used to refuse it ("the varied field changes the number of nodes") on the first such try.
    Such a try is now solved from the scene's own start (fit.csv: fresh) and the fit goes on.
    Modelled with a stand-in solve whose node count changes at 0.24 m and whose reading is
    100 x width."""
    import numpy as np

    from clothsim.compression import fit as fitmod

    class Sim:
        def __init__(self, scene, callback=None):
            self.x = float(scene.fabric.size[0])
            self.model = type("M", (), {"fixed_axes": np.zeros((10 if self.x < 0.24 else 12, 3), bool),
                                        "mold": None})()
            self.state = type("S", (), {"positions": np.zeros((10 if self.x < 0.24 else 12, 3))})()
            self.settings = None

        def run(self):
            pass

        def solved_along_a_path(self):
            return False                                   # no stages, friction or load steps

        def result(self):
            x, state = self.x, self.state
            return type("R", (), {"state": state, "solve": type("V", (), {"status": "converged"})(),
                                  "read": lambda _, names: {n: 100.0 * x for n in names},
                                  "compression": lambda _: {"probes": [{"name": "side", "pressure_mmhg": 100.0 * x}]}})()

    monkeypatch.setattr(fitmod.simulation, "Simulation", Sim)
    monkeypatch.setattr(fitmod.simulation, "warm_up", lambda *a: None)
    res = fitmod.fit(SLEEVE, [fitmod.Vary("fabric.size.0", 0.2, 0.3)], [fitmod.Target("side", 25.0)],
                     overrides=["probes=[{name: side, point: [0.06, 0.0, 0.0]}]", "fabric.size.0=0.2"], tol_mmhg=0.01)
    assert res.converged and abs(res.values[0] - 0.25) < 1e-4, res.message
    starts = [(t.values[0] >= 0.24, t.start) for t in res.tries]
    first_big = next(k for k, (big, _) in enumerate(starts) if big)
    assert starts[0] == (False, "fresh") and starts[1] == (False, "warm"), starts   # the count held: warm
    assert starts[first_big][1] == "fresh", starts
