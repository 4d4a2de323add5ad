"""``python app.py sweep``: validate, run what is not finished, rebuild summary.csv, plot."""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

from ..fileio import OutputError, check_free_space, check_out_dir, describe_write_error
from ..plottext import failure
from .executors import _on_terminate, _Progress, _run_dask, _run_local, check_dask_address
from .plots import make_plots
from .runs import _atomic_write, _FolderLock, build_summary, finished
from .spec import Run, Sweep, SweepError, load_sweep, validate_runs


def run_sweep(path: str | Path, out: str | Path, *, workers: int | None = None, dask: str | None = None,
              force: bool = False, skip_errors: bool = False, stream=sys.stderr, plots: bool = True) -> dict:
    """Validate, run (what is not finished) and summarize a sweep. Returns a report dict:
    total, ran, skipped, not_converged, statuses, numba_compiled, numba_cache_hits, seconds.

    Runs that ended in status ``error`` are retried unless skip_errors; force reruns all. The
    output folder is locked while the sweep runs (see _FolderLock). Raises SweepError for bad
    input (nothing has run then), a folder in use by another sweep, a folder that cannot be
    written or a full disk (the message says which; finished runs are kept)."""
    check_dask_address(dask)
    sweep = load_sweep(path)
    errors = validate_runs(sweep)
    if errors:
        raise SweepError(f"{len(sweep.runs)} runs expanded from {path}; invalid runs (nothing was run):\n"
                         + "\n".join("  " + e for e in errors))
    out = Path(out)
    try:
        check_out_dir(out)
    except OutputError as exc:
        raise SweepError(str(exc)) from None
    with _FolderLock(out):
        try:
            check_free_space(out, 0)
            return _run_locked(sweep, out, workers, dask, force, skip_errors, stream, plots)
        except OSError as exc:  # a full disk (or the folder made read-only) while writing
            raise SweepError(describe_write_error(exc, out) + "; finished runs are kept, rerun to continue") from None


def _run_locked(sweep: Sweep, out: Path, workers, dask, force, skip_errors, stream, plots) -> dict:
    _atomic_write(out / "sweep.yaml", sweep.path.read_bytes())
    todo = [r for r in sweep.runs if force or not finished(out, r, skip_errors)]
    skipped = len(sweep.runs) - len(todo)
    retried = 0 if force or skip_errors else sum(
        1 for r in todo if finished(out, r, skip_errors=True))
    known = {r.run_id for r in sweep.runs}
    strays = [p.name for p in out.iterdir() if p.is_dir() and p.name.startswith("run-") and p.name not in known]
    n_workers = workers or os.cpu_count() or 1
    where = (f"Dask cluster at {dask}" if dask and dask != "local" else
             f"a Dask LocalCluster of {n_workers} workers" if dask else f"{min(n_workers, max(1, len(todo)))} local worker processes")
    stream.write(f"sweep {sweep.path.name}: {len(sweep.runs)} runs ({sweep.spec.sweep.mode} over "
                 f"{', '.join(sweep.varied)}); {skipped} already finished (skipped), {len(todo)} to run on {where}\n")
    if retried:
        stream.write(f"  {retried} ended in error (retried; --skip-errors keeps them)\n")
    if strays:
        stream.write(f"  note: {len(strays)} run folders in {out} belong to no run of this sweep (left alone)\n")
    stream.flush()
    report = {"total": len(sweep.runs), "ran": 0, "skipped": skipped, "numba_compiled": 0,
              "numba_cache_hits": 0, "pids": set(),
              "warm_compiled": 0, "warm_s": 0.0}
    t0 = time.perf_counter()
    prog = _Progress(len(sweep.runs), skipped, stream)
    last_csv = [time.perf_counter()]

    def on_done(run: Run, payload: dict) -> None:
        rec = payload.get("record", {})
        status = json.loads(payload["files"]["summary.json"])["status"] if "files" in payload else payload["status"]
        report["ran"] += 1
        report["numba_compiled"] += rec.get("numba_compiled", 0)
        report["numba_cache_hits"] += rec.get("numba_cache_hits", 0)
        if "pid" in rec:
            report["pids"].add((rec.get("host"), rec["pid"]))
        prog.update(run.run_id, status)
        if time.perf_counter() - last_csv[0] > 10.0:  # a live table for long sweeps
            build_summary(sweep, out)
            last_csv[0] = time.perf_counter()

    def on_warm(rec: dict) -> None:
        report["warm_compiled"] += rec["numba_compiled"]
        report["warm_s"] += rec["seconds"]

    interrupted = False
    failed: OSError | None = None
    try:
        if todo:
            if dask:
                _run_dask(todo, sweep, out, n_workers, dask, on_done, on_warm)
            else:
                _run_local(todo, sweep, out, min(n_workers, len(todo)), on_done, on_warm)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP (Terminated)
        interrupted = str(exc) or True
    except OSError as exc:  # writing a run failed (full disk): the pool is already stopped
        failed = exc
    finally:
        prog.close()
        try:
            rows = build_summary(sweep, out)
        except OSError as exc:
            failed = failed or exc
    if failed is not None:
        raise failed
    if plots:
        try:
            make_plots(sweep, rows, out)
        except Exception as exc:  # noqa: BLE001 (summary.csv and the runs are written: a plot never costs them)
            import warnings

            warnings.warn(f"{out}/plots not (all) written ({failure(exc)}); the results are in "
                          f"{out}/summary.csv", stacklevel=2)
    statuses: dict[str, int] = {}
    for r in rows:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
    report.update(seconds=time.perf_counter() - t0, statuses=statuses, interrupted=interrupted,
                  not_converged=sum(n for s, n in statuses.items() if s != "converged"),
                  workers_used=len(report["pids"]))
    del report["pids"]
    return report


