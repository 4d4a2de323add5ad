"""Inverse sizing: the value of scene fields that gives target probe pressures.

``python app.py fit SCENE --vary FIELD[=LO:HI] --target "PROBE=20mmHg"`` varies any field a
``--set`` path reaches (a panel width ``fabric.size.0``, a stretch, a material ``scale``) until
the probe reads the target. A field the scene file omits starts from the schema's default
(``fabric.warp.scale`` 1, ``solver.C`` 2); integer fields (counts) cannot be varied. A target
may name one of the scene's measuring levels instead of a probe (``--target B=27.5mmHg``, see
:func:`level_names`): it reads that level's girth mean (clothsim.compression.levels), the
standard's reading; a probe of the same name wins.

- **One field, one target**: secant steps on residual(x) = reading(x) - target, kept inside the
  bracket once the residual changes sign (Illinois regula falsi, the secant's safeguarded form;
  a value it proposes again, where the reading is not monotonic inside the bracket, is replaced
  by the bracket's middle: solves are deterministic), and inside [LO, HI] (default: the start
  value +-30 %). A step that would leave [LO, HI] tries the bound; if the residual keeps its sign
  there the target is out of reach and the fit is refused with the reachable range (the readings
  at both bounds).
- **Several fields / targets**: least squares (scipy.optimize.least_squares, trust-region
  reflective with the bounds, forward differences), each residual a solve; it stops at the first
  solve (a step or a difference) whose readings all meet their targets within the tolerance.

Every solve after the first starts from the previous equilibrium (its free coordinates), so the
contact set and the seam are already in place; a solve typically takes a few Newton steps. A
scene solved along a loading path (stages, friction, ``solver.load_steps`` > 1) is the exception:
its answer is the path's from the scene's start, and a path begun at another equilibrium can end
elsewhere (the sewn sleeve drawn on at 1.1 and relaxed with mu 0.4, 20 x 8, at 0.235 m: 18.47
mmHg from the 0.25 m equilibrium, 18.07 from its start), so each of its solves runs every stage
from the scene's own start, as ``run`` does. A fit reached from a warm start is then solved once
more from the scene's own start (what ``run fitted.yaml`` does): where the equilibrium is not
unique (a stocking's slack courses) the two can differ, and the search goes on from fresh starts
until that reading meets the tolerance too, so the fitted run and its files are the ones a rerun
reproduces (fit.csv's ``start`` column).

Limitations: the reading must depend continuously on the field (an integer field such as
``fabric.divisions`` is refused; a try whose scene has another node count than the previous one,
as a panel's rows gain or lose nodes under a reduction per level, is solved from the scene's own
start); the single-field search assumes the reading is monotonic between LO and HI (the
reachable range it reports is the range between the readings at the bounds).
"""

from __future__ import annotations

import copy
import csv
import io
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml
from pydantic import BaseModel

from .. import simulation
from ..compile import design_outlines
from ..config import SceneError, apply_overrides, read_yaml, scene_from_dict
from ..labels import field_unit
from ..mold import mold_query_many
from ..results import RESULT_FILES, atomic_write_bytes
from ..sizing import default_for, sizing_table, table_lines
from ..sizingspec import GarmentSpec
from . import MMHG
from .folder import runnable_scene
from .levels import LevelError

if TYPE_CHECKING:
    from ..results import Result


class FitError(ValueError):
    """A fit that cannot run or cannot reach its target (message says why). ``tries``: the
    solves spent before it was refused (empty for bad input)."""

    def __init__(self, message: str, tries: list | None = None):
        super().__init__(message)
        self.tries = list(tries or [])


class FitInterrupted(Exception):
    """A signal (``name``: SIGINT, SIGTERM) stopped the fit: ``tries`` are the solves that
    finished before it (a solve the signal cut short is not among them)."""

    def __init__(self, name: str, tries: list):
        super().__init__(f"interrupted ({name}) after {len(tries)} finished solve{'s' if len(tries) != 1 else ''}")
        self.name = name
        self.tries = list(tries)


@dataclass
class Vary:
    """A field to vary: its ``--set`` path and bounds (None: the start value +-30 %)."""

    path: str
    lo: float | None = None
    hi: float | None = None


@dataclass
class Target:
    """A probe's target reading [mmHg]."""

    probe: str
    mmhg: float


