"""Speed-against-error benchmark: every solver on every benchmark scene, a table and a plot.

``python app.py bench [--quick] [--out docs/benchmarks]`` writes ``<out>/benchmarks.md`` (machine, date,
versions, one row per solver and scene) and ``<out>/speed_vs_error.png`` (node-position error
against time, log-log, one curve per solver and scene).

For each (scene, solver) run, in a fresh child process (so that peak memory and JIT compilation
belong to that run alone):
- compile_s: the first call (one iteration) compiles the numba kernels or loads them from the
  on-disk cache; it is timed apart and not counted in the solve times;
- the solve from the scene's initial state to e = 1e-9 N (or the run's time limit): the time
  [s] at which ||V||_inf first fell below each level 1e-2 ... 1e-9 N (from the recorded
  history), iterations, final status and residual;
- peak_rss_mb: the child's peak resident memory (ru_maxrss, includes Python, numba and the
  libraries, about 200 MB);
- the error of the node positions (max norm over nodes [m]) at each level against a reference
  solve taken 1000 times tighter than 1e-9 N (newton, e = 1e-12 N), or to its float64 floor
  (its own residual is reported). For paper, positions are captured at the end of the batch
  in which the level was crossed (a little later, so if anything its errors look smaller).
The paper solver is capped by a time limit (its sweep count grows with the square of the grid's
side); levels it did not reach are reported as "not reached".

Work units. Wall-clock seconds on a shared machine swing 2x from run to run, so every time is also
reported in work units (WU): the time divided by the time of one *reference pass* over the same
scene's springs, measured in the same process before and after the solve (their mean: the
machine's speed drifts within a minute) (``reference_pass``: a plain numba loop in this
file that uses no clothsim kernel; per spring: the length, the lookup of the strain in the
spring's piecewise-linear table, the force on both nodes and the energy). Both are measured in
process CPU time (``time.process_time``), so time lost to other jobs on the machine counts in
neither: a level's CPU time is read off the (wall time, CPU time) pairs recorded at each callback
of the run, interpolated at the level's wall time. For the paper solver the cost of one sweep
(CPU time / sweeps) is also given in WU; a sweep visits every node once, so this is the cost per
node in units of a reference pass's cost per node.

The modules, by job: :mod:`.cases` (the scenes and the campaign's settings), :mod:`.report`
(the machine, the markdown tables, the plot); this one measures and runs (``python app.py
bench``; ``python -m clothsim.bench`` too) and re-exports their names. The design notes on the
smooth surface are a page of their own (docs/benchmarks/smooth_newton.md).
"""

from __future__ import annotations

import math
import multiprocessing as mp
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from .. import solvers
from ..config import load_scene
from ..simulation import prepare
from .cases import (GARMENT_REPEAT, LEVELS, PAIR_SOLVES, REFERENCE_E, ROOT, SCAN_BODIES,
                    SCAN_GARMENT_TIME_LIMIT, SCAN_GARMENTS, SCAN_MAX_ITERATIONS, SCAN_TIME_LIMIT,
                    TARGET_E, Case, cases, scan_band_overrides)
from .report import (_fmt_height, _fmt_ms, _fmt_tw, _fmt_wu, write_garment_report, write_report,
                     write_scan_report)

# re-exported: the names the single module had
from .cases import _optional_terms, four_panel_cap_overrides, garment_cases  # noqa: F401
from .report import (SMOOTH_SCAN_NOTES, _fmt_e, _fmt_t, _plot, machine_info, paired_ratios,  # noqa: F401
                     scan_table)


#: where the campaign looks for the body files (the repository's copies, see static/bodies/README.md)
SCAN_DIRS = (ROOT / "static" / "bodies",)


def scan_body_path(stem: str) -> Path | None:
    """The body file ``<stem>.stl`` in the first of ``SCAN_DIRS`` that has it, or None."""
    for d in SCAN_DIRS:
        if (d / f"{stem}.stl").exists():
            return d / f"{stem}.stl"
    return None


