"""Typed results (issue 29 item 1): one field list (clothsim.records), each field with its unit,
that summary.json, sweeps (``outputs:`` and summary.csv), the report's summary table, plot labels
and docs/guide/sweeps.md read; the pressure analysis in one module (clothsim.pressure) with one
sensor-disc concept; results.py reads no scene."""

from __future__ import annotations

import ast
import copy
import json
from pathlib import Path

import pytest
import yaml

import clothsim
from clothsim.config import load_scene, scene_from_dict
from clothsim.sweep import SweepError, SweepFile, build_summary, load_sweep

ROOT = Path(__file__).resolve().parents[1]
PKG = Path(clothsim.__file__).parent


def _scalar_outputs(summary: dict) -> list[str]:
    """Every scalar field a run's summary.json holds, named as a sweep output: its top-level
    numbers and words, the friction report's (friction.KEY) and each stage's (stage:NAME.KEY,
    its friction's as stage:NAME.friction.KEY)."""
    out = [k for k, v in summary.items() if not isinstance(v, (dict, list))]
    fr = summary.get("friction") or {}
    out += [f"friction.{k}" for k, v in fr.items() if not isinstance(v, (dict, list))]
    for st in fr.get("stages") or []:
        out += [f"stage:{st['name']}.{k}" for k, v in st.items() if not isinstance(v, (dict, list)) and k != "name"]
        out += [f"stage:{st['name']}.friction.{k}" for k, v in st["friction"].items()
                if not isinstance(v, (dict, list))]
    return out


@pytest.fixture(scope="module")
def staged_run(tmp_path_factory):
    """The capstan in two stages (drape, then pull with friction) with a probe on the cylinder,
    solved and saved: its summary has friction, stages and probes."""
    from clothsim.simulation import solve

    data = yaml.safe_load((ROOT / "tests" / "data" / "capstan_stages.yaml").read_text())
    data["probes"] = [{"name": "top", "point": [0.10, 0.01, 0.0], "radius": 0.01}]
    scene = scene_from_dict(data, ROOT / "tests" / "data" / "capstan_stages.yaml")
    res = solve(scene)
    assert res.solve.converged, res.solve.message
    out = tmp_path_factory.mktemp("staged")
    res.save(out)
    return res, out


@pytest.mark.slow
def test_every_summary_field_of_a_run_is_a_sweep_output_and_in_the_report(staged_run):
    """The issue's check, on a real run's summary.json (a staged scene with friction and a probe):
    each of its scalar fields is accepted as a sweep output (``max_sensor_pressure_mmhg`` was
    refused as "unknown output", and gathered_rows, the friction report's stick / slip / cone
    violation and the stages' figures were no outputs) and has a row in the report's summary
    table."""
    from clothsim.compression.report import build_report

    res, out = staged_run
    s = json.loads((out / "summary.json").read_text())
    names = _scalar_outputs(s)
    for must in ("max_sensor_pressure_mmhg", "gathered_rows", "friction.stick", "friction.slip",
                 "friction.cone_violation", "stage:pull.iterations", "stage:pull.friction.slip"):
        assert must in names
    refused = []
    for name in names:
        try:
            SweepFile.model_validate({"base": "x.yaml", "sweep": {"parameters": {"solver.C": [2]}}, "outputs": [name]})
        except Exception as exc:  # noqa: BLE001
            refused.append(f"{name}: {exc}")
    assert not refused, "\n".join(refused)
    html = build_report(out)
    missing = [n for n in names if f"id='summary-{n}'" not in html]
    assert not missing, missing


def test_every_field_of_the_field_list_is_a_sweep_output_and_a_report_row():
    """The whole field list, conditional fields included (a summary holding every one): each is
    accepted as a sweep output, flattened into a sweep row and shown in the report's table with
    its unit."""
    from clothsim.compression.report_html import summary_table
    from clothsim.records import (FRICTION_FIELDS, STAGE_FIELDS, SUMMARY_FIELDS, Diagnostics, FrictionReport,
                                  RunSummary, StageReport, flatten)

    summary = {f.key: (1.5 if f.scalar else []) for f in SUMMARY_FIELDS}
    fr = {k: 2 for k in FrictionReport.keys()}
    fr["steps"] = []
    fr["stages"] = [{**{k: 3 for k in StageReport.keys()}, "name": "press", "friction": dict(fr, stages=[])}]
    summary["friction"] = fr
    flat = flatten(summary)
    names = ([f.key for f in SUMMARY_FIELDS if f.scalar] + [f.key for f in FRICTION_FIELDS]
             + [f"stage:press.{f.key}" for f in STAGE_FIELDS])
    assert len(names) > 50
    for name in names:
        SweepFile.model_validate({"base": "x.yaml", "sweep": {"parameters": {"solver.C": [2]}}, "outputs": [name]})
        assert name in flat, name
    table = summary_table(summary)
    for name in names:
        assert f"id='summary-{name}'" in table, name
    assert "<td>mmHg</td>" in table and "<td>N</td>" in table
    # the records' field order is summary.json's (RunSummary, then Diagnostics)
    assert [f.key for f in SUMMARY_FIELDS] == [*RunSummary.keys(), *Diagnostics.keys()]


