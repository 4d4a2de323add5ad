"""Parameter sweeps: expand a sweep file into runs, validate them all, run them on local worker
processes or a Dask cluster, and keep every finished run.

A sweep file names a base scene (relative to the sweep file), the fields to vary and the outputs
to tabulate and plot::

    base: ../sphere_cap.yaml
    set: {solver.method: paper}          # optional: fixed overrides applied to every run
    sweep:
      mode: grid                         # grid = every combination; zip = element by element
      parameters:
        solver.C: [1.5, 2, 4, 8]
        fabric.divisions: [[10, 10], [20, 20]]
        constraints.0.stretch: {linspace: [1.0, 1.2, 5]}   # 5 values from 1.0 to 1.2
        solver.e: {logspace: [1.0e-8, 1.0e-4, 5]}          # 5 values from 1e-8 to 1e-4, log-spaced
    outputs: [iterations, wall_time_s, max_contact_pressure_mmhg]

Output folder (``--out``)::

    sweep.yaml                       the sweep file as run
    run-0003-1a2b3c4d/               one folder per run: result.npz, history.csv, sheet.ply,
                                     scene.yaml, sweep_run.json, summary.json (written last)
    summary.csv                      one row per run, rebuilt from the run folders
    plots/<output>__vs__<param>.png  one plot per (output, varied parameter; zip: one parameter),
                                     timings left out unless listed under plots:

Design decisions (why):

* **Run ids** are ``run-<index>-<8 hex of sha1(parameter values)>``: stable across reruns of the
  same sweep file and independent of the executor or of completion order.
* **Workers return the files' bytes; the driver writes them.** A worker runs
  :func:`clothsim.simulation.solve`, saves the Result with :meth:`Result.save` into a private
  temporary folder (so the files are exactly those of a single headless run) and returns their
  bytes. The driver writes each file atomically (temporary name, then rename) into the run folder,
  ``summary.json`` last. This works on a remote Dask cluster without a shared filesystem (only the
  files the scenes reference, such as mold meshes, must be readable by the workers).
* **A finished run is a folder with summary.json.** ``summary.csv`` is rebuilt from the folders,
  so an interrupted sweep (Ctrl-C, killed driver or worker) keeps every finished run and rerunning
  the same command runs only the rest (``--force`` reruns all). A finished run whose scene no
  longer matches what the sweep file now expands to (the base scene was edited) is rerun, and so
  is one that ended in status ``error`` (``--skip-errors`` keeps those).
* **One sweep per folder.** The driver holds ``fcntl.flock`` on ``out/.clothsim.lock``
  (holding its pid) while it runs; a second sweep (or a run or fit) is refused naming that pid. The kernel drops the
  lock with the driver, however it ends, so a stale lock file never blocks.
* **Workers die with the driver.** SIGTERM/SIGHUP act as Ctrl-C (the pool is terminated). Local
  workers (children of the forkserver, not of the driver) set PR_SET_PDEATHSIG and poll the
  driver's pid, so even ``kill -9`` of the driver leaves no worker behind.
* **A full disk** stops the sweep with SweepError (exit 2): free space is checked before each
  run's files are written and a failed write leaves no temporary file.
* **A failing run never stops the sweep.** The worker catches every exception (SceneError,
  MoldError, unexpected ones) and reports status ``error`` with the message; a run that diverges
  or hits a limit keeps its solver status. A worker process that dies is reported as ``crashed``
  (a ``crashed.json`` note, no summary.json), so a rerun retries it.
* **Everything is validated before anything runs**: the sweep file (pydantic), every expanded
  scene and every distinct mold. An error names the run id, the field and the message.
* The local executor uses a ``forkserver`` (``spawn`` where unavailable) process pool. numba's
  on-disk cache (``cache=True`` kernels, stored beside the sources) is shared by all workers: each
  worker loads the compiled kernels instead of compiling them. The worker counts numba cache hits
  and misses per run and the driver reports them.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import os
import shutil
import signal
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .config import SceneError, apply_overrides, format_validation_error, read_yaml, scene_from_dict
from .fileio import LOCK_FILE  # noqa: F401  (the lock a sweep, run or fit holds on its --out)

#: keys of Result.summary() a sweep can tabulate and plot
SUMMARY_KEYS = (
    "name", "converged", "status", "message", "iterations", "residual", "relative_residual",
    "best_residual", "energy", "wall_time_s", "startup_s", "solver", "C", "e", "contact_count",
    "node_count", "clothsim_version", "slack_springs", "spring_count", "undetermined_nodes",
    "min_weft_extent_ratio", "max_strain_warp", "max_strain_weft", "max_contact_pressure_pa",
    "max_contact_pressure_mmhg", "gathered_contact_nodes", "max_seam_gap_m", "max_penetration_m",
)
#: outputs the sweep worker computes beside the summary (stored in sweep_run.json)
EXTRA_KEYS = {
    "max_z_m": "highest node's z [m] (a cap's apex height)",
    "min_z_m": "lowest node's z [m]",
    "run_time_s": "wall time of the whole run in the worker [s] (start-up + relaxation + files)",
}
#: outputs read from a scene's probes (summary.json "probes"): ``probe:NAME_<key>``
PROBE_OUTPUTS = {"mmhg": "pressure_mmhg", "pa": "pressure_pa", "contact_fraction": "contact_fraction"}


def _probe_output(name: str) -> bool:
    """True for ``probe:NAME_mmhg``, ``probe:NAME_pa`` or ``probe:NAME_contact_fraction``."""
    return name.startswith("probe:") and any(name.endswith("_" + k) and len(name) > len("probe:_" + k)
                                             for k in PROBE_OUTPUTS)


#: columns that depend on timing; equal sweeps differ only in these
TIMING_KEYS = ("wall_time_s", "startup_s", "run_time_s")
DEFAULT_OUTPUTS = ["iterations", "residual", "energy", "wall_time_s"]
FINISHED_FILE = "summary.json"


class SweepError(ValueError):
    """A sweep file or one of its runs is invalid; str is the user-facing message."""


# ----------------------------------------------------------------------------- the sweep file


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


#: the most runs one sweep expands to (a grid's product of counts); more is refused up front
MAX_RUNS = 100_000


class Space(_Strict):
    """``{linspace: [a, b, n]}``: n evenly spaced values from a to b (inclusive);
    ``{logspace: [a, b, n]}``: n values from a to b (inclusive, a, b > 0) evenly spaced on a log
    scale (numpy.geomspace: the endpoints are the values, not their exponents)."""

    linspace: tuple[float, float, int] | None = None
    logspace: tuple[float, float, int] | None = None

    @model_validator(mode="after")
    def _one(self):
        given = [k for k in ("linspace", "logspace") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give a list of values, {linspace: [a, b, n]} or {logspace: [a, b, n]}")
        a, b, n = getattr(self, given[0])
        if n < 1:
            raise ValueError(f"{given[0]}: n must be at least 1 (got {n})")
        if n > MAX_RUNS:
            raise ValueError(f"{given[0]}: n must be at most {MAX_RUNS:,} (got {n:,}): a sweep runs at most "
                             f"{MAX_RUNS:,} scenes")
        if not (math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"{given[0]}: a and b must be finite")
        if given[0] == "logspace" and not (a > 0 and b > 0):
            raise ValueError(f"logspace: a and b must be positive (got {a}, {b})")
        return self

    def values(self) -> list[float]:
        import numpy as np

        if self.linspace is not None:
            a, b, n = self.linspace
            v = np.linspace(a, b, n)
        else:
            a, b, n = self.logspace
            v = np.geomspace(a, b, n)
        # 12 significant digits: 1.15 rather than 1.1500000000000001 in ids, tables and scenes
        return [float(f"{x:.12g}") for x in v]


class SweepBlock(_Strict):
    """mode: grid (every combination, first parameter slowest) or zip (element by element; all
    lists the same length). parameters: scene field path -> list of values or a Space. x: the
    parameter the plots put on their x axis in zip mode (default: the first that varies; the
    zipped parameters change together, so one axis tells it all)."""

    mode: Literal["grid", "zip"] = "grid"
    parameters: dict[str, Union[list[Any], Space]]
    x: str | None = None

    @model_validator(mode="after")
    def _x(self):
        if self.x is not None and self.x not in self.parameters:
            raise ValueError(f"x: '{self.x}' is not one of the parameters ({', '.join(self.parameters)})")
        return self

    @field_validator("parameters")
    @classmethod
    def _params(cls, v):
        if not v:
            raise ValueError("give at least one parameter to vary")
        for k, vals in v.items():
            if not k or any(not p for p in k.split(".")):
                raise ValueError(f"'{k}' is not a field path like solver.C or constraints.0.stretch")
            if isinstance(vals, list) and not vals:
                raise ValueError(f"{k}: the list of values is empty")
        return v

    def expanded(self) -> dict[str, list]:
        return {k: (v.values() if isinstance(v, Space) else list(v)) for k, v in self.parameters.items()}

    @model_validator(mode="after")
    def _run_count(self):
        """At most MAX_RUNS runs (a grid's product of counts), refused before anything is expanded."""
        counts = {k: (len(v) if isinstance(v, list) else (v.linspace or v.logspace)[2])
                  for k, v in self.parameters.items()}
        total = max(counts.values()) if self.mode == "zip" else math.prod(counts.values())
        if total > MAX_RUNS:
            detail = ", ".join(f"{k}: {n:,}" for k, n in counts.items())
            raise ValueError(f"parameters: {total:,} runs ({self.mode} of {detail}); a sweep runs at most {MAX_RUNS:,}")
        return self

    @model_validator(mode="after")
    def _zip_lengths(self):
        if self.mode == "zip":
            lens = {k: len(v) for k, v in self.expanded().items()}
            if len(set(lens.values())) > 1:
                detail = ", ".join(f"{k} has {n}" for k, n in lens.items())
                raise ValueError(f"parameters: zip mode needs the same number of values for every parameter ({detail})")
        return self


class FitBlock(_Strict):
    """``fit:`` makes every run of the sweep an inverse sizing (clothsim.compression.fit, as
    ``python app.py fit``): ``vary`` the fields (``PATH`` or ``PATH=LO:HI``; default bounds: the
    run's start value +-30 %; a swept value of a fitted field is that run's start value) until the probes read ``target`` (``PROBE=VALUE[mmHg|Pa|kPa]``).
    Each run's folder holds the fitted run's files plus fitted.yaml, fit.csv and fit.json; its
    summary.json carries ``fit`` (fit.json) and the status ``not_fitted`` or ``out_of_reach`` when
    the target was not met."""

    vary: list[str] = Field(min_length=1)
    target: list[str] = Field(min_length=1)
    tol_mmhg: float = 0.1
    max_solves: int = Field(default=12, ge=1, le=100)

    @field_validator("vary")
    @classmethod
    def _vary(cls, v):
        from .compression.fit import FitError, parse_vary

        try:
            for x in v:
                parse_vary(x)
        except FitError as exc:
            raise ValueError(str(exc).replace("--vary ", "")) from None
        return v

    @field_validator("target")
    @classmethod
    def _target(cls, v):
        from .compression.fit import FitError, parse_target

        try:
            for x in v:
                parse_target(x)
        except FitError as exc:
            raise ValueError(str(exc).replace("--target ", "")) from None
        return v

    @field_validator("tol_mmhg")
    @classmethod
    def _tol(cls, v):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"must be positive and finite (got {v})")
        return v

    def parsed(self):
        """(list of Vary, list of Target)."""
        from .compression.fit import parse_target, parse_vary

        return [parse_vary(x) for x in self.vary], [parse_target(x) for x in self.target]