@dataclass
class Try:
    values: list[float]
    readings_mmhg: list[float]
    residuals_mmhg: list[float]
    time_s: float
    status: str
    start: str = "fresh"  # "warm": from the previous try's equilibrium; "fresh": the scene's own start


@dataclass
class FitResult:
    converged: bool
    message: str
    values: list[float]
    readings_mmhg: list[float]
    tries: list[Try] = field(default_factory=list)
    scene_dict: dict | None = None
    result: Result | None = None  # the clothsim Result at the fitted values

    def tries_csv(self, varies: list[Vary], targets: list[Target]) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["try", *[v.path for v in varies], *[f"{t.probe}_mmHg" for t in targets],
                    *[f"{t.probe}_residual_mmHg" for t in targets], "time_s", "status", "start"])
        for k, t in enumerate(self.tries, 1):
            w.writerow([k, *[f"{x:.10g}" for x in t.values], *[f"{p:.6f}" for p in t.readings_mmhg],
                        *[f"{r:+.6f}" for r in t.residuals_mmhg], f"{t.time_s:.3f}", t.status, t.start])
        return buf.getvalue()


_UNITS = {"mmhg": 1.0, "pa": 1.0 / MMHG, "kpa": 1000.0 / MMHG}


def parse_target(text: str) -> Target:
    """'ankle=20mmHg', 'ankle=2666Pa', 'ankle=2.7kPa' or 'ankle=20' (mmHg) -> Target."""
    m = re.fullmatch(r"\s*([^=\s]+)\s*=\s*([-+0-9.eE]+)\s*([A-Za-z]*)\s*", text)
    if not m:
        raise FitError(f"--target {text}: expected PROBE=VALUE[mmHg|Pa|kPa], e.g. ankle=20mmHg")
    unit = (m.group(3) or "mmHg").lower()
    if unit not in _UNITS:
        raise FitError(f"--target {text}: unknown unit '{m.group(3)}' (mmHg, Pa or kPa)")
    try:
        v = float(m.group(2))
    except ValueError:
        raise FitError(f"--target {text}: '{m.group(2)}' is not a number") from None
    if not math.isfinite(v) or v < 0:
        raise FitError(f"--target {text}: the pressure must be finite and not negative")
    return Target(m.group(1), v * _UNITS[unit])


def parse_vary(text: str) -> Vary:
    """'fabric.size.0' or 'fabric.size.0=0.2:0.3' -> Vary (bounds the scene cannot take are
    refused before the first solve, see :func:`_check_bounds`)."""
    if "=" not in text:
        return Vary(text.strip())
    path, rng = text.split("=", 1)
    try:
        lo, hi = (float(x) for x in rng.split(":"))
    except ValueError:
        raise FitError(f"--vary {text}: expected FIELD or FIELD=LO:HI, e.g. fabric.size.0=0.2:0.3") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise FitError(f"--vary {text}: need finite LO < HI")
    return Vary(path.strip(), lo, hi)


#: fields the schema leaves None when omitted, with the value an omitted field means (their
#: docstrings say so): a fit may vary them from that value without a --set
OMITTED_MEANS = {("MaterialSpec", "scale"): 1.0, ("MeshMoldSpec", "scale"): 1.0}


def _raw_value(data, path: str):
    """The value at ``path`` in the raw scene dict, or a KeyError naming the first missing part
    (an IndexError-free walk: a bad list index is a FitError)."""
    node = data
    for part in path.split("."):
        if isinstance(node, list):
            try:
                node = node[int(part)]
            except (ValueError, IndexError):
                raise FitError(f"--vary {path}: '{part}' is not an index of a {len(node)}-item list") from None
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise KeyError(part)
    return node


