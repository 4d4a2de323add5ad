"""Parameter sweeps (clothsim.sweep): expansion, validation before running, executors (local
processes and a real Dask LocalCluster give identical summaries), nothing lost (interrupt and
resume, failing runs recorded, --force), and the material ``scale`` field sweeps rely on.

Scenes are tiny (a 6 x 2 strip, a 6 x 6 to 10 x 10 sphere cap, paper method) so that the file runs
in well under a minute on two cores."""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT, make_scene

from clothsim import sweep as sw

STRIP = ROOT / "configs" / "uniaxial_strip.yaml"
CAP = ROOT / "configs" / "sphere_cap.yaml"


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _strip_sweep(tmp_path, parameters, mode="grid", outputs=("iterations", "energy", "wall_time_s"), name="s.yaml"):
    return _write(tmp_path / name, {
        "base": os.path.relpath(STRIP, tmp_path),
        "set": {"fabric.divisions": [6, 2], "solver.method": "paper"},
        "sweep": {"mode": mode, "parameters": parameters},
        "outputs": list(outputs),
    })


def _cap_sweep(tmp_path, parameters, mode="grid", divisions=(6, 6), name="cap.yaml",
               outputs=("iterations", "energy", "max_contact_pressure_mmhg", "wall_time_s")):
    return _write(tmp_path / name, {
        "base": str(CAP),
        "set": {"fabric.divisions": list(divisions), "solver.method": "paper"},
        "sweep": {"mode": mode, "parameters": parameters},
        "outputs": list(outputs),
    })


def _args(path, out, **kw):
    return argparse.Namespace(sweep=str(path), out=str(out), workers=kw.get("workers", 2),
                              dask=kw.get("dask"), force=kw.get("force", False))


def _csv(path: Path, drop=sw.TIMING_KEYS) -> list[dict]:
    rows = list(csv.DictReader(path.open()))
    return [{k: v for k, v in r.items() if k not in drop} for r in rows]


# ----------------------------------------------------------------------------- expansion


def test_grid_expansion_order_ids_and_linspace(tmp_path):
    """grid mode: every combination, first parameter slowest; linspace gives n values from a to
    b inclusive, rounded to 12 significant digits; the base path resolves against the sweep file;
    run ids are run-<index>-<8 hex> and the same on a second load (stable across reruns)."""
    p = _strip_sweep(tmp_path, {"solver.C": [1.5, 3], "constraints.1.stretch": {"linspace": [1.0, 1.2, 5]}})
    s = sw.load_sweep(p)
    assert s.base_path == STRIP.resolve()
    assert len(s.runs) == 10
    assert [r.params["solver.C"] for r in s.runs] == [1.5] * 5 + [3] * 5
    assert [r.params["constraints.1.stretch"] for r in s.runs[:5]] == [1.0, 1.05, 1.1, 1.15, 1.2]
    assert all(r.run_id.startswith(f"run-{r.index:04d}-") and len(r.run_id) == 17 for r in s.runs)
    assert len({r.run_id for r in s.runs}) == 10
    assert [r.run_id for r in sw.load_sweep(p).runs] == [r.run_id for r in s.runs]
    # the fixed `set` overrides and the varied values both reach the scene
    assert s.runs[6].scene["fabric"]["divisions"] == [6, 2]
    assert s.runs[6].scene["solver"]["C"] == 3 and s.runs[6].scene["constraints"][1]["stretch"] == 1.05


def test_zip_and_logspace(tmp_path):
    """zip mode pairs values element by element; logspace [a, b, n] gives n values from a to b
    (the values, not exponents) evenly spaced on a log scale."""
    p = _strip_sweep(tmp_path, {"solver.e": {"logspace": [1e-8, 1e-4, 5]}, "solver.C": [2, 3, 4, 5, 6]}, mode="zip")
    s = sw.load_sweep(p)
    assert len(s.runs) == 5
    np.testing.assert_allclose([r.params["solver.e"] for r in s.runs], [1e-8, 1e-7, 1e-6, 1e-5, 1e-4], rtol=1e-12)
    assert [r.params["solver.C"] for r in s.runs] == [2, 3, 4, 5, 6]