#: outputs of a fitting sweep: the fit's own (fit:PATH is the fitted value of a varied field)
FIT_OUTPUTS = {"fit_converged": "the fit met every target within tol_mmhg",
               "fit_solves": "solves the fit spent"}


def _fit_output(name: str) -> bool:
    return name.startswith("fit:") and len(name) > 4


class SweepFile(_Strict):
    """A sweep: base scene (path relative to the sweep file), fixed overrides (``set``), the
    parameters to vary, an optional ``fit`` (each run an inverse sizing, see FitBlock) and the
    outputs to tabulate and plot (keys of summary.json, max_z_m, min_z_m, run_time_s, a probe's
    reading: probe:NAME_mmhg, probe:NAME_pa, probe:NAME_contact_fraction; with ``fit``:
    fit:PATH, the fitted value of a varied field, fit_converged and fit_solves) and the outputs to
    plot (``plots``; default: the numeric outputs but the timings, BOOKKEEPING)."""

    name: str | None = None
    base: str
    fixed: dict[str, Any] = Field(default_factory=dict, alias="set")
    sweep: SweepBlock
    fit: FitBlock | None = None
    outputs: list[str] = Field(default_factory=lambda: list(DEFAULT_OUTPUTS))
    plots: list[str] | None = None

    @model_validator(mode="after")
    def _plots(self):
        for o in self.plots or []:
            if o not in self.outputs:
                raise ValueError(f"plots: '{o}' is not one of the outputs ({', '.join(self.outputs)})")
        return self

    @field_validator("outputs")
    @classmethod
    def _outputs(cls, v):
        known = set(SUMMARY_KEYS) | set(EXTRA_KEYS) | set(FIT_OUTPUTS)
        for i, name in enumerate(v):
            if name not in known and not _probe_output(name) and not _fit_output(name):
                raise ValueError(f"unknown output '{name}' (known: {', '.join(sorted(known))}, "
                                 f"probe:NAME_mmhg / _pa / _contact_fraction, or fit:FIELD)")
        if len(set(v)) != len(v):
            raise ValueError("an output is listed twice")
        return v

    @model_validator(mode="after")
    def _fit_outputs(self):
        fit_outs = [o for o in self.outputs if _fit_output(o) or o in FIT_OUTPUTS]
        if fit_outs and self.fit is None:
            raise ValueError(f"outputs: {fit_outs[0]} needs a fit: block (fit: {{vary: [...], target: [...]}})")
        if self.fit is not None:
            paths = [v.path for v in self.fit.parsed()[0]]
            for o in self.outputs:
                if _fit_output(o) and o[4:] not in paths:
                    raise ValueError(f"outputs: {o}: '{o[4:]}' is not a field the fit varies ({', '.join(paths)})")
        return self