@pytest.mark.slow
def test_a_runs_summary_holds_only_fields_of_the_field_list(staged_run):
    """No summary key outside the field list (the two hand-kept lists drifted): summary.json's
    keys, its friction report's, its stages' and its probes'."""
    from clothsim.records import SUMMARY_FIELDS, FrictionReport, ProbeReading, RunSummary, StageReport

    res, out = staged_run
    s = json.loads((out / "summary.json").read_text())
    nested = {"friction", "probes", "profiles", "classes"}
    assert set(s) - nested <= {f.key for f in SUMMARY_FIELDS}
    assert set(s["friction"]) <= set(FrictionReport.keys())
    for st in s["friction"]["stages"]:
        assert set(st) <= set(StageReport.keys())
        assert set(st["friction"]) <= set(FrictionReport.keys())
    for p in s["probes"]:
        assert set(p) <= set(ProbeReading.keys())
    # the records and the dict agree (the summary is the records' to_dict)
    assert res.summary_record().to_dict() == {k: s[k] for k in RunSummary.keys()}
    assert {k: v for k, v in res.diagnostics().items()} == {k: s[k] for k in res.diagnostics()}
    d = res.diagnostics_record()
    assert d.max_sensor_pressure_mmhg == s["max_sensor_pressure_mmhg"]


def test_a_sweep_tabulates_friction_stage_and_probe_outputs(tmp_path):
    """summary.csv reads the named outputs from a run folder: friction.slip, stage:pull.iterations,
    stage:pull.friction.cone_violation, probe:top_mmhg, max_sensor_pressure_mmhg (no solve: a
    finished run folder written by hand)."""
    base = tmp_path / "capstan.yaml"
    data = yaml.safe_load((ROOT / "tests" / "data" / "capstan_stages.yaml").read_text())
    data["probes"] = [{"name": "top", "point": [0.10, 0.01, 0.0], "radius": 0.01}]
    base.write_text(yaml.safe_dump(data))
    outputs = ["max_sensor_pressure_mmhg", "gathered_rows", "friction.slip", "stage:pull.iterations",
               "stage:pull.friction.cone_violation", "probe:top_mmhg", "probe:top_force_n"]
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"base": "capstan.yaml", "sweep": {"parameters": {"solver.C": [2]}},
                                                     "outputs": outputs}))
    sweep = load_sweep(tmp_path / "s.yaml")
    run = sweep.runs[0]
    d = tmp_path / "out" / run.run_id
    d.mkdir(parents=True)
    summary = {"status": "converged", "converged": True, "max_sensor_pressure_mmhg": 12.5, "gathered_rows": 0,
               "friction": {"mu": 0.3, "slip": 7, "stick": 0, "cone_violation": 0.01,
                            "stages": [{"name": "drape", "iterations": 4, "friction": {"slip": 0}},
                                       {"name": "pull", "iterations": 31, "friction": {"cone_violation": 0.02}}]},
               "probes": [{"name": "top", "pressure_mmhg": 3.25, "force_n": 0.001}]}
    (d / "summary.json").write_text(json.dumps(summary))
    (d / "sweep_run.json").write_text(json.dumps({"scene_hash": "", "extra": {}}))
    rows = build_summary(sweep, tmp_path / "out")
    assert [rows[0][o] for o in outputs] == [12.5, 0, 7, 31, 0.02, 3.25, 0.001]
    header = (tmp_path / "out" / "summary.csv").read_text().splitlines()[0].split(",")
    assert header[header.index("status") + 1:-1] == outputs