def _scan_row(case: Case, body: str, height, surface: str, time_limit: float = SCAN_TIME_LIMIT) -> dict:
    """One campaign run: newton alone to TARGET_E from the case's start (kernels compiled by a
    one-iteration run first); a JSON-able row."""
    model, state, settings = _load(case, "newton", TARGET_E, time_limit, SCAN_MAX_ITERATIONS)
    solvers.solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1, "time_limit_s": None}))
    ref_s = reference_pass_time(model, state.positions)
    c0 = time.process_time()
    res = solvers.solve(model, state, settings)
    cpu = time.process_time() - c0
    return {"body": body, "height": height, "surface": surface, "nodes": int(model.node_count),
            "status": res.status, "iterations": int(res.iterations), "residual": float(res.residual),
            "wall_s": float(res.wall_time_s), "cpu_s": cpu, "ref_pass_s": ref_s,
            "wu": cpu / ref_s, "contact": int(state.in_contact.sum()),
            "ms_per_iteration": 1e3 * cpu / max(res.iterations, 1)}


def run_scan_body(stem: str, heights, surface: str = "faceted") -> list[dict]:
    """The campaign's runs on one body (in one process: the kernels compile once): newton alone
    to e = TARGET_E from each height's wrapped start; returns one JSON-able row per height."""
    path = scan_body_path(stem)
    rows = []
    for h in heights:
        case = Case(f"{stem} y={h:.2f}", "configs/torso_band.yaml", scan_band_overrides(path, h, surface),
                    ("newton",), {"newton": SCAN_TIME_LIMIT}, group="scans")
        rows.append(_scan_row(case, stem, h, surface))
    return rows


def run_scan_garment(name: str, stem: str, config: str, overrides, surface: str) -> list[dict]:
    """One garment of the campaign (``SCAN_GARMENTS``) on the ``surface`` of the body ``stem``:
    one row (height None)."""
    ov = list(overrides) + [f"mold.path={scan_body_path(stem)}", f"mold.surface={surface}"]
    case = Case(name, config, ov, ("newton",), {"newton": SCAN_GARMENT_TIME_LIMIT}, group="scans")
    return [_scan_row(case, name, None, surface, SCAN_GARMENT_TIME_LIMIT)]


def run_scans(surface: str = "faceted", log=None) -> list[dict]:
    """The whole scan campaign (each body and each garment in a child process); bodies whose file
    is missing are skipped with a message."""
    jobs = []
    for stem, heights in SCAN_BODIES:
        if scan_body_path(stem) is None:
            if log:
                log(f"scan campaign: {stem}.stl not found in {', '.join(str(d) for d in SCAN_DIRS)}: skipped")
            continue
        jobs.append((stem, run_scan_body, (stem, heights, surface)))
    for name, stem, config, overrides, surf in SCAN_GARMENTS:
        if scan_body_path(stem) is not None:
            jobs.append((name, run_scan_garment, (name, stem, config, overrides, surf or surface)))
    rows = []
    for label, fn, args in jobs:
        try:
            got = _in_child(fn, *args)
        except Exception as exc:
            if log:
                log(f"scan campaign: {label}: failed: {exc}")
            continue
        for r in got:
            if log:
                log(f"{r['body']:16s} {_fmt_height(r['height']):6s} {r['surface']:8s} {r['status']:10s} "
                    f"it {r['iterations']:4d} res {r['residual']:.1e}  {r['wall_s']:.2f} s  {r['wu']:.0f} WU  "
                    f"{r['ms_per_iteration']:.1f} ms/it")
        rows += got
    return rows


# ------------------------------------------------------------------------------------------------
# the work unit
# ------------------------------------------------------------------------------------------------