@dataclass
class Run:
    """One expanded run: its index, stable id, parameter values and the raw scene dict."""

    index: int
    run_id: str
    params: dict[str, Any]
    scene: dict = field(repr=False)
    scene_hash: str = ""


@dataclass
class Sweep:
    spec: SweepFile
    path: Path
    base_path: Path
    runs: list[Run]

    @property
    def varied(self) -> list[str]:
        return list(self.spec.sweep.parameters)


def _canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def run_id_for(index: int, params: dict) -> str:
    h = hashlib.sha1(_canonical(params).encode()).hexdigest()[:8]
    return f"run-{index:04d}-{h}"


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file and expand it into runs (not yet validated as scenes)."""
    path = Path(path)
    data, root = read_yaml(path, SweepError)
    if not isinstance(data, dict):
        raise SweepError(f"{path}: a sweep file must be a mapping with base, sweep and outputs")
    try:
        spec = SweepFile.model_validate(data)
    except ValidationError as exc:
        raise SweepError(format_validation_error(exc, str(path), root)) from None
    base_path = (path.parent / spec.base).resolve()
    if not base_path.is_file():
        raise SweepError(f"{path}: base: no such scene file {base_path}")
    return Sweep(spec, path.resolve(), base_path, expand(spec, base_path))


def expand(spec: SweepFile, base_path: Path) -> list[Run]:
    """The runs of a sweep, in a deterministic order (grid: first parameter slowest)."""
    base = read_yaml(base_path, SweepError)[0]  # bounded, UTF-8, aliases budgeted
    if not isinstance(base, dict):
        raise SweepError(f"{base_path}: the base scene must be a mapping")
    values = spec.sweep.expanded()
    names = list(values)
    if spec.sweep.mode == "grid":
        combos = list(itertools.product(*(values[n] for n in names)))
    else:
        combos = list(zip(*(values[n] for n in names)))
    runs = []
    for i, combo in enumerate(combos):
        params = dict(zip(names, combo))
        runs.append(Run(i, run_id_for(i, params), params, {}))
    # fixed overrides first, then the varied ones (a varied field wins)
    for run in runs:
        try:
            run.scene = apply_overrides(apply_overrides(base, spec.fixed), run.params)
        except SceneError as exc:
            run.scene = {"__error__": str(exc).replace("--set ", "")}
    return runs


def _fmt(v) -> str:
    return json.dumps(v) if isinstance(v, (list, dict, tuple)) else str(v)


def validate_runs(sweep: Sweep, max_errors: int = 20) -> list[str]:
    """Validate every expanded scene and every distinct mold; returns error lines (empty = ok).

    Each line names the run, its parameter values, the field and the message."""
    from .mold import MoldError, check_mold

    errors: list[str] = []
    molds: dict[str, str | None] = {}
    n_bad = 0
    for run in sweep.runs:
        label = f"{run.run_id} ({', '.join(f'{k}={_fmt(v)}' for k, v in run.params.items())})"
        msg = run.scene.get("__error__") if isinstance(run.scene, dict) else None
        scene = None
        if msg is None:
            try:
                scene = scene_from_dict(run.scene, None)
            except SceneError as exc:
                msg = "; ".join(line.split(": ", 1)[1] if line.startswith("<scene>: ") else line
                                for line in str(exc).splitlines())
        if scene is not None:
            scene._source = sweep.base_path
            fit = sweep.spec.fit.model_dump() if sweep.spec.fit is not None else None
            key = scene.to_dict() if fit is None else [scene.to_dict(), fit]  # a new target reruns
            run.scene_hash = hashlib.sha1(_canonical(key).encode()).hexdigest()[:16]
            if fit is not None:
                msg = _check_fit(sweep, run)
            if msg is None:
                msg = _check_probe_outputs(sweep.spec.outputs, scene)
            if scene.mold is not None and msg is None:
                key = _canonical([scene.mold, str(scene.base_dir)])
                if key not in molds:
                    try:
                        check_mold(scene.mold, scene.base_dir)  # the file and mesh, not the surface
                        molds[key] = None
                    except (MoldError, SceneError, OSError, ValueError) as exc:
                        molds[key] = f"mold: {exc}"
                msg = molds[key]
        if msg is not None:
            n_bad += 1
            if len(errors) < max_errors:
                errors.append(f"{label}: {msg}")
    if n_bad > len(errors):
        errors.append(f"... and {n_bad - len(errors)} more invalid runs")
    return errors


def _check_probe_outputs(outputs: list[str], scene) -> str | None:
    """The first ``probe:NAME_<key>`` output whose NAME is not a probe of the scene (the message),
    or None: such a column stayed empty in every run, with no word."""
    names = [p.name for p in scene.probes]
    for o in outputs:
        if not _probe_output(o):
            continue
        key = next(k for k in sorted(PROBE_OUTPUTS, key=len, reverse=True) if o.endswith("_" + k))
        name = o[len("probe:"):-len(key) - 1]
        if name not in names:
            return (f"outputs: {o}: the scene has no probe '{name}' "
                    f"(probes: {', '.join(names) if names else 'none'})")
    return None


def _check_fit(sweep: Sweep, run: Run) -> str | None:
    """A fitting sweep's run: its targets name probes of its scene and its varied fields hold
    numbers (the message, or None)."""
    from .compression.fit import FitError, check_fit

    varies, targets = sweep.spec.fit.parsed()
    try:
        check_fit(run.scene, sweep.base_path, varies, targets)
    except (FitError, SceneError) as exc:
        return "fit: " + str(exc).replace("--target ", "target ").replace("--vary ", "vary ")
    return None


# ----------------------------------------------------------------------------- the worker


def _numba_counts() -> tuple[int, int]:
    """(cache hits, cache misses = compilations) summed over clothsim's numba kernels so far in
    this process."""
    try:
        from numba.core.dispatcher import Dispatcher
    except ImportError:  # pragma: no cover
        return 0, 0
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
            from .simulation import solve

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
            "scene.yaml": yaml.safe_dump(task["scene"], sort_keys=False).encode(),
            "error.txt": traceback.format_exc().encode(),
            "summary.json": json.dumps(summary, indent=2).encode(),
        }
        record["extra"] = {}
    h1, m1 = _numba_counts()
    record["numba_cache_hits"] = h1 - h0
    record["numba_compiled"] = m1 - m0
    record["extra"]["run_time_s"] = time.perf_counter() - t0
    return {"run_id": task["run_id"], "files": files, "record": record}


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
    from .compression.fit import FitError, FitResult, fit_data, fit_info, write_outputs

    spec = FitBlock.model_validate(task["fit"])
    varies, targets = spec.parsed()
    try:
        res = fit_data(task["scene"], Path(task["source"]), varies, targets, tol_mmhg=spec.tol_mmhg,
                       max_solves=spec.max_solves)
    except FitError as exc:
        res = FitResult(False, str(exc), [], [], tries=exc.tries)
        info = {**fit_info(res, varies, targets), "fields": {}, "readings_mmhg": {}}
        summary = {"converged": False, "status": "out_of_reach", "message": str(exc), "fit": info}
        files = {"scene.yaml": yaml.safe_dump(task["scene"], sort_keys=False).encode(),
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
        from .simulation import prepare, warm_up

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


# ----------------------------------------------------------------------------- run folders


def _atomic_write(path: Path, data: bytes) -> None:
    from .results import atomic_write_bytes

    atomic_write_bytes(path, data)


def write_run(out: Path, payload: dict) -> None:
    """Write a worker's files into out/<run_id>/, each atomically, summary.json last."""
    from .fileio import check_free_space

    d = out / payload["run_id"]
    d.mkdir(parents=True, exist_ok=True)
    check_free_space(out, sum(len(b) for b in payload["files"].values()))
    # an older result must not look finished while the new files replace it
    for stale in (FINISHED_FILE, "crashed.json", "error.txt"):
        (d / stale).unlink(missing_ok=True)
    for tmp in d.glob(".*.tmp*"):  # left by a write that was killed half-way
        tmp.unlink(missing_ok=True)
    files = payload["files"]
    for name, data in files.items():
        if name != FINISHED_FILE:
            _atomic_write(d / name, data)
    _atomic_write(d / "sweep_run.json", json.dumps(payload["record"], indent=2, default=str).encode())
    _atomic_write(d / FINISHED_FILE, files[FINISHED_FILE])