def test_a_named_output_names_a_probe_or_stage_of_the_scene(tmp_path):
    """stage:NAME.KEY and probe:NAME_SUFFIX are checked against the scene before anything runs; an
    unknown KEY or SUFFIX is an unknown output."""
    from clothsim.sweep import validate_runs

    base = tmp_path / "capstan.yaml"
    base.write_text((ROOT / "tests" / "data" / "capstan_stages.yaml").read_text())
    for outputs, msg in ((["stage:press.iterations"], "the scene has no stage 'press' (stages: drape, pull)"),
                         (["probe:top_mmhg"], "the scene has no probe 'top'")):
        (tmp_path / "s.yaml").write_text(yaml.safe_dump({"base": "capstan.yaml",
                                                         "sweep": {"parameters": {"solver.C": [2]}}, "outputs": outputs}))
        errors = validate_runs(load_sweep(tmp_path / "s.yaml"))
        assert len(errors) == 1 and msg in errors[0], errors
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"base": "capstan.yaml", "sweep": {"parameters": {"solver.C": [2]}},
                                                     "outputs": ["stage:pull.iteratons"]}))
    with pytest.raises(SweepError, match="unknown output 'stage:pull.iteratons'"):
        load_sweep(tmp_path / "s.yaml")


def test_the_sweeps_page_lists_the_field_list():
    """docs/guide/sweeps.md's table of outputs is records.outputs_markdown() (regenerate it with
    ``python -c "from clothsim.records import outputs_markdown; print(outputs_markdown())"``)."""
    from clothsim.records import outputs_markdown

    page = (ROOT / "docs" / "guide" / "sweeps.md").read_text()
    start = page.index("<!-- outputs: generated from clothsim.records -->\n") + len(
        "<!-- outputs: generated from clothsim.records -->\n")
    end = page.index("<!-- end of outputs -->")
    assert page[start:end] == outputs_markdown()


def test_one_sensor_disc_and_units_defined_once():
    """The peak sensor and a probe are the same concept (clothsim.pressure.SensorDisc) with their
    own radii (5 mm, 1 cm: the numbers of the existing outputs); the probe's scene default equals
    PROBE_SENSOR's; MMHG is defined once."""
    from clothsim import pressure, results
    from clothsim.compression import MMHG
    from clothsim.compression.spec import DEFAULT_PROBE_RADIUS

    assert pressure.PEAK_SENSOR.radius_m == results.SENSOR_RADIUS_M == 0.005
    assert pressure.PROBE_SENSOR.radius_m == DEFAULT_PROBE_RADIUS == 0.01
    assert MMHG is pressure.MMHG and results.MMHG is pressure.MMHG
    defs = [p for p in PKG.rglob("*.py") if "\nMMHG = " in p.read_text()]
    assert defs == [PKG / "units.py"], defs  # (clothsim.units: pressure.py re-exports it)


def _imports(path: Path) -> set[str]:
    mod = ".".join(path.relative_to(PKG.parent).with_suffix("").parts)
    package = mod.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            target = node.module if not node.level else ".".join(
                package.split(".")[:len(package.split(".")) - node.level + 1] + ([node.module] if node.module else []))
            out.add(target)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_results_read_no_scene_and_import_nothing_above_them():
    """results.py holds the Scene only to pass it on: it reads none of its fields (what it reports
    comes from RunInputs, taken at compile time), imports nothing from compression/ (it imported
    compression.probes) and no module probes a scene with getattr."""
    src = (PKG / "results.py").read_text()
    tree = ast.parse(src)
    reads = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Attribute)
             and n.value.attr == "scene"]
    assert not reads, f"results.py reads self.scene.<field> at lines {reads}"
    assert not [m for m in _imports(PKG / "results.py") if m.startswith("clothsim.compression")]
    bad = [f"{p.relative_to(PKG)}" for p in PKG.rglob("*.py")
           if 'getattr(scene, "probes"' in p.read_text() or 'getattr(self.scene, "probes"' in p.read_text()
           or 'getattr(self.app.sim.scene, "probes"' in p.read_text()]
    assert not bad, bad


@pytest.mark.slow
def test_a_result_without_inputs_is_refused(staged_run):
    from clothsim.results import Result

    res, _ = staged_run
    with pytest.raises(TypeError, match="run_inputs"):
        Result(res.scene, res.model, res.state, res.solve)
    r2 = Result(res.scene, res.model, res.state, res.solve, inputs=copy.copy(res.inputs))
    assert r2.summary()["name"] == load_scene(ROOT / "tests" / "data" / "capstan_stages.yaml").name


def test_the_cli_lists_the_outputs(capsys):
    """``python app.py outputs`` prints the field list with units: what a sweep file's outputs:
    takes."""
    from clothsim.cli import main
    from clothsim.records import OUTPUT_FIELDS

    assert main(["outputs"]) == 0
    text = capsys.readouterr().out
    lines = {ln.split()[0]: ln for ln in text.splitlines()[1:]}
    assert set(OUTPUT_FIELDS) <= set(lines)
    assert lines["max_sensor_pressure_mmhg"].split()[1] == "mmHg"
    assert "probe:NAME_mmhg" in lines and "stage:NAME.friction.slip" in lines
