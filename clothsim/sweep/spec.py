"""The sweep file (pydantic), its expansion into runs and their validation before anything runs."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Union

import numpy as np
from pydantic import ConfigDict, Field, ValidationError, field_validator, model_validator

from ..compression.fit import FitError, check_fit, parse_target, parse_vary
from ..config import SceneError, apply_overrides, format_validation_error, read_yaml, scene_from_dict
from ..mold import MoldError, check_mold
from ..records import (FIT_FIELDS, OUTPUT_FIELDS, PROBE_SUFFIXES, SUMMARY_FIELDS, TIMING_KEYS,  # noqa: F401
                       WORKER_FIELDS, split_named)
from ..strict import Strict, positive_finite

#: summary.json keys a sweep can tabulate and plot (the field list, clothsim.records.SUMMARY_FIELDS)
SUMMARY_KEYS = tuple(f.key for f in SUMMARY_FIELDS)
#: outputs the sweep worker computes beside the summary (stored in sweep_run.json)
EXTRA_KEYS = {f.key: f.doc for f in WORKER_FIELDS}
#: outputs read from a scene's probes (summary.json "probes"): ``probe:NAME_<suffix>`` -> the reading's key
PROBE_OUTPUTS = dict(PROBE_SUFFIXES)
#: outputs of a fitting sweep: the fit's own (fit:PATH is the fitted value of a varied field)
FIT_OUTPUTS = {f.key: f.doc for f in FIT_FIELDS}
DEFAULT_OUTPUTS = ["iterations", "residual", "energy", "wall_time_s"]


def _probe_output(name: str) -> bool:
    """True for ``probe:NAME_SUFFIX`` (SUFFIX one of PROBE_OUTPUTS: mmhg, pa, contact_fraction, ...)."""
    named = split_named(name)
    return named is not None and named[0] == "probe"


class SweepError(ValueError):
    """A sweep file or one of its runs is invalid; str is the user-facing message."""


class _ByName(Strict):
    """clothsim.strict's base (unknown fields refused) that also takes a field by its name where
    it has an alias (``set`` / ``fixed``)."""
    model_config = ConfigDict(populate_by_name=True)


#: the most runs one sweep expands to (a grid's product of counts); more is refused up front
MAX_RUNS = 100_000


class Space(_ByName):
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
        if self.linspace is not None:
            a, b, n = self.linspace
            v = np.linspace(a, b, n)
        else:
            a, b, n = self.logspace
            v = np.geomspace(a, b, n)
        # 12 significant digits: 1.15 rather than 1.1500000000000001 in ids, tables and scenes
        return [float(f"{x:.12g}") for x in v]


class SweepBlock(_ByName):
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


def _parses(v: list[str], parse, flag: str) -> list[str]:
    """``v`` if ``parse`` (the fit command's reader of --vary or --target) reads each item, else
    its FitError as a ValueError, without the command's ``flag``."""
    try:
        for x in v:
            parse(x)
    except FitError as exc:
        raise ValueError(str(exc).replace(flag, "")) from None
    return v


class FitBlock(_ByName):
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

    _vary = field_validator("vary")(classmethod(lambda cls, v: _parses(v, parse_vary, "--vary ")))
    _target = field_validator("target")(classmethod(lambda cls, v: _parses(v, parse_target, "--target ")))
    _tol = field_validator("tol_mmhg")(classmethod(lambda cls, v: positive_finite(v)))

    def parsed(self):
        """(list of Vary, list of Target)."""
        return [parse_vary(x) for x in self.vary], [parse_target(x) for x in self.target]


def _fit_output(name: str) -> bool:
    return name.startswith("fit:") and len(name) > 4


class SweepFile(_ByName):
    """A sweep: base scene (path relative to the sweep file), fixed overrides (``set``), the
    parameters to vary, an optional ``fit`` (each run an inverse sizing, see FitBlock) and the
    outputs to tabulate and plot (the field list of clothsim.records: summary.json's fields, the
    friction report's friction.KEY, a stage's stage:NAME.KEY, a probe's probe:NAME_SUFFIX, the
    worker's max_z_m, min_z_m, run_time_s; with ``fit``: fit:PATH, the fitted value of a varied
    field, fit_converged and fit_solves) and the outputs to plot (``plots``; default: the numeric
    outputs but the timings, BOOKKEEPING)."""

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
        for name in v:
            if name not in OUTPUT_FIELDS and split_named(name) is None and not _fit_output(name):
                raise ValueError(f"unknown output '{name}' (known: {', '.join(sorted(OUTPUT_FIELDS))}, "
                                 f"probe:NAME_{'/_'.join(PROBE_OUTPUTS)}, stage:NAME.KEY, or fit:FIELD; "
                                 f"docs/guide/sweeps.md lists them)")
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
    """The first ``probe:NAME_SUFFIX`` (``stage:NAME.KEY``) output whose NAME is not a probe (a
    stage) of the scene (the message), or None: such a column stayed empty in every run, with no
    word."""
    probes = [p.name for p in scene.probes]
    # a stage without a name is "stage N" (clothsim.simulation)
    stages = [st.name or f"stage {n + 1}" for n, st in enumerate(scene.stages)]
    for o in outputs:
        named = split_named(o)
        if named is None:
            continue
        kind, name, _ = named
        names = probes if kind == "probe" else stages
        if name not in names:
            return (f"outputs: {o}: the scene has no {kind} '{name}' "
                    f"({kind}s: {', '.join(names) if names else 'none'})")
    return None


def _check_fit(sweep: Sweep, run: Run) -> str | None:
    """A fitting sweep's run: its targets name probes of its scene and its varied fields hold
    numbers (the message, or None)."""
    varies, targets = sweep.spec.fit.parsed()
    try:
        check_fit(run.scene, sweep.base_path, varies, targets)
    except (FitError, SceneError) as exc:
        return "fit: " + str(exc).replace("--target ", "target ").replace("--vary ", "vary ")
    return None