def write_crashed(out: Path, run: Run, message: str) -> None:
    d = out / run.run_id
    d.mkdir(parents=True, exist_ok=True)
    (d / FINISHED_FILE).unlink(missing_ok=True)
    _atomic_write(d / "crashed.json", json.dumps({"status": "crashed", "message": message}, indent=2).encode())


def finished(out: Path, run: Run, skip_errors: bool = True) -> bool:
    """True if out/<run_id> holds a complete run of this very scene (one that ended in status
    ``error`` counts only with skip_errors)."""
    d = out / run.run_id
    if not (d / FINISHED_FILE).is_file():
        return False
    try:
        rec = json.loads((d / "sweep_run.json").read_text())
    except (OSError, ValueError):
        return False
    if rec.get("scene_hash") != run.scene_hash:
        return False
    return skip_errors or _status(d) != "error"


def _status(d: Path) -> str | None:
    try:
        return json.loads((d / FINISHED_FILE).read_text()).get("status")
    except (OSError, ValueError, AttributeError):
        return None


class _FolderLock:
    """The sweep's lock on its output folder (clothsim.fileio.FolderLock, shared with run and
    fit: a run into a sweep's folder is refused too). Raises SweepError naming the holder."""

    def __init__(self, out: Path):
        from .fileio import FolderLock

        self.lock = FolderLock(out, "sweep")

    def __enter__(self):
        from .fileio import OutputError

        try:
            self.lock.__enter__()
        except OutputError as exc:
            raise SweepError(str(exc)) from None
        return self

    def __exit__(self, *exc):
        self.lock.__exit__(*exc)