@njit(cache=True)
def reference_pass(pos, spring_nodes, rest, width, table, x, y, start, out):
    """One plain force pass over the springs: the unit of work the benchmark reports times in.

    pos (N,3) [m]; spring_nodes (S,2); rest, width (S,) [m]; table (S,) index into the packed
    tables x (strain), y (tension [N/m]) with offsets start (T+1,). Per spring: the length l, the
    strain l/l0 - 1, a linear search for its segment in the spring's table (the first segment
    extended below the table, the last beyond: no slack branch, so the work does not depend on
    the state), the tension T, the energy w l0 int_0^strain T (trapezoids of the segments below
    plus the partial one), and the force T w (x_b - x_a)/l added to node a and subtracted from
    node b. Writes out (N,3) [N]; returns the energy [J]. Deliberately independent of
    clothsim.kernels, so that speeding those up does not move the unit."""
    for k in range(out.shape[0]):
        out[k, 0] = 0.0
        out[k, 1] = 0.0
        out[k, 2] = 0.0
    energy = 0.0
    for s in range(spring_nodes.shape[0]):
        a = spring_nodes[s, 0]
        b = spring_nodes[s, 1]
        dx = pos[b, 0] - pos[a, 0]
        dy = pos[b, 1] - pos[a, 1]
        dz = pos[b, 2] - pos[a, 2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        strain = length / rest[s] - 1.0
        t = table[s]
        m = start[t]
        w_below = 0.0
        while m < start[t + 1] - 2 and strain >= x[m + 1]:
            w_below += 0.5 * (y[m] + y[m + 1]) * (x[m + 1] - x[m])
            m += 1
        k1 = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
        ds = strain - x[m]
        tension = y[m] + k1 * ds
        energy += width[s] * rest[s] * (w_below + y[m] * ds + 0.5 * k1 * ds * ds)
        f = tension * width[s] / max(length, 1e-300)
        out[a, 0] += f * dx
        out[a, 1] += f * dy
        out[a, 2] += f * dz
        out[b, 0] -= f * dx
        out[b, 1] -= f * dy
        out[b, 2] -= f * dz
    return energy


def reference_pass_time(model, positions, min_batch_s: float = 0.003, batches: int = 15) -> float:
    """CPU time [s] of one ``reference_pass`` over model's springs at positions (N,3) [m]: the
    smallest over ``batches`` batches of passes (each at least ``min_batch_s``) of batch time /
    passes. The first call compiles (or loads from numba's cache) and is not counted."""
    t = model.tables
    args = (np.ascontiguousarray(positions, dtype=np.float64), model.spring_nodes, model.spring_rest_length,
            model.spring_width, model.spring_table, t.x, t.y, t.start, np.empty((model.node_count, 3)))
    reference_pass(*args)
    reps = 1
    while True:
        c0 = time.process_time()
        for _ in range(reps):
            reference_pass(*args)
        dt = time.process_time() - c0
        if dt >= min_batch_s or reps >= 1 << 20:
            break
        reps *= 2
    best = dt / reps
    for _ in range(batches - 1):
        c0 = time.process_time()
        for _ in range(reps):
            reference_pass(*args)
        best = min(best, (time.process_time() - c0) / reps)
    return best


class CpuClock:
    """(wall, CPU) time pairs [s] since construction, recorded at each solver callback; ``cpu_at``
    converts a wall time of the run (as in the solver's history) to CPU time."""

    def __init__(self):
        self.w0 = time.perf_counter()
        self.c0 = time.process_time()
        self.offset = None  # wall time of the driver's start, after this clock's start
        self.wall = [0.0]
        self.cpu = [0.0]

    def sample(self, elapsed: float | None = None) -> None:
        """Record now; elapsed = the driver's own elapsed time, if known (gives the offset)."""
        w = time.perf_counter() - self.w0
        self.wall.append(w)
        self.cpu.append(time.process_time() - self.c0)
        if elapsed is not None and self.offset is None:
            self.offset = max(0.0, w - elapsed)

    def cpu_at(self, t_run: float) -> float:
        """CPU time [s] spent between the driver's start and run time t_run [s] (driver clock)."""
        off = self.offset or 0.0
        return float(np.interp(off + t_run, self.wall, self.cpu) - np.interp(off, self.wall, self.cpu))


# ------------------------------------------------------------------------------------------------
# one run (in a child process)
# ------------------------------------------------------------------------------------------------


def _load(case: Case, solver: str, e: float, time_limit: float | None, max_iterations: int | None = None):
    scene = load_scene(ROOT / case.config, list(case.overrides))
    upd: dict[str, Any] = {"method": solver, "e": e, "time_limit_s": time_limit}
    if max_iterations is not None:
        upd["max_iterations"] = max_iterations
    settings = scene.solver.model_copy(update=upd)
    model, state, _ = prepare(scene)
    return model, state, settings


def run_reference(case: Case) -> dict:
    """Newton to e = REFERENCE_E (or its floor): the positions every run is compared with.

    It runs without grid sequencing, so its path differs from the measured newton runs (which
    sequence): a newton run is not compared with its own trajectory."""
    model, state, settings = _load(case, "newton", REFERENCE_E, 600.0)
    settings = settings.model_copy(update={"newton_sequencing": False})
    solvers.solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1}))
    res = solvers.solve(model, state, settings.model_copy(update={"stall_iterations": 200}))
    return {"positions": state.positions.copy(), "residual": res.residual, "status": res.status}