def test_zip_length_mismatch_and_bad_sweep_file(tmp_path):
    """A zip of lists of different lengths, an unknown output and an unknown key are sweep-file
    errors with file:line: field: message."""
    p = _strip_sweep(tmp_path, {"solver.C": [2, 3, 4], "fabric.divisions": [[6, 2], [8, 2]]}, mode="zip")
    with pytest.raises(sw.SweepError) as e:
        sw.load_sweep(p)
    msg = str(e.value)
    assert "zip mode" in msg and "solver.C has 3" in msg and "fabric.divisions has 2" in msg
    assert msg.startswith(f"{p}:")
    p = _strip_sweep(tmp_path, {"solver.C": [2]}, outputs=["iterations", "iteratoins"])
    with pytest.raises(sw.SweepError, match=r"s.yaml:\d+: outputs: unknown output 'iteratoins'"):
        sw.load_sweep(p)
    d = yaml.safe_load(p.read_text())
    d["sweep"]["paramters"] = d["sweep"].pop("parameters")
    _write(p, d)
    with pytest.raises(sw.SweepError, match="sweep.paramters: unknown field"):
        sw.load_sweep(p)


# ----------------------------------------------------------------------------- validation


def test_every_run_validated_before_any_runs(tmp_path, capsys):
    """A bad value in one run stops the sweep before anything runs (exit 2, no output folder):
    the message names the run id, its parameter values, the field and the validator's message."""
    p = _strip_sweep(tmp_path, {"solver.C": [2, 0.5, 3]})
    out = tmp_path / "out"
    assert sw.main(_args(p, out)) == 2
    err = capsys.readouterr().err
    bad = sw.load_sweep(p).runs[1].run_id
    assert f"{bad} (solver.C=0.5): solver.C: must be greater than 1 (got 0.5)" in err
    assert err.count("run-0") == 1  # only the bad run is listed
    assert not out.exists()


# ----------------------------------------------------------------------------- material scale


def test_material_scale_multiplies_the_table():
    """MaterialSpec.scale multiplies a table's tension (stress x thickness for stress tables,
    presets too); omitted means 1 and is not written to scene.yaml; it must be positive."""
    from clothsim.config import SceneError

    base = make_scene()
    scaled = make_scene(**{"fabric.warp.scale": 2.5, "fabric.weft.scale": 0.5})
    (bw, bf), (sw_, sf) = base.tables(), scaled.tables()
    np.testing.assert_allclose(sw_.tension, 2.5 * bw.tension)
    np.testing.assert_allclose(sf.tension, 0.5 * bf.tension)
    np.testing.assert_array_equal(sw_.strain, bw.strain)
    preset = {"fabric.warp": {"preset": "powernet_est"}, "fabric.weft": {"preset": "powernet_est"}}
    f1 = make_scene(**preset).tables()[1]
    f3 = make_scene(**{**preset, "fabric.weft": {"preset": "powernet_est", "scale": 3}}).tables()[1]
    np.testing.assert_allclose(f3.tension, 3 * f1.tension)
    assert "scale" not in base.to_yaml()
    with pytest.raises(SceneError, match="fabric.warp.scale: must be positive"):
        make_scene(**{"fabric.warp.scale": 0})


# ----------------------------------------------------------------------------- executors


@pytest.mark.slow
def test_local_processes_and_dask_localcluster_give_identical_summaries(tmp_path):
    """The same sweep on local worker processes and on a real dask.distributed LocalCluster
    writes identical summary.csv files (timing columns aside) and the same run folders; after
    the warm-up task the runs load every kernel from numba's on-disk cache (none recompiled)."""
    p = _cap_sweep(tmp_path, {"solver.C": [1.5, 3], "constraints.0.stretch": [1.05, 1.1]})
    rep_local = sw.run_sweep(p, tmp_path / "local", workers=2, stream=io.StringIO(), plots=False)
    rep_dask = sw.run_sweep(p, tmp_path / "dask", workers=2, dask="local", stream=io.StringIO(), plots=False)
    for rep in (rep_local, rep_dask):
        assert rep["ran"] == 4 and rep["statuses"] == {"converged": 4}
        assert rep["numba_compiled"] == 0, rep
        assert rep["numba_cache_hits"] > 0
    a, b = _csv(tmp_path / "local" / "summary.csv"), _csv(tmp_path / "dask" / "summary.csv")
    assert a == b and len(a) == 4
    assert sorted(x.name for x in (tmp_path / "local").glob("run-*")) == \
        sorted(x.name for x in (tmp_path / "dask").glob("run-*"))
    run = next((tmp_path / "dask").glob("run-*"))
    assert {f.name for f in run.iterdir()} == {"result.npz", "history.csv", "sheet.ply", "scene.yaml",
                                               "summary.json", "sweep_run.json"}