def read_row(out: Path, run: Run) -> dict:
    """The summary of one run from its folder: summary.json + the sweep worker's extras."""
    d = out / run.run_id
    row: dict[str, Any] = {}
    try:
        row.update(json.loads((d / FINISHED_FILE).read_text()))
        rec = json.loads((d / "sweep_run.json").read_text())
        row.update(rec.get("extra", {}))
        for p in row.get("probes") or []:  # probe outputs: probe:NAME_mmhg, _pa, _contact_fraction
            for key, field in PROBE_OUTPUTS.items():
                row[f"probe:{p['name']}_{key}"] = p.get(field)
        fit = row.get("fit")
        if isinstance(fit, dict):  # a fitting sweep's run: fit:PATH, fit_converged, fit_solves
            for path, value in (fit.get("fields") or {}).items():
                row[f"fit:{path}"] = value
            row["fit_converged"] = fit.get("converged")
            row["fit_solves"] = fit.get("solves")
    except (OSError, ValueError):
        try:
            row.update(json.loads((d / "crashed.json").read_text()))
        except (OSError, ValueError):
            row.update({"status": "pending", "message": "not run yet"})
    return row


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v)
    return str(v)


def build_summary(sweep: Sweep, out: Path) -> list[dict]:
    """Rebuild out/summary.csv from the run folders; returns the rows (dicts of raw values)."""
    outputs = [o for o in sweep.spec.outputs if o != "status"]
    header = ["run_id", *sweep.varied, "status", *outputs, "message"]
    rows = []
    for run in sweep.runs:
        r = read_row(out, run)
        row = {"run_id": run.run_id, **run.params, "status": r.get("status", "error")}
        for o in outputs:
            row[o] = r.get(o)
        row["message"] = "" if row["status"] == "converged" else (r.get("message") or "")
        rows.append(row)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow([_cell(row.get(h)) for h in header])
    _atomic_write(out / "summary.csv", buf.getvalue().encode())
    return rows


# ----------------------------------------------------------------------------- plots


def _axis_values(values: list) -> tuple[list[float] | None, str]:
    """Numeric x positions for parameter values, or None for categorical ones, and an axis note."""
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return [float(v) for v in values], ""
    if all(isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) for x in v)
           and len(set(v)) == 1 for v in values):
        return [float(v[0]) for v in values], " (n of [n, n])"
    return None, ""