def run_case(case: Case, solver: str, ref_positions: np.ndarray | None) -> dict:
    """One (scene, solver) measurement; returns a JSON-able dict."""
    limit = case.time_limit.get(solver)
    model, state, settings = _load(case, solver, TARGET_E, limit)
    t0 = time.perf_counter()
    solvers.solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1, "time_limit_s": None}))
    compile_s = time.perf_counter() - t0
    # the reference pass before and after the solve, their mean: the machine's speed drifts
    # (the same process measured 1.9 then 1.3 ms a pass within a minute)
    pos0 = state.positions.copy()
    ref_before = reference_pass_time(model, pos0)
    snaps: dict[float, np.ndarray] = {}
    clock = CpuClock()

    def cb(prog):
        clock.sample(prog.elapsed_s)
        for lv in LEVELS:
            if lv not in snaps and prog.residual <= lv:
                snaps[lv] = prog.state.positions.copy()
        return False

    res = solvers.solve(model, state, settings, callback=cb)
    clock.sample()
    cpu_total = clock.cpu[-1]
    ref_after = reference_pass_time(model, pos0)
    ref_s = 0.5 * (ref_before + ref_after)
    h = res.history
    times, times_wu = {}, {}
    for lv in LEVELS:
        hit = np.nonzero(h["residual"] <= lv)[0] if len(h["residual"]) else []
        times[lv] = float(h["time"][hit[0]]) if len(hit) else None
        times_wu[lv] = clock.cpu_at(times[lv]) / ref_s if times[lv] is not None else None
    err = {}
    if ref_positions is not None:
        for lv, p in snaps.items():
            err[lv] = float(np.abs(p - ref_positions).max())
        err_final = float(np.abs(state.positions - ref_positions).max())
    else:
        err_final = None
    curve_t = h["time"].tolist() if len(h["time"]) else []
    curve_r = h["residual"].tolist() if len(h["residual"]) else []
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
    return {
        "case": case.name, "group": case.group, "solver": solver, "nodes": int(model.node_count),
        "status": res.status, "iterations": int(res.iterations), "residual": float(res.residual),
        "wall_time_s": float(res.wall_time_s), "compile_s": compile_s, "time_limit_s": limit,
        "times": {str(k): v for k, v in times.items()},
        "times_wu": {str(k): v for k, v in times_wu.items()},
        "ref_pass_s": ref_s, "ref_pass_before_after_s": [ref_before, ref_after],
        "springs": int(model.spring_count), "cpu_s": cpu_total,
        "wall_s_outer": clock.wall[-1], "total_wu": cpu_total / ref_s,
        "sweep_wu": (cpu_total / ref_s / res.iterations) if solver == "paper" and res.iterations else None,
        "errors": {str(k): v for k, v in err.items()}, "error_final": err_final,
        "peak_rss_mb": peak, "curve_time": curve_t, "curve_residual": curve_r,
        "energy": float(res.energy),
    }


def _best_of(case: Case, solver: str, ref_positions, repeat: int) -> dict:
    """``run_case`` in ``repeat`` fresh processes; ``_pick_best`` of the runs."""
    return _pick_best([_in_child(run_case, case, solver, ref_positions) for _ in range(max(1, int(repeat)))])


def _pick_best(runs: list) -> dict:
    """The run with the fewest work units to 1e-7 N (its total when 1e-7 was not reached), with
    ``wu_runs`` and ``cpu_runs`` added: every run's work units and CPU seconds to 1e-7 N, in
    order (None where not reached, or where the run failed: a None in ``runs``)."""
    def key(r):
        w = r["times_wu"].get("1e-07")
        return (w is None, w if w is not None else r["total_wu"])

    def wu(r):
        return None if r is None else r["times_wu"].get("1e-07")

    best = dict(min((r for r in runs if r is not None), key=key))
    best["wu_runs"] = [wu(r) for r in runs]
    best["cpu_runs"] = [None if wu(r) is None or not r.get("ref_pass_s") else wu(r) * r["ref_pass_s"] for r in runs]
    return best