def _schema_value(scene, path: str):
    """(value, owner class name, field name) at ``path`` in the validated scene: a field the file
    omits holds its default. Raises FitError when the schema has no such field."""
    node, owner, name = scene, None, None
    done: list[str] = []
    for part in path.split("."):
        where = ".".join(done) or "the scene"
        if isinstance(node, BaseModel):
            fields = type(node).model_fields
            key = next((k for k, f in fields.items() if part in (k, f.alias)), None)
            if key is None:
                known = ", ".join(sorted(f.alias or k for k, f in fields.items()))
                raise FitError(f"--vary {path}: {where} has no field '{part}' (its fields: {known})")
            owner, name, node = type(node).__name__, key, getattr(node, key)
        elif isinstance(node, (list, tuple)):
            try:
                node = node[int(part)]
            except (ValueError, IndexError):
                raise FitError(f"--vary {path}: '{part}' is not an index of {where}, a {len(node)}-item list") from None
            owner = name = None
        elif node is None and _omitted_block(owner, name) is not None:
            # an omitted block whose fields all have defaults (garment: scale.width is 1)
            node = _omitted_block(owner, name)
            fields = type(node).model_fields
            key = next((k for k, f in fields.items() if part in (k, f.alias)), None)
            if key is None:
                known = ", ".join(sorted(f.alias or k for k, f in fields.items()))
                raise FitError(f"--vary {path}: {where} has no field '{part}' (its fields: {known})")
            owner, name, node = type(node).__name__, key, getattr(node, key)
        elif node is None:
            raise FitError(f"--vary {path}: {where} is not set in the scene and has no default; give it with "
                           f"--set (e.g. --set {'.'.join(done)}=...)")
        else:
            raise FitError(f"--vary {path}: {where} holds {node!r}, which has no field '{part}'")
        done.append(part)
    return node, owner, name


def _omitted_block(owner, name):
    """The default of an omitted scene block a fit may vary fields of (``garment``: its scale
    is the design's, 1), or None."""
    if (owner, name) == ("Scene", "garment"):

        return GarmentSpec()
    return None


def start_value(data: dict, path: str, scene=None) -> float:
    """The start value of a varied field: the scene file's value, or, for a field the file omits,
    the schema's default (``solver.C`` 2.0, ``fabric.warp.scale`` 1, see OMITTED_MEANS). Refused
    (FitError): a path the schema does not define, a field that is not a number, an integer field
    (a count: ``fabric.divisions``, ``solver.max_iterations``; a fit varies a continuous value),
    and an omitted field with no default value (give it with --set first). ``scene``: the
    validated scene of ``data`` (it tells the field's type)."""
    if scene is None:
        scene = scene_from_dict(copy.deepcopy(data))
    if scene.panels and path.split(".")[:2] == ["fabric", "size"]:
        raise FitError(f"--vary {path}: a garment of panels has no fabric.size (each panel has its outline): vary "
                       f"garment.scale.width (the panels' width over the design's) or garment.reduction (% of "
                       f"the body's girth at garment.levels)")
    value, owner, name = _schema_value(scene, path)
    if value is None and (owner, name) in OMITTED_MEANS:
        value = OMITTED_MEANS[(owner, name)]
    if value is None and path == "garment.reduction":

        value = default_for(path, scene, *design_outlines(scene))  # the design pattern's own reduction at the first level
    if value is None:
        raise FitError(f"--vary {path}: the field is not set and has no default value; give its start value "
                       f"with --set {path}=VALUE")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FitError(f"--vary {path}: the field holds {value!r}, not a number")
    if isinstance(value, int):
        raise FitError(f"--vary {path}: the field holds an integer ({value}): a fit varies a continuous value")
    try:
        raw = _raw_value(data, path)
    except KeyError:
        return float(value)  # omitted in the file: the schema's default
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise FitError(f"--vary {path}: the field holds {raw!r}, not a number")
    return float(raw)


def warm_start(model, state, positions: np.ndarray, rounds: int = 8) -> None:
    """Start ``state`` from an earlier equilibrium's ``positions`` (N, 3) [m]: its free
    coordinates are taken over, the held ones stay prescribed. A node held on some axes whose
    prescribed coordinate moved (e.g. a column held in x that the new scene places elsewhere) can
    land inside the mold; such nodes are moved back to the surface (closest point, held
    coordinates reset, repeated ``rounds`` times), so the start does not penetrate."""
    fixed = model.fixed_axes
    free = ~fixed
    state.positions[free] = positions[free]
    if model.mold is None:
        return

    margs = model.mold.kernel_args()
    for _ in range(rounds):
        n = model.node_count
        sd, cp, nrm = np.empty(n), np.empty((n, 3)), np.empty((n, 3))
        mold_query_many(margs, state.positions, sd, cp, nrm, np.empty((n, 2), np.int64))
        bad = sd < 0.0
        if not bad.any():
            return
        state.positions[bad] = cp[bad]
        state.positions[fixed] = model.prescribed_positions[fixed]