@pytest.mark.slow
def test_sweep_on_a_separate_dask_scheduler_over_tcp(tmp_path):
    """A real remote-style cluster: `dask scheduler` and `dask worker` started as their own
    processes (the command-line tools a user runs on other machines), the sweep given the
    scheduler's tcp:// address. It writes the same summary as local worker processes."""
    pytest.importorskip("distributed")
    sched_file = tmp_path / "scheduler.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
             "--no-dashboard", "--scheduler-file", str(sched_file)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env))
        t0 = time.time()
        while not sched_file.exists() and time.time() - t0 < 60:
            time.sleep(0.2)
        assert sched_file.exists(), "the dask scheduler did not start"
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "2", "--nthreads", "1",
             "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=str(tmp_path)))
        from dask.distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
        p = _cap_sweep(tmp_path, {"solver.C": [1.5, 3]})
        rep_remote = sw.run_sweep(p, tmp_path / "remote", dask=address, stream=io.StringIO(), plots=False)
        rep_local = sw.run_sweep(p, tmp_path / "local", workers=2, stream=io.StringIO(), plots=False)
        for rep in (rep_remote, rep_local):
            assert rep["ran"] == 2 and rep["statuses"] == {"converged": 2}
        assert _csv(tmp_path / "remote" / "summary.csv") == _csv(tmp_path / "local" / "summary.csv")
    finally:
        for pr in procs[::-1]:
            pr.terminate()
        for pr in procs[::-1]:
            try:
                pr.wait(20)
            except subprocess.TimeoutExpired:
                pr.kill()


# ----------------------------------------------------------------------------- nothing lost


@pytest.mark.slow
def test_failing_run_recorded_exit_status_counts_it_and_force_reruns(tmp_path, capsys):
    """A run that raises (the initial sheet penetrates the mold) records status 'error' and the
    message; one stopped by max_iterations records its status; the others still run; exit 1 says
    how many did not converge. A rerun with skip_errors skips finished runs (failed ones
    included); without it the run that ended in error is retried (issue 15.14); --force reruns
    them all. Plots are written per output, against the first zipped parameter."""
    p = _cap_sweep(tmp_path, {"initial.lift": [0.03, 0.0, 0.03], "solver.max_iterations": [100000, 100000, 3]},
                   mode="zip", outputs=("iterations", "max_contact_pressure_mmhg"))
    out = tmp_path / "out"
    assert sw.main(_args(p, out)) == 1
    stdout = capsys.readouterr().out
    assert "2 of 3 runs did not converge or failed" in stdout
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["converged", "error", "max_iterations"]
    assert "penetrate the mold" in rows[1]["message"] and rows[1]["iterations"] == ""
    assert rows[2]["iterations"] == "3" and rows[0]["message"] == ""
    assert (out / rows[1]["run_id"] / "error.txt").read_text().startswith("Traceback")
    # zip mode: the zipped parameters change together, so one x axis (the first that varies)
    assert sorted(x.name for x in (out / "plots").iterdir()) == sorted(
        f"{o}__vs__initial.lift.png" for o in ("iterations", "max_contact_pressure_mmhg"))
    mtimes = {d.name: (d / "summary.json").stat().st_mtime_ns for d in out.glob("run-*")}
    rep = sw.run_sweep(p, out, workers=2, stream=io.StringIO(), plots=False, skip_errors=True)
    assert rep["ran"] == 0 and rep["skipped"] == 3
    assert mtimes == {d.name: (d / "summary.json").stat().st_mtime_ns for d in out.glob("run-*")}
    rep = sw.run_sweep(p, out, workers=2, stream=io.StringIO(), plots=False)
    assert rep["ran"] == 1 and rep["skipped"] == 2  # the error run is retried by default
    err_id = rows[1]["run_id"]
    assert {n: t for n, t in mtimes.items() if n != err_id} == {
        d.name: (d / "summary.json").stat().st_mtime_ns for d in out.glob("run-*") if d.name != err_id}
    mtimes = {d.name: (d / "summary.json").stat().st_mtime_ns for d in out.glob("run-*")}
    rep = sw.run_sweep(p, out, workers=2, force=True, stream=io.StringIO(), plots=False)
    assert rep["ran"] == 3 and rep["skipped"] == 0
    assert all((d / "summary.json").stat().st_mtime_ns > mtimes[d.name] for d in out.glob("run-*"))
    assert [r["status"] for r in csv.DictReader((out / "summary.csv").open())] == \
        ["converged", "error", "max_iterations"]


