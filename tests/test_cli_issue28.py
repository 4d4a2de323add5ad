"""The command line against issue 28: one command per --out folder, an interrupted fit keeps its
tries, bad --dask addresses, exact messages, the pressure printed by run, sweep plots with
readable axes, a truthful start-up note and descriptions for every command."""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from conftest import ROOT, scene_dict

from clothsim import cli

SLEEVE = ROOT / "configs" / "sewn_sleeve.yaml"
SIDE_PROBE = "probes=[{name: side, point: [0.06, 0.0, 0.0]}]"


def _popen(*args):
    return subprocess.Popen([sys.executable, str(ROOT / "app.py"), *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_for(p, text: str, count: int = 1, limit_s: float = 600) -> str:
    """Standard error of p up to the count-th line holding text (p must still be running)."""
    seen, n = "", 0
    t0 = time.monotonic()
    while n < count and time.monotonic() - t0 < limit_s:
        line = p.stderr.readline()
        if not line and p.poll() is not None:
            break
        seen += line
        n += text in line
    assert n >= count, f"never saw {count} x {text!r}:\n{seen}"
    return seen


# ----------------------------------------------------------------------------- item 5


@pytest.mark.slow
def test_a_second_run_into_a_busy_out_is_refused_at_once(tmp_path):
    """Two `run --out` into one folder at once both exited 0 and the folder held one run's
    summary.json beside the other's result.npz; the second is now refused before its solve (exit
    2, naming the holder) and the folder holds the first run's files only."""
    out = tmp_path / "o"
    a = _popen("run", str(ROOT / "configs" / "sphere_cap.yaml"), "--set", "solver.method=paper",
               "--set", "solver.e=1e-30", "--set", "solver.stall_iterations=1000000", "--progress", "--out", str(out))
    try:
        _wait_for(a, "start-up: model built")  # the lock is taken before the solve starts
        small = tmp_path / "s.yaml"
        small.write_text(yaml.safe_dump(scene_dict(**{"solver.e": 1e-7})))
        t0 = time.monotonic()
        b = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", str(small), "--out", str(out), "--quiet"],
                           cwd=ROOT, capture_output=True, text=True, timeout=600)
        took = time.monotonic() - t0
        assert b.returncode == 2, (b.returncode, b.stdout, b.stderr)
        assert f"error: --out {out}: in use by another run (pid {a.pid})" in b.stderr, b.stderr
        assert "Traceback" not in b.stderr and b.stdout == ""
        print(f"second run refused in {took:.1f} s")
        assert not (out / "summary.json").exists()  # the second wrote nothing
    finally:
        a.send_signal(signal.SIGINT)
        so, se = a.communicate(timeout=300)
    assert a.returncode == 130, se
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "stopped" and s["node_count"] == 41 * 41  # the sphere cap's, not the strip's
    # once the first has ended, the folder is free again
    small_run = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", str(small), "--out", str(out), "--quiet"],
                               cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert small_run.returncode == 0, small_run.stderr
    assert json.loads((out / "summary.json").read_text())["node_count"] == 11 * 3  # the strip's


# ----------------------------------------------------------------------------- item 6


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_fit_keeps_its_tries(tmp_path, sig):
    """SIGINT after three finished tries left --out empty (no fit.csv); SIGTERM killed the fit
    (143) with no word. Both now stop it: exit 130, a message, fit.csv holding the finished tries
    (written atomically) and fit.json saying it was interrupted."""
    out = tmp_path / "fit"
    # a tolerance no solve meets: the fit goes on until stopped
    p = _popen("fit", str(SLEEVE), "--vary", "fabric.size.0=0.2:0.3", "--target", "side=20mmHg", "--set", SIDE_PROBE,
               "--set", "solver.method=newton", "--tol", "1e-12", "--max-solves", "100", "--out", str(out))
    try:
        seen = _wait_for(p, "  try ", count=3)
    finally:
        p.send_signal(sig)
        so, se = p.communicate(timeout=300)
    name = signal.Signals(sig).name
    assert p.returncode == 130, (p.returncode, seen + se)
    assert "Traceback" not in se
    assert f"{name}: stopping; the tries finished so far are kept" in se
    assert f"interrupted ({name}): " in se and f"wrote {out}/fit.csv" in se
    rows = (out / "fit.csv").read_text().splitlines()
    assert rows[0].startswith("try,fabric.size.0,side_mmHg") and len(rows) - 1 >= 3, rows
    tried = seen.count("  try ") + se.count("  try ")
    assert len(rows) - 1 == tried  # every finished try, and only those
    info = json.loads((out / "fit.json").read_text())
    assert info["interrupted"] == name and info["converged"] is False and info["solves"] == len(rows) - 1
    assert not [f for f in os.listdir(out) if ".tmp" in f]
    assert so.startswith("not fitted: interrupted")


# ----------------------------------------------------------------------------- item 8


def _strip_sweep(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump({"base": str(ROOT / "configs" / "uniaxial_strip.yaml"),
                                 "set": {"fabric.divisions": [6, 2], "solver.method": "paper"},
                                 "sweep": {"parameters": {"solver.C": [2, 3]}}, "outputs": ["iterations"]}))
    return p


@pytest.mark.parametrize("address", ["nonsense", "http://127.0.0.1:1", "tcp://[::1", "tcp://127.0.0.1:0"])
def test_a_bad_dask_address_is_refused_naming_dask(tmp_path, capsys, address):
    """These gave tracebacks and exit 1; now exit 2, one line naming --dask, nothing run."""
    from clothsim import sweep as sw

    out = tmp_path / "out"
    args = argparse.Namespace(sweep=str(_strip_sweep(tmp_path)), out=str(out), workers=1, dask=address,
                              force=False, skip_errors=False)
    assert sw.main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: --dask {address}: ") and "Traceback" not in err, err
    assert not out.exists() or not list(out.glob("run-*"))


@pytest.mark.slow
def test_a_port_that_never_answers_is_refused_within_the_timeout(tmp_path):
    """A port that accepts and never answers (not a scheduler) hung the sweep over 300 s; it is
    refused after clothsim.sweep.DASK_CONNECT_TIMEOUT_S (15 s) with exit 2."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)  # connections are accepted by the kernel and never answered
    port = srv.getsockname()[1]
    try:
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, str(ROOT / "app.py"), "sweep", str(_strip_sweep(tmp_path)), "--out",
                            str(tmp_path / "out"), "--dask", f"tcp://127.0.0.1:{port}"],
                           cwd=ROOT, capture_output=True, text=True, timeout=240)
        took = time.monotonic() - t0
    finally:
        srv.close()
    print(f"refused after {took:.1f} s")
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert f"error: --dask tcp://127.0.0.1:{port}: no Dask scheduler answered within 15 s" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


# ----------------------------------------------------------------------------- item 11


def test_a_value_just_over_a_bound_is_shown_with_enough_digits(tmp_path):
    """'at most 1e+09 N/m (got 1e+09 N/m)' for 1.0000001e9: the value now shows the digits that
    put it over the bound, from the scene and from a CSV table."""
    from clothsim.config import SceneError, load_scene
    from clothsim.material import MaterialError, parse_table_csv

    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(scene_dict(**{"fabric.warp": {"strain": [0, 0.1], "tension": [0, 1.0000001e9]}})))
    with pytest.raises(SceneError, match=r"at most 1e\+09 N/m \(got 1\.0000001e\+09 N/m\)"):
        load_scene(p)
    with pytest.raises(MaterialError, match=r"t\.csv:3: tension: at most 1e\+09 N/m \(got 1\.0000001e\+09 N/m\)"):
        parse_table_csv("strain,tension\n0,0\n0.1,1000000100\n", "t.csv")
    with pytest.raises(SceneError, match=r"at most 1e\+06 m \(got 1000000\.1\)"):
        load_scene(p, ["fabric.size=[1000000.1, 0.1]"])


def test_a_csv_cell_with_an_underscore_is_not_a_number():
    """Python's float() reads '1_5' as 15: a table cell must not."""
    from clothsim.material import MaterialError, parse_table_csv

    with pytest.raises(MaterialError, match=r"^t\.csv:3: not a number: 0\.1,1_5$"):
        parse_table_csv("strain,tension\n0,0\n0.1,1_5\n", "t.csv")
    s, v, _ = parse_table_csv("strain,tension\n0,0\n0.1,15\n", "t.csv")
    assert v[-1] == 15.0


@pytest.mark.parametrize("bounds, which", [("1e-300:1e300", "upper bound 1e+300"), ("-0.1:0.3", "lower bound -0.1")])
def test_a_fit_bound_the_scene_cannot_take_names_vary(capsys, bounds, which):
    """`fit --vary fabric.size.0=1e-300:1e300` blamed the scene file, and a negative width bound
    was accepted; both are refused before any solve, naming the --vary bound."""
    t0 = time.monotonic()
    rc = cli.main(["fit", str(SLEEVE), "--vary", f"fabric.size.0={bounds}", "--target", "side=20mmHg",
                   "--set", SIDE_PROBE, "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.startswith("error: --vary fabric.size.0=") and f"its {which}: fabric.size" in err, err
    assert str(SLEEVE) not in err and "Traceback" not in err
    assert time.monotonic() - t0 < 60  # no solve was spent


# ----------------------------------------------------------------------------- item 17


@pytest.mark.slow
def test_run_prints_the_pressure_peak_and_the_probes(tmp_path):
    """`run` printed iterations, residual, energy and contact nodes but never a pressure: the
    sensor peak (mmHg and Pa) and each probe (name, mmHg, class) follow the summary line; with
    --json standard output stays JSON alone."""
    args = ["run", str(SLEEVE), "--set", "solver.method=newton", "--set", SIDE_PROBE,
            "--set", "classes={probe: side}", "--out", str(tmp_path / "o"), "--quiet"]
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), *args], cwd=ROOT, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    lines = r.stdout.splitlines()
    assert lines[0].startswith("converged:")
    assert lines[1] == (f"  pressure: peak {s['max_sensor_pressure_mmhg']:.2f} mmHg ({s['max_sensor_pressure_pa']:.1f} Pa) "
                        f"on a sensor disc of radius 5 mm; {s['max_contact_pressure_mmhg']:.2f} mmHg at a single node"), lines
    assert 10 < s["max_sensor_pressure_mmhg"] < 60
    probe = s["probes"][0]
    row = next(line for line in lines if line.strip().startswith("side "))
    assert f"{probe['pressure_mmhg']:8.2f} mmHg" in row
    assert all(f"{k}: {v}" in row for k, v in probe["classes"].items()) and probe["classes"]
    j = subprocess.run([sys.executable, str(ROOT / "app.py"), *args[:-3], "--json", "--quiet"], cwd=ROOT,
                       capture_output=True, text=True, timeout=900)
    assert j.returncode == 0 and json.loads(j.stdout)["max_sensor_pressure_mmhg"] == pytest.approx(
        s["max_sensor_pressure_mmhg"], rel=1e-9)
    assert "  pressure: peak " in j.stderr


# ----------------------------------------------------------------------------- item 19


def _fake_rows(sweep, **extra):
    rows = []
    for k, run in enumerate(sweep.runs):
        rows.append({**run.params, "run_id": run.run_id, "status": "converged", "fit:fabric.size.0": 0.15 + 0.01 * k,
                     "probe:ankle_mmhg": 25.0 + 0.01 * k, "fit_converged": True, "fit_solves": 3 + k,
                     "max_strain_warp": 0.3 + 0.01 * k, "run_time_s": 10.0 + k, **extra})
    return rows


def _labels(monkeypatch):
    """Record each saved figure's (xlabel, ylabel)."""
    import matplotlib.figure

    seen = []
    real = matplotlib.figure.Figure.savefig

    def savefig(fig, *a, **kw):
        ax = fig.axes[0]
        seen.append((ax.get_xlabel(), ax.get_ylabel()))
        return real(fig, *a, **kw)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    return seen


def test_size_chart_plots_each_output_against_the_swept_radius(tmp_path, monkeypatch):
    """The size chart zips four parameters: it drew every output against every one of them (20
    PNGs, run_time_s against initial.wrap.start_angle among them) with raw field paths as axis
    labels. Now: one x axis (the first zipped parameter that varies, or the sweep's x), no
    bookkeeping outputs unless listed under plots, readable labels with units."""
    from clothsim import sweep as sw

    sweep = sw.load_sweep(ROOT / "configs" / "sweeps" / "size_chart.yaml")
    seen = _labels(monkeypatch)
    paths = sw.make_plots(sweep, _fake_rows(sweep), tmp_path)
    assert sorted(p.name for p in paths) == sorted(f"{o}__vs__mold.cylinder.radius.png" for o in (
        "fit_fabric.size.0", "probe_ankle_mmhg", "fit_solves", "max_strain_warp"))
    labels = dict(zip((p.name.split("__vs__")[0] for p in paths), seen))
    assert labels["fit_fabric.size.0"] == ("mold cylinder radius [m]", "fitted fabric size (warp) [m]")
    assert labels["probe_ankle_mmhg"][1] == "probe ankle pressure [mmHg]"
    assert labels["max_strain_warp"][1] == "peak warp strain [-]"
    # the sweep names its x axis; a bookkeeping output is plotted when listed under plots
    spec = yaml.safe_load((ROOT / "configs" / "sweeps" / "size_chart.yaml").read_text())
    spec["base"] = str(ROOT / "configs" / "class2_sleeve.yaml")
    spec["sweep"]["x"] = "initial.wrap.start_angle"
    spec["plots"] = ["run_time_s", "fit:fabric.size.0"]
    p = tmp_path / "chart.yaml"
    p.write_text(yaml.safe_dump(spec))
    sweep = sw.load_sweep(p)
    seen.clear()
    paths = sw.make_plots(sweep, _fake_rows(sweep), tmp_path / "b")
    assert sorted(q.name for q in paths) == ["fit_fabric.size.0__vs__initial.wrap.start_angle.png",
                                             "run_time_s__vs__initial.wrap.start_angle.png"]
    assert ("initial wrap start angle [deg]", "run time [s]") in seen
    spec["plots"] = ["iterations"]
    p.write_text(yaml.safe_dump(spec))
    with pytest.raises(sw.SweepError, match="plots: 'iterations' is not one of the outputs"):
        sw.load_sweep(p)
    spec["plots"], spec["sweep"]["x"] = None, "solver.C"
    p.write_text(yaml.safe_dump(spec))
    with pytest.raises(sw.SweepError, match="x: 'solver.C' is not one of the parameters"):
        sw.load_sweep(p)


def test_grid_plots_skip_a_parameter_that_does_not_vary(tmp_path):
    from clothsim import sweep as sw

    p = tmp_path / "g.yaml"
    p.write_text(yaml.safe_dump({"base": str(ROOT / "configs" / "uniaxial_strip.yaml"),
                                 "sweep": {"parameters": {"solver.C": [2, 3], "solver.e": [1e-7]}},
                                 "outputs": ["iterations", "energy", "wall_time_s"]}))
    sweep = sw.load_sweep(p)
    rows = [{**r.params, "status": "converged", "iterations": 10 + r.index, "energy": 1.0 + r.index,
             "wall_time_s": 0.1} for r in sweep.runs]
    assert sorted(q.name for q in sw.make_plots(sweep, rows, tmp_path)) == [
        "energy__vs__solver.C.png", "iterations__vs__solver.C.png"]


# ----------------------------------------------------------------------------- item 20, 18


def test_no_wheel_is_committed():
    assert not list(ROOT.glob("*.whl"))


@pytest.mark.slow
def test_the_compile_note_only_on_a_cold_cache(tmp_path):
    """`view` printed "compiling kernels (first run only)" on every start; it now says so only
    when numba's cache for these sources holds no compiled kernel, and that it loads them
    otherwise."""
    def start(cache):
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        s.close()
        p = subprocess.Popen([sys.executable, str(ROOT / "app.py"), "view", str(ROOT / "configs" / "uniaxial_strip.yaml"),
                              "--no-browser", "--port", str(port)], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        try:
            line = p.stderr.readline()
            while line.startswith(("note:", "warning:")):
                line = p.stderr.readline()
        finally:
            p.send_signal(signal.SIGTERM)
            p.communicate(timeout=120)
        return line

    cold = tmp_path / "cold"
    assert start(cold).startswith("compiling kernels (first start after an install or update")
    # the same sources' cache folder holding a compiled kernel's index: warm
    folder = subprocess.run([sys.executable, "-c", "import clothsim, numba; print(numba.config.CACHE_DIR)"],
                            cwd=ROOT, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "warm")},
                            capture_output=True, text=True, check=True).stdout.strip()
    (Path(folder) / "clothsim_x").mkdir(parents=True)
    (Path(folder) / "clothsim_x" / "kernels.f-1.py311.nbi").write_bytes(b"x")
    line = start(tmp_path / "warm")
    assert line.startswith("loading the compiled kernels from numba's cache"), line
    assert "first run only" not in line


def test_fit_and_report_have_a_description():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name in ("fit", "report", "run", "sweep", "bench", "view"):
        assert sub.choices[name].description, name
    assert "Inverse sizing" in sub.choices["fit"].format_help()
    assert "HTML report" in sub.choices["report"].format_help()


def test_a_fitting_sweep_refuses_a_bound_before_anything_runs(tmp_path):
    """The same check for a sweep's fit: block, before any run (it would have ended a run's fit
    with a message blaming the base scene, or not at all)."""
    from clothsim import sweep as sw

    p = tmp_path / "chart.yaml"
    p.write_text(yaml.safe_dump({"base": str(ROOT / "configs" / "class2_sleeve.yaml"),
                                 "sweep": {"parameters": {"mold.cylinder.radius": [0.035, 0.04]}},
                                 "fit": {"vary": ["fabric.size.0=-0.1:0.3"], "target": ["ankle=25mmHg"]},
                                 "outputs": ["fit:fabric.size.0"]}))
    errors = sw.validate_runs(sw.load_sweep(p))
    assert len(errors) == 2 and all(
        "fit: vary fabric.size.0=-0.1:0.3: its lower bound -0.1: fabric.size: must be positive" in e for e in errors), errors