class _Solver:
    """Solves the scene at given field values, warm-starting from the previous equilibrium."""

    def __init__(self, data: dict, source: Path | None, varies: list[Vary], targets: list[Target], log=None,
                 stop: list | None = None):
        self.data, self.source, self.varies, self.targets = data, source, varies, targets
        self.stop = stop if stop is not None else []  # a signal's name once one asked the fit to stop
        self.prev = None
        self.warm = False
        self.fresh = False  # True: every solve from the scene's own start (no warm start)
        self.tries: list[Try] = []
        self.results: list = []
        self.log = log

    def scene_dict(self, x) -> dict:
        return apply_overrides(self.data, {v.path: float(xi) for v, xi in zip(self.varies, x)})

    def __call__(self, x) -> np.ndarray:
        if self.stop:
            raise FitInterrupted(self.stop[0], self.tries)
        t0 = time.perf_counter()
        # a value the scene refuses names the --vary that set it, not the scene file
        blame = {v.path: f"--vary {v.path} (at {float(xi):.8g})" for v, xi in zip(self.varies, x)}
        scene = scene_from_dict(self.scene_dict(x), self.source, None, blame)
        # a signal stops the solve at its next iteration; that try is dropped (not an equilibrium)
        sim = simulation.Simulation(scene, callback=lambda prog: bool(self.stop))
        # a loading path (stages, friction, load steps) is replayed from the scene's own start; a
        # field that changes the node count (a panel's row lengths under a reduction per level:
        # its rows gain or lose nodes) cannot start from the previous equilibrium either: such a
        # try is solved from the scene's own start
        warm = (self.prev is not None and not self.fresh and not sim.solved_along_a_path()
                and self.prev.positions.shape == sim.state.positions.shape)
        if warm:
            warm_start(sim.model, sim.state, self.prev.positions)
        if not self.warm:
            simulation.warm_up(sim.model, sim.state, sim.settings)
            self.warm = True
        sim.run()
        if self.stop:
            raise FitInterrupted(self.stop[0], self.tries)
        res = sim.result()
        # the targets' readings alone (Result.read: a probe's pressure, a level's girth mean), by the
        # code the full readings use; those (every probe, every level's side sensors) are computed
        # once, for the fitted result, when it is written
        try:
            readings = res.read([t.probe for t in self.targets])
        except LevelError as e:
            raise FitError(f"--target {self.targets[0].probe}: no reading there (its levels could not be read: "
                           f"{e})") from None
        # no contact round a level reads 0 mmHg, so a garment too loose to touch the body there is
        # tightened, not refused
        readings = {k: 0.0 if v is None else v for k, v in readings.items()}
        p = [readings[t.probe] for t in self.targets]
        r = [pi - t.mmhg for pi, t in zip(p, self.targets)]
        self.prev = res.state
        t = Try([float(xi) for xi in x], p, r, time.perf_counter() - t0, res.solve.status,
                "warm" if warm else "fresh")
        self.tries.append(t)
        self.results.append(res)
        if self.log is not None:
            self.log(t)
        return np.asarray(r)


def fit(scene_path: str | Path, varies: list[Vary], targets: list[Target], *, overrides: list[str] | None = None,
        tol_mmhg: float = 0.1, max_solves: int = 12, log=None, stop: list | None = None) -> FitResult:
    """Find field values whose probe readings meet the targets within ``tol_mmhg`` (see the module
    docstring). Raises FitError on bad input or an unreachable target (with the reachable range),
    FitInterrupted (with the finished tries) once ``stop`` (a list a signal handler appends to)
    is not empty."""
    scene_path = Path(scene_path)
    data, _ = read_yaml(scene_path)
    data = apply_overrides(data, overrides or [])
    return fit_data(data, scene_path, varies, targets, tol_mmhg=tol_mmhg, max_solves=max_solves, log=log, stop=stop)


