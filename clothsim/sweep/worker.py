"""The sweep worker: one run in a worker process (local or Dask), returning its files' bytes (the
driver writes them), and the kernel warm-up before the sweep fans out."""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import yaml
from numba.core.dispatcher import Dispatcher

from ..compression.folder import portable_scene_yaml
from ..compression.fit import FitError, FitResult, fit_data, fit_info, write_outputs
from ..config import scene_from_dict
from ..simulation import prepare, solve, warm_up
from .spec import FitBlock, Run, Sweep, _canonical, _fmt


def _numba_counts() -> tuple[int, int]:
    """(cache hits, cache misses = compilations) summed over clothsim's numba kernels so far in
    this process."""
    hits = misses = 0
    seen = set()
    for name, mod in list(sys.modules.items()):
        if not name.startswith("clothsim") or mod is None:
            continue
        for obj in list(vars(mod).values()):
            if isinstance(obj, Dispatcher) and id(obj) not in seen:
                seen.add(id(obj))
                st = obj.stats
                hits += sum(st.cache_hits.values())
                misses += sum(st.cache_misses.values())
    return hits, misses


def run_one(task: dict) -> dict:
    """Run one scene in a worker and return its files' bytes (never raises for a bad run).

    task: run_id, index, params, scene (raw dict), source (the base scene path, for relative
    paths), scene_hash. Returns {"run_id", "files": {name: bytes}, "record": dict}."""
    t0 = time.perf_counter()
    h0, m0 = _numba_counts()
    record = {"run_id": task["run_id"], "index": task["index"], "params": task["params"],
              "scene_hash": task.get("scene_hash", ""), "pid": os.getpid(), "host": _hostname()}
    files: dict[str, bytes] = {}
    try:
        if task.get("fit"):
            files, result = _fit_one(task)
        else:
            # a problem the start-up finds in a swept field names the parameter, not the base file
            blame = {k: f"sweep parameter {k}={_fmt(v)}" for k, v in (task.get("params") or {}).items()}
            scene = scene_from_dict(task["scene"], task["source"], None, blame)
            result = solve(scene)
            files = _result_files(result)
        record["extra"] = {}
        if result is not None:
            z = result.positions[..., 2]
            record["extra"] = {"max_z_m": float(z.max()), "min_z_m": float(z.min())}
    except Exception as exc:  # a failing run is recorded, never raised
        summary = {"converged": False, "status": "error", "message": f"{type(exc).__name__}: {exc}"}
        files = {
            "scene.yaml": failed_scene_yaml(task),
            "error.txt": traceback.format_exc().encode(),
            "summary.json": json.dumps(summary, indent=2).encode(),
        }
        record["extra"] = {}
    h1, m1 = _numba_counts()
    record["numba_cache_hits"] = h1 - h0
    record["numba_compiled"] = m1 - m0
    record["extra"]["run_time_s"] = time.perf_counter() - t0
    return {"run_id": task["run_id"], "files": files, "record": record}


def failed_scene_yaml(task: dict) -> bytes:
    """``scene.yaml`` of a run that ended without a result (an error, a fit out of reach): as a
    result folder's (:func:`clothsim.compression.folder.portable_scene_yaml`: file references by
    name, each file's SHA-256 in the header, no path of the machine that ran it) when the run's
    scene loads; otherwise the scene as the sweep made it, headed by where its relative file
    references start from (the base scene's folder, by name)."""
    try:
        return portable_scene_yaml(scene_from_dict(task["scene"], task["source"])).encode()
    except Exception:  # the scene itself is what failed: keep it as it was, said so
        head = (f"# The run's scene did not load (error.txt says why). Its file references are relative to the\n"
                f"# folder of the sweep's base scene, {Path(task['source']).name}.\n")
        return (head + yaml.safe_dump(task["scene"], sort_keys=False)).encode()