def main(args) -> int:
    """``python app.py sweep FILE --out DIR [--workers N] [--dask local|tcp://host:8786] [--force]
    [--skip-errors]``.

    Exit status: 0 all runs converged, 1 some did not converge or failed (the count is printed),
    2 bad input (nothing run), an --out in use by another sweep, or a full disk; 130 interrupted
    (Ctrl-C, SIGTERM or SIGHUP: workers stopped, finished runs kept; rerun to continue)."""
    if args.workers is not None and args.workers < 1:
        print("error: --workers must be at least 1", file=sys.stderr)
        return 2
    import threading

    handlers = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if sig is not None:
                handlers[sig] = signal.signal(sig, _on_terminate)
    try:
        rep = run_sweep(args.sweep, args.out, workers=args.workers, dask=args.dask, force=args.force,
                        skip_errors=getattr(args, "skip_errors", False))
    except SweepError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)
    out = Path(args.out)
    st = ", ".join(f"{n} {s}" for s, n in sorted(rep["statuses"].items(), key=lambda kv: -kv[1]))
    print(f"{rep['total']} runs: {st}; ran {rep['ran']} in {rep['seconds']:.1f} s, skipped {rep['skipped']} "
          f"finished; wrote {out}/summary.csv and {out}/plots/")
    if rep["ran"]:
        print(f"  numba: cache warm-up compiled {rep['warm_compiled']} kernels ({rep['warm_s']:.1f} s); "
              f"then the runs loaded {rep['numba_cache_hits']} from the on-disk cache and compiled "
              f"{rep['numba_compiled']}")
    if rep["interrupted"]:
        print(f"interrupted: {rep['total'] - rep['statuses'].get('pending', 0) - rep['statuses'].get('crashed', 0)} "
              f"of {rep['total']} runs finished and kept; rerun the same command to continue", file=sys.stderr)
        return 130
    if rep["not_converged"]:
        print(f"{rep['not_converged']} of {rep['total']} runs did not converge or failed (see {out}/summary.csv)")
        return 1
    return 0