def level_names(scene) -> list[str]:
    """The names of the scene's measuring levels a target may name (their girth mean): a chart
    leg's levels, ``levels.find`` (default B, C, D) on a scan, and ``levels.heights``."""
    spec = getattr(scene, "levels", None)
    leg = getattr(getattr(scene, "mold", None), "leg", None)
    out = list(leg.levels) if leg is not None else []
    if spec is not None:
        if leg is None:
            out += list(spec.find) if spec.find is not None else ["B", "C", "D"]
        out += [k for k in spec.heights if k not in out]
    return out


def check_fit(data: dict, source: Path | None, varies: list[Vary], targets: list[Target]) -> list[float]:
    """Check a fit before any solve: the scene validates, every target names one of its probes
    (once), every varied path (given once) is a continuous number of the scene or of its schema
    (see :func:`start_value`) and the scene takes both its bounds (:func:`_check_bounds`; a sweep
    checks every run's fit so before anything runs). Returns the start values; raises FitError
    (or SceneError)."""
    if not varies or not targets:
        raise FitError("fit needs at least one --vary and one --target")
    for what, names in (("--vary", [v.path for v in varies]), ("--target", [t.probe for t in targets])):
        for n, name in enumerate(names):
            if name in names[:n]:
                raise FitError(f"{what} {name}: given twice")
    scene = scene_from_dict(copy.deepcopy(data), source)
    names = [p.name for p in scene.probes]
    levels = [k for k in level_names(scene) if k not in names]
    for t in targets:
        if t.probe not in names and t.probe not in levels:
            more = f"; measuring levels (their girth mean): {', '.join(levels)}" if levels else ""
            raise FitError(f"--target {t.probe}: the scene has no probe '{t.probe}' "
                           f"(probes: {', '.join(names) or 'none; add probes: [{name, point, radius}]'}{more})")
    x0 = [start_value(data, v.path, scene) for v in varies]
    lo, hi = _bounds(varies, x0)
    _check_bounds(data, source, varies, [min(max(x, a), b) for x, a, b in zip(x0, lo, hi)], lo, hi)
    return x0


def _bounds(varies: list[Vary], x0: list[float]) -> tuple[list[float], list[float]]:
    """(LO, HI) of each varied field: the --vary bounds, else the start value +-30 %."""
    lo = [v.lo if v.lo is not None else x - 0.3 * abs(x) for v, x in zip(varies, x0)]
    hi = [v.hi if v.hi is not None else x + 0.3 * abs(x) for v, x in zip(varies, x0)]
    for v, x, a, b in zip(varies, x0, lo, hi):
        if not a < b:
            raise FitError(f"--vary {v.path}: give bounds (FIELD=LO:HI): the start value is {x}")
    return lo, hi


def fit_data(data: dict, source: Path | None, varies: list[Vary], targets: list[Target], *,
             tol_mmhg: float = 0.1, max_solves: int = 12, log=None, stop: list | None = None) -> FitResult:
    """:func:`fit` on a raw scene dict (as in the YAML; ``source``: the file its relative paths
    resolve against). The sweep runner calls this for each run of a sweep with a ``fit:`` block."""
    if isinstance(tol_mmhg, bool) or not (isinstance(tol_mmhg, (int, float)) and math.isfinite(tol_mmhg)
                                          and tol_mmhg > 0):
        raise FitError(f"tol_mmhg: must be a positive finite number (got {tol_mmhg!r})")
    if isinstance(max_solves, bool) or not isinstance(max_solves, int) or max_solves < 1:
        raise FitError(f"max_solves: must be an integer, at least 1 (got {max_solves!r})")
    x0 = check_fit(data, source, varies, targets)
    scene_path = source
    lo, hi = _bounds(varies, x0)
    x0 = [min(max(x, a), b) for x, a, b in zip(x0, lo, hi)]
    f = _Solver(data, scene_path, varies, targets, log, stop)

    def search(x, budget):
        if len(varies) == 1 and len(targets) == 1:
            return _secant(f, x[0], lo[0], hi[0], tol_mmhg, budget, varies[0], targets[0])
        return _least_squares(f, x, lo, hi, tol_mmhg, budget)

    def best(first):
        return first + int(np.argmin([np.abs(t.residuals_mmhg).max() for t in f.tries[first:]]))

    out = search(x0, max_solves)
    first = 0
    if out.converged and f.tries[best(0)].start == "warm":
        # reached from a warm start: where slack courses leave the equilibrium not unique, the
        # scene's own start (what `run fitted.yaml` does) can land on another state and read
        # differently (0.15 mmHg on the stocking). Solve the fitted values from the scene's own
        # start, and go on from fresh starts when that misses the tolerance: the fitted run and
        # its files are then the ones a rerun reproduces
        warm, warm_msg = out, out.message
        left = max_solves - len(f.tries)  # --max-solves bounds the whole fit, the check included
        if left < 1:
            warm.message = (f"{warm_msg} from warm starts; not checked from the scene's own start "
                            f"(--max-solves spent: raise it to check)")
        else:
            first = len(f.tries)
            f.fresh = True
            try:
                out = search(out.values, left)
                worst = float(np.abs(f.tries[best(first)].residuals_mmhg).max())
                n = len(f.tries) - first
                out.message = (f"|residual| {worst:.3g} <= {tol_mmhg} mmHg from the scene's own start (the fitted "
                               f"run; checked in {n} fresh solve{'s' if n > 1 else ''} after warm starts: {warm_msg})"
                               if out.converged else
                               f"from the scene's own start, {out.message} (warm starts first: {warm_msg})")
            except FitError as exc:  # the fresh readings' bracket failed: keep the warm fit, say so
                out, first = warm, 0
                out.message = f"{warm_msg} from warm starts; the check from the scene's own start failed: {exc}"
    out.tries = f.tries
    if out.converged or out.values:
        # the result at the best try (the last one for a converged secant) of the last search
        k = best(first)
        out.values = f.tries[k].values
        out.readings_mmhg = f.tries[k].readings_mmhg
        out.result = f.results[k]
        out.scene_dict = f.scene_dict(out.values)
    return out