def _interleaved(jobs: list[tuple], repeat: int, log=None) -> list[dict]:
    """``run_case`` for every (case, solver, reference positions) of ``jobs``, in ``repeat``
    rounds of fresh processes, each round running every job once in turn (so that all scenes
    share the machine's state of the moment: its load drifts over minutes), then
    ``_pick_best`` per job. A failed run is logged and kept as None, so that every job's lists
    stay one entry per round (``paired_ratios`` pairs them by position). Each row also gets
    ``rounds``: how many of its runs completed."""
    runs: list[list] = [[] for _ in jobs]
    for _ in range(max(1, int(repeat))):
        for j, (case, solver, ref) in enumerate(jobs):
            try:
                runs[j].append(_in_child(run_case, case, solver, ref))
            except Exception as exc:
                runs[j].append(None)
                if log:
                    log(f"{case.name} / {solver}: failed: {exc}")
    done = [sum(r is not None for r in rj) for rj in runs]
    return [dict(_pick_best(rj), rounds=d) for rj, d in zip(runs, done) if d]


def _child_reference(case):
    r = run_reference(case)
    return {"positions": r["positions"], "residual": r["residual"], "status": r["status"]}


def _cpu_to(model, state, settings, e: float = 1e-7) -> float | None:
    """CPU seconds of one solve of ``model`` from a copy of ``state`` until its residual first
    reaches e [N] (as ``run_case`` times it: the driver's history, converted to CPU time); None
    when it is not reached."""
    clock = CpuClock()

    def cb(prog):
        clock.sample(prog.elapsed_s)
        return False

    res = solvers.solve(model, state.copy(), settings, callback=cb)
    clock.sample()
    hit = np.nonzero(res.history["residual"] <= e)[0] if len(res.history["residual"]) else []
    return clock.cpu_at(float(res.history["time"][hit[0]])) if len(hit) else None


def run_pair(base: Case, case: Case, solves: int = PAIR_SOLVES) -> list[list]:
    """In one process, the scene ``case`` against ``base`` (newton): both loaded and warmed up as
    in ``run_case`` (one single-iteration solve each), then solved alternately ``solves`` times
    each, in the order base, case, case, base, base, case, ... Returns one [base s, case s] per
    neighbouring pair: CPU seconds to 1e-7 N (``_cpu_to``; None where not reached). The two
    solves of a pair share the process (its memory placement) and the machine's load of the
    moment, and no reference pass enters their ratio."""
    loaded = []
    for c in (base, case):
        model, state, settings = _load(c, "newton", TARGET_E, c.time_limit.get("newton"))
        solvers.solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1, "time_limit_s": None}))
        loaded.append((model, state, settings))
    pairs = []
    for k in range(max(1, int(solves))):
        order = (0, 1) if k % 2 == 0 else (1, 0)
        t = [None, None]
        for i in order:
            t[i] = _cpu_to(*loaded[i])
        pairs.append(t)
    return pairs


def same_process_ratios(base: Case, others: list[Case], rounds: int, log=None) -> dict:
    """For each scene of ``others``: ``rounds`` fresh processes of ``run_pair`` against ``base``;
    returns {scene name: [case s / base s of every pair]} (pairs where either did not reach
    1e-7 N, or a process that failed, are left out and logged)."""
    out = {}
    for case in others:
        ratios = []
        for _ in range(max(1, int(rounds))):
            try:
                pairs = _in_child(run_pair, base, case)
            except Exception as exc:
                if log:
                    log(f"{case.name}: same-process pair failed: {exc}")
                continue
            ratios += [c / b for b, c in pairs if b and c is not None]
        out[case.name] = ratios
    return out


def _in_child(fn, *args):
    with ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn")) as ex:
        return ex.submit(fn, *args).result()