def _label(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return _fmt(v)


#: outputs that keep the books (timings) rather than describe the result: not plotted unless the
#: sweep file lists them under ``plots``
BOOKKEEPING = TIMING_KEYS


def plot_axes(sweep: Sweep, rows: list[dict]) -> list[str]:
    """The parameters the plots put on their x axis: in grid mode each parameter that takes more
    than one value; in zip mode one (the zipped parameters change together): ``sweep.x`` or the
    first that takes more than one value."""
    def varies(param):
        seen = []
        for r in rows:
            if r.get(param) not in seen:
                seen.append(r.get(param))
        return len(seen) > 1

    moving = [p for p in sweep.varied if varies(p)]
    if sweep.spec.sweep.mode == "zip":
        if sweep.spec.sweep.x is not None:
            return [sweep.spec.sweep.x]
        return moving[:1]
    return moving


def plot_outputs(sweep: Sweep, rows: list[dict]) -> list[str]:
    """The outputs plotted: the sweep file's ``plots``, or every numeric output but the
    bookkeeping ones (BOOKKEEPING: timings)."""
    chosen = sweep.spec.plots if sweep.spec.plots is not None else [
        o for o in sweep.spec.outputs if o not in BOOKKEEPING]
    return [o for o in chosen
            if any(isinstance(r.get(o), (int, float)) and not isinstance(r.get(o), bool) for r in rows)]


def make_plots(sweep: Sweep, rows: list[dict], out: Path) -> list[Path]:
    """One PNG per (plotted output, x axis): out/plots/<output>__vs__<param>.png, axes labelled
    with readable names and units (clothsim.labels). The x axes are :func:`plot_axes`, the
    outputs :func:`plot_outputs`.

    grid mode with several parameters: one line per combination of the other parameters (up to
    10, with a legend), otherwise points. zip mode: one line. Runs that did not converge are
    drawn hollow; failed runs (no value) are left out and counted in the title. Names and swept
    values are drawn as written, never as mathtext (clothsim.plottext)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from .labels import axis_label
    from .plottext import PLAIN, plain_legend

    outputs = plot_outputs(sweep, rows)
    pdir = out / "plots"
    pdir.mkdir(parents=True, exist_ok=True)
    written = []
    varied = sweep.varied
    spaces = sweep.spec.sweep.parameters
    for param in plot_axes(sweep, rows):
        all_vals = []
        for r in rows:
            if r[param] not in all_vals:
                all_vals.append(r[param])
        xs_num, note = _axis_values(all_vals)
        others = [p for p in varied if p != param] if sweep.spec.sweep.mode == "grid" else []
        groups: dict[str, list[dict]] = {}
        for r in rows:
            key = ", ".join(f"{p}={_label(r[p])}" for p in others)
            groups.setdefault(key, []).append(r)
        logx = isinstance(spaces[param], Space) and spaces[param].logspace is not None
        if xs_num is not None and not logx and min(xs_num) > 0 and max(xs_num) / min(xs_num) >= 16 and len(xs_num) >= 4:
            logx = True
        for o in outputs:
            fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
            n_missing = 0
            as_lines = len(groups) <= 10
            cmap = plt.get_cmap("viridis" if len(groups) > 10 else "tab10")
            for gi, (key, grp) in enumerate(groups.items()):
                pts = []
                for r in grp:
                    y = r.get(o)
                    if not isinstance(y, (int, float)) or isinstance(y, bool) or not math.isfinite(y):
                        n_missing += 1
                        continue
                    x = xs_num[all_vals.index(r[param])] if xs_num is not None else all_vals.index(r[param])
                    pts.append((x, float(y), r["status"] == "converged"))
                if not pts:
                    continue
                pts.sort()
                color = cmap(gi / max(1, len(groups) - 1)) if len(groups) > 10 else cmap(gi % 10)
                if as_lines:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", color=color, lw=1.4,
                            label=key or None)
                for x, y, ok in pts:
                    ax.plot([x], [y], "o", ms=5, color=color, mfc=color if ok else "none",
                            alpha=1.0 if as_lines else 0.6)
            if xs_num is None:
                ax.set_xticks(range(len(all_vals)))
                ax.set_xticklabels([_label(v) for v in all_vals], rotation=30 if len(all_vals) > 6 else 0, **PLAIN)
            elif logx:
                from matplotlib.ticker import NullFormatter

                ax.set_xscale("log")
                ticks = sorted(set(xs_num))
                if len(ticks) <= 12:  # label the swept values themselves, not powers of ten
                    ax.set_xticks(ticks)
                    ax.set_xticklabels([f"{t:.4g}" for t in ticks])
                    ax.xaxis.set_minor_formatter(NullFormatter())
            ys = [r.get(o) for r in rows if isinstance(r.get(o), (int, float)) and not isinstance(r.get(o), bool)]
            pos = [y for y in ys if math.isfinite(y) and y > 0]
            if pos and len(pos) == len(ys) and max(pos) / min(pos) > 1e3:
                ax.set_yscale("log")
            # plain text: a field name or a unit is never parsed as mathtext
            ax.set_xlabel(axis_label(param) + note, **PLAIN)
            ax.set_ylabel(axis_label(o), **PLAIN)
            title = f"{sweep.spec.name or sweep.path.stem}: {o} against {param}"
            sub = []
            together = [p for p in varied if p != param] if sweep.spec.sweep.mode == "zip" else []
            if together:
                sub.append(f"zipped with {', '.join(together)}")
            if any(r["status"] != "converged" for r in rows if isinstance(r.get(o), (int, float))):
                sub.append("hollow = did not converge")
            if n_missing:
                sub.append(f"{n_missing} runs without a value (failed or pending)")
            if not as_lines:
                sub.append(f"{len(groups)} combinations of {', '.join(others)} as points")
            ax.set_title(title + ("\n" + "; ".join(sub) if sub else ""), fontsize=10, **PLAIN)
            ax.grid(True, alpha=0.3, which="both")
            if as_lines and others:
                plain_legend(ax, fontsize=8, title=None, loc="best", framealpha=0.8)
            fig.tight_layout()
            safe = f"{o}__vs__{param}".replace("/", "_").replace(":", "_")
            p = pdir / f"{safe}.png"
            buf = io.BytesIO()
            fig.savefig(buf, format="png")
            plt.close(fig)
            _atomic_write(p, buf.getvalue())
            written.append(p)
    return written


# ----------------------------------------------------------------------------- executors


class _Progress:
    """A progress bar over runs on stderr: redrawn in place on a terminal, one line per finished
    run otherwise (logs, CI)."""

    def __init__(self, total: int, done: int, stream=sys.stderr):
        self.total, self.done, self.failed = total, done, 0
        self.stream = stream
        self.tty = stream.isatty()
        self.t0 = time.perf_counter()
        self.n_new = 0

    def update(self, run_id: str, status: str) -> None:
        self.done += 1
        self.n_new += 1
        if status != "converged":
            self.failed += 1
        el = time.perf_counter() - self.t0
        left = self.total - self.done
        eta = el / self.n_new * left if self.n_new else 0.0
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(frac * 24)
        text = (f"[{bar:<24}] {self.done}/{self.total} runs, {self.failed} not converged, "
                f"{_hms(el)} elapsed, ~{_hms(eta)} left  {run_id} {status}")
        if self.tty:
            self.stream.write("\r" + text[:160].ljust(160))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _hms(s: float) -> str:
    s = int(s)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _task(run: Run, sweep: Sweep) -> dict:
    return {"run_id": run.run_id, "index": run.index, "params": run.params, "scene": run.scene,
            "source": str(sweep.base_path), "scene_hash": run.scene_hash,
            "fit": sweep.spec.fit.model_dump() if sweep.spec.fit is not None else None}


_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (prctl PR_SET_PDEATHSIG); a no-op
    elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _process_start(pid: int) -> str | None:
    """The start time of process pid (field 22 of /proc/pid/stat), None if gone or unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2:].split()[19]