def _check_bounds(data: dict, source: Path | None, varies: list[Vary], x0, lo, hi) -> None:
    """Refuse, before any solve, a bound the scene cannot take (a negative width, a width over
    the 1e6 m bound), naming the --vary that gave it: each bound is validated with the other
    fields at their start values."""
    for n, v in enumerate(varies):
        for which, b in (("lower", lo[n]), ("upper", hi[n])):
            x = list(x0)
            x[n] = b
            given = f"{v.path}={v.lo:.8g}:{v.hi:.8g}" if v.lo is not None else f"{v.path} (default bounds +-30 %)"
            label = f"--vary {given}: its {which} bound {b:.8g}"
            try:
                scene_from_dict(apply_overrides(data, {u.path: float(xi) for u, xi in zip(varies, x)}), source,
                                None, {v.path: label})
            except SceneError as exc:
                msg = str(exc)
                if label not in msg:  # the bound broke another field (a derived check): say which bound
                    msg = f"{label}: {msg}"
                raise FitError(msg) from None


def _secant(f: _Solver, x0: float, lo: float, hi: float, tol: float, max_solves: int, vary: Vary,
            target: Target) -> FitResult:
    pts: list[tuple[float, float]] = []  # (x, residual)

    def ev(x):
        r = float(f([x])[0])
        pts.append((x, r))
        return r

    def done(r):
        return abs(r) <= tol

    def unreachable():
        # readings at both bounds give the reachable range
        for b in (lo, hi):
            if not any(abs(x - b) <= 1e-12 * max(1.0, abs(b)) for x, _ in pts):
                ev(b)
        rb = {x: r for x, r in pts}
        p_lo = rb[min(rb, key=lambda x: abs(x - lo))] + target.mmhg
        p_hi = rb[min(rb, key=lambda x: abs(x - hi))] + target.mmhg
        a, b = sorted((p_lo, p_hi))
        # a try between the bounds that read outside their range: the reading is not monotonic
        # (a sleeve cut too narrow slides off the form and reads 0 at the lower bound)
        xo, ro = max(pts, key=lambda p: max(p[1] + target.mmhg - b, a - p[1] - target.mmhg))
        po = ro + target.mmhg
        odd = (f"; but {vary.path} = {xo:.6g} read {po:.2f} mmHg, outside that range: the reading is not "
               f"monotonic between the bounds (a garment too narrow for the form slides off it and reads 0): "
               f"narrow them" if max(po - b, a - po) > tol else "")
        raise FitError(f"target {target.probe} = {target.mmhg:.2f} mmHg is out of reach: {vary.path} from {lo:.6g} "
                       f"to {hi:.6g} gives {a:.2f} to {b:.2f} mmHg (reachable range; widen it with "
                       f"--vary {vary.path}=LO:HI){odd}", f.tries)

    r0 = ev(x0)
    if done(r0):
        return FitResult(True, "reached on the first solve", [x0], [r0 + target.mmhg])
    if max_solves < 2:
        return FitResult(False, f"not within {tol} mmHg after 1 solve (residual {r0:+.3g} mmHg at {vary.path} = "
                                f"{x0:.8g}); raise --max-solves", [x0], [r0 + target.mmhg])
    # second point: a small step inside the bounds
    h = 0.01 * (hi - lo)
    x1 = x0 + h if x0 + h <= hi else x0 - h
    r1 = ev(x1)
    bracket = None  # (xa, ra, xb, rb) with ra, rb of opposite signs
    side = 0  # Illinois: which end was kept twice
    while len(pts) < max_solves:
        (xa, ra), (xb, rb) = pts[-2], pts[-1]
        if done(rb):
            return FitResult(True, f"|residual| {abs(rb):.3g} <= {tol} mmHg after {len(pts)} solves", [xb],
                             [rb + target.mmhg])
        # the tightest bracket among all points
        neg = [(x, r) for x, r in pts if r < 0]
        pos = [(x, r) for x, r in pts if r > 0]
        if neg and pos:
            xn, rn = max(neg, key=lambda p: p[1])
            xp, rp = min(pos, key=lambda p: p[1])
            bracket = (xn, rn, xp, rp)
        if bracket is None:
            if rb == ra:
                # flat (e.g. a slack sleeve reads 0): walk toward the bound that should help
                x = hi if abs(hi - xb) > abs(lo - xb) else lo
            else:
                x = xb - rb * (xb - xa) / (rb - ra)
            if x <= lo or x >= hi:
                xbnd = lo if x <= lo else hi
                if any(abs(px - xbnd) <= 1e-12 * max(1.0, abs(xbnd)) for px, _ in pts):
                    unreachable()
                rbnd = ev(xbnd)
                if rbnd * rb > 0 and not done(rbnd):
                    unreachable()
                continue
            ev(x)
            continue
        xn, rn, xp, rp = bracket
        # secant from the last two points if it stays strictly inside the bracket, else Illinois
        x = xb - rb * (xb - xa) / (rb - ra) if rb != ra else math.nan
        a, b = sorted((xn, xp))
        if not (math.isfinite(x) and a < x < b):
            wn, wp = rn, rp
            if side == 1:
                wn *= 0.5
            elif side == 2:
                wp *= 0.5
            x = xn - wn * (xp - xn) / (wp - wn)
            side = 1 if rb > 0 else 2
        if any(abs(x - px) <= 1e-12 * max(1.0, abs(x)) for px, _ in pts):
            # a value already solved (a reading that is not monotonic inside the bracket, as a
            # frictional scene's can be, left the bracket and Illinois' weights as they were):
            # the solve is deterministic, so halve the bracket instead of solving it again
            x = 0.5 * (xn + xp)
        ev(x)
    xb, rb = min(pts, key=lambda p: abs(p[1]))
    if done(rb):
        return FitResult(True, f"|residual| {abs(rb):.3g} <= {tol} mmHg after {len(pts)} solves", [xb],
                         [rb + target.mmhg])
    return FitResult(False, f"not within {tol} mmHg after {len(pts)} solves (best residual {rb:+.3g} mmHg at "
                            f"{vary.path} = {xb:.8g}); raise --max-solves", [xb], [rb + target.mmhg])