def run(quick: bool = False, out: str | Path = "docs/benchmarks", log=None, scans: str = "with",
        surface: str = "faceted", garments: bool = False, repeat: int = GARMENT_REPEAT) -> list[dict]:
    """Run the benchmark and write the report; returns the rows. scans: "with" (the scan campaign
    too, in the full benchmark only), "without", or "only" (the campaign alone, written to
    ``benchmarks_scans.md``); surface: the scans' contact surface ("faceted" or "smooth");
    repeat: rounds of fresh processes with ``garments`` (``_interleaved``)."""
    t0 = time.perf_counter()
    if scans == "only":
        scan_rows = run_scans(surface, log)
        write_scan_report(scan_rows, Path(out), time.perf_counter() - t0, surface)
        return scan_rows
    rows, refs = [], {}
    if garments:
        jobs = []
        for case in cases(quick, garments):
            try:
                ref = _in_child(_child_reference, case)
            except Exception as exc:
                if log:
                    log(f"{case.name}: reference failed: {exc}")
                ref = None
            good = ref is not None and ref["status"] == "converged"
            jobs += [(case, solver, ref["positions"] if good else None) for solver in case.solvers]
        rows = _interleaved(jobs, repeat, log)
        gc = [c for c in cases(quick, garments)]
        same = same_process_ratios(gc[0], gc[1:], repeat, log) if len(gc) > 1 else {}
        for r in rows:
            if r["case"] in same:
                r["same_process_ratios"] = same[r["case"]]
        for r in rows:
            if log:
                log(f"{r['case']:32s} {r['solver']:7s} {r['status']:15s} it {r['iterations']:7d} "
                    f"res {r['residual']:.1e}  t(1e-7) {_fmt_tw(r, 1e-7):>16s}  runs (WU) "
                    f"{', '.join(_fmt_wu(w) for w in r['wu_runs'])}"
                    + (f"  same process / square: median {np.median(r['same_process_ratios']):.2f} of "
                       f"{len(r['same_process_ratios'])}" if r.get("same_process_ratios") else ""))
        write_garment_report(rows, Path(out), time.perf_counter() - t0)
        return rows
    for case in cases(quick, garments):
        try:
            ref = _in_child(_child_reference, case)
        except Exception as exc:  # keep going: a missing scene must not sink the whole benchmark
            if log:
                log(f"{case.name}: reference failed: {exc}")
            ref = None
        if ref is not None:
            refs[case.name] = {"status": ref["status"], "residual": ref["residual"]}
        for solver in case.solvers:
            try:
                # a reference that did not converge is no reference: no error column then
                good = ref is not None and ref["status"] == "converged"
                r = _best_of(case, solver, ref["positions"] if good else None, 1)
            except Exception as exc:
                if log:
                    log(f"{case.name} / {solver}: failed: {exc}")
                continue
            rows.append(r)
            if log:
                log(f"{case.name:32s} {solver:7s} {r['status']:15s} it {r['iterations']:7d} "
                    f"res {r['residual']:.1e}  t(1e-7) {_fmt_tw(r, 1e-7):>16s}  compile {r['compile_s']:.1f}s  "
                    f"RSS {r['peak_rss_mb']:.0f} MB  ref {_fmt_ms(r['ref_pass_s'])} ms")
    scan_rows = run_scans(surface, log) if scans == "with" and not quick else []
    write_report(rows, refs, Path(out), quick, time.perf_counter() - t0, scan_rows)
    return rows


def main(args) -> int:
    """CLI entry (``python app.py bench``): args.quick, args.out, args.scans (the scan campaign
    alone), args.surface (the scans' contact surface)."""
    quick = bool(getattr(args, "quick", False))
    out = getattr(args, "out", "docs/benchmarks") or "docs/benchmarks"
    only = bool(getattr(args, "scans", False))
    surface = getattr(args, "surface", None) or "faceted"
    garments = bool(getattr(args, "garments", False))
    repeat = getattr(args, "repeat", None) or GARMENT_REPEAT
    run(quick, out, log=lambda s: print(s, flush=True), scans="only" if only else "with", surface=surface,
        garments=garments, repeat=repeat)
    if garments:
        print(f"wrote {Path(out) / 'benchmarks_garments.md'}")
    elif only:
        print(f"wrote {Path(out) / ('benchmarks_scans' + ('' if surface == 'faceted' else '_' + surface) + '.md')}")
    else:
        print(f"wrote {Path(out) / 'benchmarks.md'} and {Path(out) / 'speed_vs_error.png'}")
    return 0