def _worker_init(driver_pid: int, driver_start: str | None, poll_s: float = 0.5) -> None:
    """Pool worker initializer: the worker dies with the sweep driver, however the driver ends.

    A local worker's parent is the forkserver, not the driver, so two guards: PR_SET_PDEATHSIG
    (the worker is killed when the forkserver dies) and a daemon thread that polls the driver's
    pid (with its start time, against pid reuse) and exits the worker when the driver is gone
    (kill -9 included). The thread runs between kernel calls: a worker notices within one
    solver iteration."""
    import threading

    _die_with_parent()

    def alive() -> bool:
        if driver_start is not None:
            return _process_start(driver_pid) == driver_start
        try:
            os.kill(driver_pid, 0)
            return True
        except ProcessLookupError:
            return False
        except PermissionError:
            return True

    def watch() -> None:
        while alive():
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="clothsim-driver-watch", daemon=True).start()


def _local_pool(workers: int):
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    # one thread per worker process (as Dask's nanny does), inherited by the spawned workers
    for k in _THREAD_ENV:
        os.environ.setdefault(k, "1")
    methods = mp.get_all_start_methods()
    if "forkserver" in methods:
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["clothsim.simulation", "clothsim.sweep"])
    else:
        ctx = mp.get_context("spawn")
    me = os.getpid()
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                               initargs=(me, _process_start(me)))


def _run_local(todo, sweep, out, workers, on_done, on_warm):
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    pool = _local_pool(workers)
    futs = {}
    try:
        for t in _warm_tasks(todo, sweep):
            on_warm(pool.submit(warm_cache, t).result())
        futs = {pool.submit(run_one, _task(r, sweep)): r for r in todo}
        for fut in as_completed(futs):
            run = futs[fut]
            try:
                payload = fut.result()
            except BrokenProcessPool:
                write_crashed(out, run, "a worker process died (out of memory or killed?); rerun to retry")
                on_done(run, {"status": "crashed"})
                continue
            except Exception as exc:  # pickling or other infrastructure failure
                write_crashed(out, run, f"{type(exc).__name__}: {exc}")
                on_done(run, {"status": "crashed"})
                continue
            write_run(out, payload)
            on_done(run, payload)
    except BaseException:
        for f in futs:
            f.cancel()
        pool.shutdown(wait=False, cancel_futures=True)
        _terminate_pool(pool)
        raise
    pool.shutdown(wait=True)