def _least_squares(f: _Solver, x0, lo, hi, tol, max_solves) -> FitResult:
    from scipy.optimize import least_squares

    scale = np.asarray(hi) - np.asarray(lo)
    cache: dict = {}
    n0 = len(f.tries)  # the solves before this search

    def fun(x):
        key = tuple(np.round(x, 15))
        if key not in cache:
            if len(f.tries) - n0 >= max_solves:
                raise _Budget()
            cache[key] = f(x)
            if np.abs(cache[key]).max() <= tol:  # every target met: stop, as the secant does
                raise _Met()
        return cache[key]

    class _Budget(Exception):
        pass

    class _Met(Exception):
        pass

    msg = ""
    try:
        sol = least_squares(fun, np.asarray(x0, float), bounds=(lo, hi), x_scale=scale, diff_step=1e-4,
                            method="trf", xtol=1e-10, ftol=1e-10, gtol=1e-12, max_nfev=max_solves)
        msg = sol.message
    except _Budget:
        msg = f"stopped after {max_solves} solves"
    except _Met:
        msg = "every target met"
    best = min(f.tries[n0:], key=lambda t: np.abs(t.residuals_mmhg).max())
    ok = bool(np.abs(best.residuals_mmhg).max() <= tol)
    n = len(f.tries) - n0
    text = (f"all targets within {tol} mmHg after {n} solves" if ok else
            f"best residual {np.abs(best.residuals_mmhg).max():.3g} mmHg after {n} solves ({msg}); "
            + ("raise --max-solves" if msg.startswith("stopped after") else
               "the targets may not be reachable together"))
    return FitResult(ok, text, best.values, best.readings_mmhg)