def _result_files(result, extra=None) -> dict[str, bytes]:
    """The files of a single headless run (Result.save into a private temporary folder), plus
    ``extra(folder)`` writing more files there first."""
    files = {}
    with tempfile.TemporaryDirectory(prefix="clothsim-run-") as td:
        if extra is not None:
            extra(Path(td))
        else:
            result.save(td)
        for p in sorted(Path(td).iterdir()):
            if p.is_file() and not p.name.startswith("."):
                files[p.name] = p.read_bytes()
    return files


def _fit_one(task: dict):
    """One run of a fitting sweep: fit the run's scene (warm starts inside the fit) and return
    (files, the fitted Result or None). The fitted run's files plus fitted.yaml, fit.csv and
    fit.json; summary.json gains ``fit`` (fit.json's content) and, when the targets were not met,
    the status ``not_fitted`` (or ``out_of_reach``, with the reachable range in the message)."""
    spec = FitBlock.model_validate(task["fit"])
    varies, targets = spec.parsed()
    try:
        res = fit_data(task["scene"], Path(task["source"]), varies, targets, tol_mmhg=spec.tol_mmhg,
                       max_solves=spec.max_solves)
    except FitError as exc:
        res = FitResult(False, str(exc), [], [], tries=exc.tries)
        info = {**fit_info(res, varies, targets), "fields": {}, "readings_mmhg": {}}
        summary = {"converged": False, "status": "out_of_reach", "message": str(exc), "fit": info}
        files = {"scene.yaml": failed_scene_yaml(task),
                 "fit.csv": res.tries_csv(varies, targets).encode(),
                 "fit.json": json.dumps(info, indent=2).encode(),
                 "summary.json": json.dumps(summary, indent=2).encode()}
        return files, None
    files = _result_files(res.result, lambda d: write_outputs(res, d, varies, targets))
    summary = json.loads(files["summary.json"])
    summary["fit"] = fit_info(res, varies, targets)
    if not res.converged:
        summary.update(converged=False, status="not_fitted", message=res.message)
    files["summary.json"] = json.dumps(summary, indent=2).encode()
    return files, res.result


def warm_cache(task: dict) -> dict:
    """Compile (or load) the kernels one run needs, in a worker, before the sweep fans out: with
    a cold on-disk cache this makes one worker compile while the others wait, instead of every
    worker compiling the same kernels at once; with a warm cache it costs a cache load."""
    t0 = time.perf_counter()
    h0, m0 = _numba_counts()
    try:
        scene = scene_from_dict(task["scene"], task["source"])
        model, state, _ = prepare(scene)
        warm_up(model, state, scene.solver)
    except Exception:  # the run itself will report it
        pass
    h1, m1 = _numba_counts()
    return {"numba_cache_hits": h1 - h0, "numba_compiled": m1 - m0, "seconds": time.perf_counter() - t0}


def _warm_tasks(todo: list[Run], sweep: Sweep) -> list[dict]:
    """One warm-up task per distinct (solver method, mold kind): the smallest such run."""
    def size(r: Run) -> int:
        """The run's lattice size: the sheet's divisions, or its panels' (a garment's)."""
        divs = [r.scene.get("fabric", {}).get("divisions")] + [p.get("divisions") for p in r.scene.get("panels") or []
                                                               if isinstance(p, dict)]
        return sum(math.prod(d) for d in divs if isinstance(d, (list, tuple)) and d
                   and all(isinstance(x, int) for x in d))

    picked: dict[str, Run] = {}
    for r in todo:
        mold = r.scene.get("mold") or {}
        key = _canonical([r.scene.get("solver", {}).get("method", "auto"), sorted(mold) if isinstance(mold, dict) else str(mold)])
        if key not in picked or size(r) < size(picked[key]):
            picked[key] = r
    return [_task(r, sweep) for r in picked.values()]


def _hostname() -> str:
    import socket

    return socket.gethostname()


def _task(run: Run, sweep: Sweep) -> dict:
    return {"run_id": run.run_id, "index": run.index, "params": run.params, "scene": run.scene,
            "source": str(sweep.base_path), "scene_hash": run.scene_hash,
            "fit": sweep.spec.fit.model_dump() if sweep.spec.fit is not None else None}