def _terminate_pool(pool) -> None:
    """Stop our own worker processes at once (Ctrl-C, SIGTERM): only the pool's processes, by id;
    then the forkserver that started them, if this driver started one."""
    procs = getattr(pool, "_processes", None) or {}
    for p in list(procs.values()):
        try:
            p.terminate()
        except Exception:
            pass
    for p in list(procs.values()):
        try:
            p.join(timeout=2.0)
        except Exception:
            pass
    try:
        from multiprocessing import forkserver

        pid = getattr(forkserver._forkserver, "_forkserver_pid", None)
        if pid:
            os.kill(pid, signal.SIGTERM)
    except (ImportError, AttributeError, ProcessLookupError, PermissionError):
        pass


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP reached the sweep driver: it stops as on Ctrl-C (workers terminated,
    finished runs kept)."""


def _on_terminate(signum, frame):
    raise Terminated(signal.Signals(signum).name)


#: seconds to wait for a Dask scheduler to answer (--dask ADDRESS) before the sweep is refused: a
#: port that accepts connections and never answers (not a scheduler) used to hang the sweep
DASK_CONNECT_TIMEOUT_S = 15.0
#: the address schemes a remote Dask scheduler listens on
DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")


def check_dask_address(address: str | None) -> None:
    """Refuse (SweepError naming --dask) an address that is neither ``local`` nor
    ``[SCHEME://]HOST:PORT`` with a scheme of DASK_SCHEMES and a port from 1 to 65535, before
    anything runs (``nonsense``, ``http://...``, ``tcp://[::1`` gave tracebacks)."""
    if address is None or address == "local":
        return
    hint = "give 'local' or a scheduler address tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)"
    try:
        from distributed.comm.addressing import parse_address, parse_host_port

        scheme, loc = parse_address(str(address), strict=False)
        host, port = parse_host_port(loc)
    except ImportError:
        raise SweepError("--dask: Dask is not installed (pip install 'dask[distributed]')") from None
    except (ValueError, TypeError) as exc:
        raise SweepError(f"--dask {address}: not a scheduler address ({exc}); {hint}") from None
    if scheme not in DASK_SCHEMES:
        raise SweepError(f"--dask {address}: unknown scheme '{scheme}' (a Dask scheduler speaks "
                         f"{', '.join(DASK_SCHEMES)}); {hint}")
    if not host or not isinstance(port, int) or not 1 <= port <= 65535:
        raise SweepError(f"--dask {address}: needs a host and a port from 1 to 65535; {hint}")


def _reach_scheduler(address: str, timeout: float = None) -> None:
    """Open (and close) a Dask connection to ``address`` within ``timeout`` seconds
    (DASK_CONNECT_TIMEOUT_S), handshake included: a port that accepts and never answers is
    refused with SweepError instead of hanging the sweep."""
    import asyncio

    from distributed.comm import connect

    timeout = DASK_CONNECT_TIMEOUT_S if timeout is None else timeout

    async def probe():
        # Dask's own timeout (it retries a refused connection) ends first and says why; the outer
        # one ends a connection accepted but never answered, where Dask's handshake waits on
        comm = await connect(address, timeout=0.8 * timeout)
        await comm.close()

    try:
        asyncio.run(asyncio.wait_for(probe(), timeout))
    except (asyncio.TimeoutError, TimeoutError):
        raise SweepError(f"--dask {address}: no Dask scheduler answered within {timeout:g} s (is it one? "
                         f"start it with dask scheduler, or use --dask local)") from None
    except Exception as exc:  # refused, unknown host, a handshake that failed, ...
        why = str(exc) if isinstance(exc, OSError) and str(exc) else f"{type(exc).__name__}: {exc}"
        raise SweepError(f"--dask {address}: cannot reach the Dask scheduler ({why}); "
                         f"start it (dask scheduler) or use --dask local") from None


def _run_dask(todo, sweep, out, workers, address, on_done, on_warm):
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=50)
        client = Client(cluster)
    else:
        _reach_scheduler(address)
        try:
            client = Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S:g}s")
        except (OSError, TimeoutError, ValueError) as exc:  # not a write failure: name the scheduler
            raise SweepError(f"--dask {address}: cannot reach the Dask scheduler ({exc}); start it "
                             f"(dask scheduler) or use --dask local") from None
    try:
        for t in _warm_tasks(todo, sweep):
            on_warm(client.submit(warm_cache, t, pure=False).result())
        futs = {}
        for r in todo:
            f = client.submit(run_one, _task(r, sweep), key=f"clothsim-{r.run_id}-{os.getpid()}-{time.time_ns()}",
                              pure=False)
            futs[f.key] = (f, r)
        for f in as_completed([f for f, _ in futs.values()]):
            run = futs[f.key][1]
            try:
                payload = f.result()
            except Exception as exc:  # KilledWorker, lost connection, ...
                write_crashed(out, run, f"{type(exc).__name__}: {exc}; rerun to retry")
                on_done(run, {"status": "crashed"})
                f.release()
                continue
            f.release()
            write_run(out, payload)
            on_done(run, payload)
    finally:
        try:
            client.close()
        finally:
            if cluster is not None:
                cluster.close()


# ----------------------------------------------------------------------------- the command


def run_sweep(path: str | Path, out: str | Path, *, workers: int | None = None, dask: str | None = None,
              force: bool = False, skip_errors: bool = False, stream=sys.stderr, plots: bool = True) -> dict:
    """Validate, run (what is not finished) and summarize a sweep. Returns a report dict:
    total, ran, skipped, not_converged, statuses, numba_compiled, numba_cache_hits, seconds.

    Runs that ended in status ``error`` are retried unless skip_errors; force reruns all. The
    output folder is locked while the sweep runs (see _FolderLock). Raises SweepError for bad
    input (nothing has run then), a folder in use by another sweep, a folder that cannot be
    written or a full disk (the message says which; finished runs are kept)."""
    from .fileio import OutputError, check_free_space, check_out_dir, describe_write_error

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

            from .plottext import failure

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