def write_outputs(res: FitResult, out: str | Path, varies: list[Vary], targets: list[Target]) -> Path:
    """out/fitted.yaml (the scene at the fitted values, with the files it reads copied beside it and
    named without a path: clothsim.compression.folder.runnable_scene), out/fit.csv (the tries), out/fit.json and
    the fitted run's result files (result.npz, summary.json, ...)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if res.result is not None:
        res.result.save(out)
        # the files the scene reads copied beside it, by name: the folder runs wherever it is moved
        text, files = runnable_scene(res.result.scene, "The scene at the fitted values (clothsim fit)",
                                     reserved={*RESULT_FILES, "fitted.yaml", "fit.csv", "fit.json"})
        for name, src in files.items():
            try:
                data = Path(src).read_bytes()
            except OSError as exc:
                raise FitError(f"fitted.yaml: cannot copy {name}, a file the scene reads ({exc.strerror})") from None
            atomic_write_bytes(out / name, data)
        atomic_write_bytes(out / "fitted.yaml", text.encode())
    atomic_write_bytes(out / "fit.csv", res.tries_csv(varies, targets).encode())
    atomic_write_bytes(out / "fit.json", json.dumps(fit_info(res, varies, targets), indent=2).encode())
    return out


def fit_info(res: FitResult, varies: list[Vary], targets: list[Target]) -> dict:
    """What fit.json holds: converged, message, fields {path: value}, units {path: unit},
    targets_mmhg, readings_mmhg {probe: mmHg}, the number of solves and, for a scene with
    measuring levels (``garment.levels``), levels: per level the body's girth, the fitted
    garment's relaxed circumference and its reduction (clothsim.sizing.sizing_table)."""

    info = {"converged": res.converged, "message": res.message,
            "fields": {v.path: x for v, x in zip(varies, res.values)},
            "units": {v.path: field_unit(v.path) for v in varies},
            "targets_mmhg": {t.probe: t.mmhg for t in targets},
            "readings_mmhg": {t.probe: p for t, p in zip(targets, res.readings_mmhg)},
            "solves": len(res.tries)}
    levels = fitted_levels(res)
    if levels:
        info["levels"] = levels
    return info


def fitted_levels(res: FitResult) -> list[dict]:
    """The sizing table (clothsim.sizing.sizing_table) of the fitted scene: [] without levels."""
    if res.result is None or getattr(res.result.scene, "garment", None) is None:
        return []

    scene = res.result.scene
    return sizing_table(scene, *design_outlines(scene), getattr(res.result.model, "mold", None))


def fitted_lines(res: FitResult, varies: list[Vary], targets: list[Target]) -> list[str]:
    """What ``fit`` prints after its verdict: each fitted field with its unit, each probe's
    reading and, with measuring levels, each level's girth, relaxed circumference and reduction."""

    out = []
    for v, x in zip(varies, res.values):
        unit = field_unit(v.path)
        out.append(f"  {v.path} = {x:.10g}" + (f" {unit}" if unit and unit != "-" else
                                                " (a ratio to the design)" if unit == "-" else ""))
    for t, p in zip(targets, res.readings_mmhg):
        out.append(f"  {t.probe}: {p:.3f} mmHg (target {t.mmhg:.3f})")
    return out + table_lines(fitted_levels(res))