def test_edited_base_scene_reruns_stale_runs(tmp_path):
    """A finished run whose scene no longer matches what the sweep expands to (here the fixed
    overrides changed) is rerun, not silently reused."""
    p = _strip_sweep(tmp_path, {"solver.C": [2, 3]})
    out = tmp_path / "out"
    assert sw.run_sweep(p, out, workers=1, stream=io.StringIO(), plots=False)["ran"] == 2
    d = yaml.safe_load(p.read_text())
    d["set"]["solver.e"] = 1e-4
    _write(p, d)
    rep = sw.run_sweep(p, out, workers=1, stream=io.StringIO(), plots=False)
    assert rep["ran"] == 2 and rep["skipped"] == 0


@pytest.mark.slow
def test_interrupted_sweep_resumes_and_matches_an_uninterrupted_one(tmp_path):
    """`python app.py sweep` killed (SIGKILL to its process group: driver and workers) after a
    few runs finished keeps those runs; rerunning the same command skips them, runs only the rest,
    and the final summary.csv equals an uninterrupted sweep's (timing columns aside)."""
    p = _cap_sweep(tmp_path, {"solver.C": [1.5, 1.75, 2, 2.5, 3, 4, 5, 6, 7, 8]}, divisions=(10, 10))
    ref = tmp_path / "ref"
    assert sw.run_sweep(p, ref, workers=2, stream=io.StringIO(), plots=False)["ran"] == 10
    out = tmp_path / "out"
    cmd = [sys.executable, str(ROOT / "app.py"), "sweep", str(p), "--out", str(out), "--workers", "1"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            start_new_session=True, cwd=ROOT)
    try:
        t0 = time.monotonic()
        for line in proc.stderr:  # one line per finished run when not on a terminal
            if line.startswith("[") and " 3/10 runs" in line:
                break
            assert time.monotonic() - t0 < 120, "the sweep did not progress"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    done = [d.name for d in out.glob("run-*") if (d / "summary.json").is_file()]
    assert 3 <= len(done) < 10
    mtimes = {n: (out / n / "summary.json").stat().st_mtime_ns for n in done}
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"{len(done)} already finished (skipped), {10 - len(done)} to run" in r.stderr
    assert f"ran {10 - len(done)} in" in r.stdout
    assert mtimes == {n: (out / n / "summary.json").stat().st_mtime_ns for n in done}
    assert _csv(out / "summary.csv") == _csv(ref / "summary.csv")
    assert not list(out.glob("run-*/.*.tmp*"))


@pytest.mark.slow
def test_an_unreachable_dask_scheduler_is_named_as_such(tmp_path, capsys, monkeypatch):
    """A scheduler that cannot be reached is reported against --dask, not as "--out: cannot
    write" (its TimeoutError is an OSError, and was taken for a write failure: a hostile pass)."""
    import dask.distributed

    def refuse(address, timeout=None):
        raise TimeoutError(f"Timed out trying to connect to {address} after {timeout}")

    monkeypatch.setattr(dask.distributed, "Client", refuse)
    p = _strip_sweep(tmp_path, {"solver.C": [2.0]})
    assert sw.main(_args(p, tmp_path / "out", dask="tcp://127.0.0.1:1")) == 2
    err = capsys.readouterr().err
    assert "error: --dask tcp://127.0.0.1:1: cannot reach the Dask scheduler (Timed out" in err, err
    assert "cannot write" not in err


def test_a_garment_sweep_runs_and_a_bad_swept_piece_names_its_parameter(tmp_path):
    """A sweep over a panel scene (no fabric.divisions) crashed choosing its warm-up run
    (KeyError 'divisions'); now it runs, and a swept value that only the start-up can refuse (a
    pattern piece the file does not hold) ends that run alone, its error naming the sweep
    parameter rather than the base file."""
    p = _write(tmp_path / "g.yaml", {
        "base": str(ROOT / "configs" / "garments" / "sleeve_dxf.yaml"),
        "sweep": {"parameters": {"panels.0.pattern.piece": ["FRONT", "FRONTT"]}},
        "outputs": ["iterations"],
    })
    rep = sw.run_sweep(p, tmp_path / "out", workers=1, stream=io.StringIO(), plots=False)
    assert rep["statuses"] == {"converged": 1, "error": 1}, rep["statuses"]
    bad = next((tmp_path / "out").glob("run-0001-*"))
    msg = json.loads((bad / "summary.json").read_text())["message"]
    assert "sweep parameter panels.0.pattern.piece=FRONTT: panels.0.pattern.piece: no piece 'FRONTT'" in msg, msg
