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
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parent.parent
LEVELS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]
TARGET_E = 1e-9
REFERENCE_E = 1e-12


@dataclass
class Case:
    """One benchmark scene: a config with overrides, and per-solver time limits [s]."""

    name: str
    config: str
    overrides: list[str] = field(default_factory=list)
    solvers: tuple[str, ...] = ("newton", "paper")
    time_limit: dict = field(default_factory=dict)  # solver -> s
    group: str = "main"


def garment_cases() -> list[Case]:
    """The panel scenes of issue 11's target (``app.py bench --garments``), newton alone, beside
    the 201^2 square they are measured against: the circle cut from the lattice on the sphere cap
    (225 divisions across: 39,877 nodes) and the four-panel garment (four 101^2 quarter panels sewn
    edge to edge: 40,804 nodes)."""
    return [
        Case("sphere cap 201^2", "configs/sphere_cap.yaml", ["fabric.divisions=[200,200]"], ("newton",),
             {"newton": 60}, group="garments"),
        Case("circle cap 40k", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[224,224]"], ("newton",),
             {"newton": 120}, group="garments"),
        Case("four panels cap 40k", "configs/garments/circle_cap.yaml", four_panel_cap_overrides(100), ("newton",),
             {"newton": 120}, group="garments"),
    ]


def cases(quick: bool, garments: bool = False) -> list[Case]:
    """The benchmark scenes (quick: small grids and short caps, under a minute in all; garments:
    the panel scenes of :func:`garment_cases` alone)."""
    if garments:
        return garment_cases()
    sc = "configs/sphere_cap.yaml"
    hard = sorted((ROOT / "configs" / "hard").glob("*.yaml"))
    if quick:
        out = [
            Case("sphere cap 41^2", sc, [], time_limit={"paper": 3, "newton": 20}),
            Case("sphere cap 101^2", sc, ["fabric.divisions=[100,100]"], ("newton",), {"newton": 20}),
        ]
        if (ROOT / "configs" / "thermoform.yaml").exists():
            out.append(Case("thermoform 41^2", "configs/thermoform.yaml", [], time_limit={"paper": 3, "newton": 20}))
        for label, ov in _optional_terms()[::2]:
            out.append(Case(f"sphere cap 21^2 {label}", sc, ["fabric.divisions=[20,20]", *ov], ("newton",),
                            {"newton": 10}, group="terms"))
        return out
    out = [
        Case("sphere cap 41^2", sc, [], time_limit={"paper": 120, "newton": 60}),
        Case("sphere cap 201^2", sc, ["fabric.divisions=[200,200]"], time_limit={"paper": 60, "newton": 60}),
        Case("sphere cap 501^2", sc, ["fabric.divisions=[500,500]"], time_limit={"paper": 30, "newton": 120}),
    ]
    for cfg, label in (("thermoform.yaml", "thermoform 41^2"), ("torso_band.yaml", "torso band 41x11"),
                       ("torso_band_held.yaml", "torso band held 41x11"),
                       ("sewn_sleeve.yaml", "sewn sleeve 51x17")):
        if (ROOT / "configs" / cfg).exists():
            out.append(Case(label, f"configs/{cfg}", [], time_limit={"paper": 60 if "sewn" in cfg else 120,
                                                                     "newton": 60}))
    for h in hard:
        out.append(Case(f"hard: {h.stem}", str(h.relative_to(ROOT)), [], time_limit={"paper": 60, "newton": 60},
                        group="hard"))
    for label, ov in _optional_terms():
        out.append(Case(f"sphere cap 41^2 {label}", sc, ov, time_limit={"paper": 60, "newton": 60}, group="terms"))
    return out


def four_panel_cap_overrides(divisions: int = 100) -> list[str]:
    """Overrides that turn ``configs/sphere_cap.yaml`` into a four-panel garment: the 0.1 m
    sheet cut into four 0.05 m quarter panels (``divisions`` x ``divisions`` each; 100 gives
    40,804 nodes, as many as the 201^2 square), sewn edge to edge by four seams, the outer
    edges held on the square stretched 10 % about the sheet's centre (each panel's stretch acts
    about its own centre, so a displacement of 0.1 (c - 0.05) m moves it to the sheet's)."""
    d = int(divisions)
    quads = (("bl", 0.0, 0.0), ("br", 0.05, 0.0), ("tl", 0.0, 0.05), ("tr", 0.05, 0.05))
    panels, cons = [], []
    for name, tx, ty in quads:
        panels.append(f"{{name: {name}, outline: [[0, 0], [0.05, 0], [0.05, 0.05], [0, 0.05]], "
                      f"divisions: [{d}, {d}], placement: {{transform: {{translate: [{tx}, {ty}, 0.0]}}}}}}")
        ox = 0 if tx == 0 else -1  # the outer column (i) and row (j) of this quarter
        oy = 0 if ty == 0 else -1
        rng = "[1, -1]" if ox == 0 else "[0, -2]"  # the row without the corner the column has
        disp = f"[{0.1 * (tx + 0.025 - 0.05):.4f}, {0.1 * (ty + 0.025 - 0.05):.4f}, 0.0]"
        cons.append(f"{{nodes: {{panel: {name}, i: {ox}, j: null}}, axes: xyz, stretch: 1.1, displacement: {disp}}}")
        cons.append(f"{{nodes: {{panel: {name}, i: {rng}, j: {oy}}}, axes: xyz, stretch: 1.1, displacement: {disp}}}")
    seams = ["{a: {panel: bl, side: right}, b: {panel: br, side: left}}",
             "{a: {panel: tl, side: right}, b: {panel: tr, side: left}}",
             "{a: {panel: bl, side: top}, b: {panel: tl, side: bottom}}",
             "{a: {panel: br, side: top}, b: {panel: tr, side: bottom}}"]
    # each panel's dome leaves the seams on the sheet's plane: lifted clear of the sphere
    return ["panels=[" + ", ".join(panels) + "]", "seams=[" + ", ".join(seams) + "]",
            "constraints=[" + ", ".join(cons) + "]", "initial.auto_clearance=true"]


def _optional_terms():
    return [
        ("(stretch only)", []),
        ("+ gravity", ["gravity={areal_density: 0.2}"]),
        ("+ shear", ["shear={stiffness: 20}"]),
        ("+ bending", ["bending={stiffness: 1}"]),
        ("+ all three", ["gravity={areal_density: 0.2}", "shear={stiffness: 20}", "bending={stiffness: 1}"]),
    ]


# ------------------------------------------------------------------------------------------------
# the scan campaign: the paper's torso band on two scanned bodies at many heights, newton alone
# ------------------------------------------------------------------------------------------------

#: the scanned bodies of the campaign (file stem, heights [m] of the band's centre line in the
#: body's own Y-up frame: waist to lower chest, below the arms)
SCAN_BODIES = (
    ("smpl_man", tuple(round(1.02 + 0.02 * i, 2) for i in range(12))),
    ("smpl_neutral", tuple(round(0.96 + 0.02 * i, 2) for i in range(12))),
)
#: where the campaign looks for the body files (the repository's copies, see static/bodies/README.md)
SCAN_DIRS = (ROOT / "static" / "bodies",)
SCAN_MAX_ITERATIONS = 400
SCAN_TIME_LIMIT = 120.0
#: ... for a garment of the campaign [s] (wall clock: the 28 x 60 stocking took 43-53 s of CPU and
#: up to 117 s of wall time on the loaded 2-core machine)
SCAN_GARMENT_TIME_LIMIT = 600.0
#: the garments of the campaign (issue 12 names the garment issue's stocking): (row name, body
#: file stem (its file from SCAN_DIRS is the mold), config, overrides, contact surface; None: the
#: campaign's), newton alone to TARGET_E like the bands
SCAN_GARMENTS = (
    ("stocking 14 x 30", "smpl_man", "configs/garments/stocking.yaml", (), None),
    ("stocking 28 x 60", "smpl_man", "configs/garments/stocking.yaml",
     ("panels.0.divisions=[28,60]", "panels.1.divisions=[28,60]"), "smooth"),
)


def scan_body_path(stem: str) -> Path | None:
    """The body file ``<stem>.stl`` in the first of ``SCAN_DIRS`` that has it, or None."""
    for d in SCAN_DIRS:
        if (d / f"{stem}.stl").exists():
            return d / f"{stem}.stl"
    return None


def scan_band_overrides(path: Path, height: float, surface: str = "faceted") -> list[str]:
    """Overrides that put configs/torso_band.yaml (the paper's 0.5 x 0.2 m band, 40 x 10
    divisions, ends pulled round to the back with stretch 1.75 and held in x and y, free along
    the body axis) onto a Y-up scan in metres at ``height`` [m]: the mold is rotated to Z-up with
    the front towards +y (``rotate: [90, 0, 180]``); the band starts on a cylinder round the body
    axis through the middle of the body's slab [height - 0.1, height + 0.1] (arms excluded:
    |x| < 0.3 m), 2 cm clear of its farthest vertex, centred on the front. ``surface``: the mesh
    mold's contact surface ("faceted" or "smooth"; always stated: a scan's default is smooth)."""
    import trimesh

    V = np.asarray(trimesh.load(str(path), force="mesh").vertices)
    sel = (np.abs(V[:, 1] - height) < 0.1) & (np.abs(V[:, 0]) < 0.3)
    z0 = 0.5 * float(V[sel, 2].min() + V[sel, 2].max())
    r = float(np.hypot(V[sel, 0], V[sel, 2] - z0).max()) + 0.02
    start = 90.0 - math.degrees(0.25 / r)
    mold = f"path: {path}, rotate: [90, 0, 180], surface: {surface}"
    return [f"mold={{{mold}}}",
            f"initial.wrap={{center: [0.0, {z0:.6f}, {height:.4f}], axis: [0, 0, 1], radius: {r:.6f}, "
            f"start_angle: {start:.6f}}}"]


def _scan_row(case: Case, body: str, height, surface: str, time_limit: float = SCAN_TIME_LIMIT) -> dict:
    """One campaign run: newton alone to TARGET_E from the case's start (kernels compiled by a
    one-iteration run first); a JSON-able row."""
    from .solvers import solve

    model, state, settings = _load(case, "newton", TARGET_E, time_limit, SCAN_MAX_ITERATIONS)
    solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1, "time_limit_s": None}))
    ref_s = reference_pass_time(model, state.positions)
    c0 = time.process_time()
    res = solve(model, state, settings)
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


def _fmt_height(h) -> str:
    return "-" if h is None else f"{h:.2f}"


def scan_table(rows: list[dict]) -> list[str]:
    """The campaign's markdown section."""
    if not rows:
        return []
    ok = [r for r in rows if r["status"] == "converged"]
    its = [r["iterations"] for r in ok]
    lines = ["## Scan campaign: the torso band on scanned bodies (newton alone)", "",
             "configs/torso_band.yaml (0.5 x 0.2 m band, 40 x 10 divisions, ends pulled round to the back "
             "with stretch 1.75, held in x and y, free along the body axis) on each body at each height "
             "(`bench.scan_band_overrides`), and the garments of `bench.SCAN_GARMENTS` "
             "(configs/garments/stocking.yaml on smpl_man's leg, its panels' 14 x 30 divisions on the "
             "campaign's surface and 28 x 60 on the smooth one; height -), newton to 1e-9 N, at most "
             f"{SCAN_MAX_ITERATIONS} iterations. `WU` = process CPU time of the solve / one reference "
             "pass; `ms/it` = CPU ms per iteration; `contact` = contact nodes at the end. "
             f"Converged {len(ok)} of {len(rows)}"
             + (f"; iterations {min(its)}-{max(its)} (median {int(np.median(its))})" if its else "") + ".", "",
             "| body | surface | height m | nodes | status | iters | final residual N | s | WU | ms/it | contact |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['body']} | {r['surface']} | {_fmt_height(r['height'])} | {r['nodes']} | {r['status']} | "
                     f"{r['iterations']} | {r['residual']:.1e} | {r['wall_s']:.2f} | {r['wu']:.0f} | "
                     f"{r['ms_per_iteration']:.1f} | {r['contact']} |")
    return lines + [""]


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
    from .config import load_scene
    from .simulation import prepare

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
    from .solvers import solve

    model, state, settings = _load(case, "newton", REFERENCE_E, 600.0)
    settings = settings.model_copy(update={"newton_sequencing": False})
    solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1}))
    res = solve(model, state, settings.model_copy(update={"stall_iterations": 200}))
    return {"positions": state.positions.copy(), "residual": res.residual, "status": res.status}


def run_case(case: Case, solver: str, ref_positions: np.ndarray | None) -> dict:
    """One (scene, solver) measurement; returns a JSON-able dict."""
    from .solvers import solve

    limit = case.time_limit.get(solver)
    model, state, settings = _load(case, solver, TARGET_E, limit)
    t0 = time.perf_counter()
    solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1, "time_limit_s": None}))
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

    res = solve(model, state, settings, callback=cb)
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


#: rounds of fresh processes in ``bench --garments`` (each round runs every scene once; the best
#: and the paired medians are reported): a process's reference pass moves by up to 1.6x from one
#: process to the next on the 2-core machine (memory placement), and with it a single run's work
#: units; the machine's load drifts over minutes
GARMENT_REPEAT = 5


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


def paired_ratios(base: dict, row: dict, key: str = "wu_runs") -> list[float]:
    """Round by round, ``row``'s figure to 1e-7 N over ``base``'s of the same round (key:
    "wu_runs" work units or "cpu_runs" CPU seconds); rounds where either is missing are skipped."""
    a, b = base.get(key) or [], row.get(key) or []
    return [y / x for x, y in zip(a, b) if x and y is not None]


def _child_reference(case):
    r = run_reference(case)
    return {"positions": r["positions"], "residual": r["residual"], "status": r["status"]}


#: solves of each scene in one process of ``run_pair`` (in the order base, scene, scene, base,
#: base, scene, ...: each pair of neighbouring solves is one ratio)
PAIR_SOLVES = 4


def _cpu_to(model, state, settings, e: float = 1e-7) -> float | None:
    """CPU seconds of one solve of ``model`` from a copy of ``state`` until its residual first
    reaches e [N] (as ``run_case`` times it: the driver's history, converted to CPU time); None
    when it is not reached."""
    from .solvers import solve

    clock = CpuClock()

    def cb(prog):
        clock.sample(prog.elapsed_s)
        return False

    res = solve(model, state.copy(), settings, callback=cb)
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
    from .solvers import solve

    loaded = []
    for c in (base, case):
        model, state, settings = _load(c, "newton", TARGET_E, c.time_limit.get("newton"))
        solve(model, state.copy(), settings.model_copy(update={"max_iterations": 1, "time_limit_s": None}))
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
    import multiprocessing as mp

    with ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn")) as ex:
        return ex.submit(fn, *args).result()


# ------------------------------------------------------------------------------------------------
# report
# ------------------------------------------------------------------------------------------------


def machine_info() -> dict:
    import numba
    import scipy

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        from . import __version__
    except ImportError:  # pragma: no cover
        __version__ = "?"
    return {
        "date": _dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
        "cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(),
        "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
        "scipy": scipy.__version__, "clothsim": __version__,
        "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def _fmt_t(v):
    if v is None:
        return "not reached"
    return f"{v:.3g}"


def _fmt_tw(r, lv):
    """A level's time as "seconds (work units)"."""
    v = r["times"][str(lv)]
    if v is None:
        return "not reached"
    wu = (r.get("times_wu") or {}).get(str(lv))
    return f"{v:.3g}" if wu is None else f"{v:.3g} ({wu:.0f})"


def _fmt_ms(v):
    return "-" if v is None else f"{v * 1e3:.3g}"


def _fmt_wu(v, digits=0):
    return "-" if v is None else f"{v:.{digits}f}"


def _fmt_e(v):
    return "-" if v is None else f"{v:.1e}"


def write_report(rows: list[dict], refs: dict, out: Path, quick: bool, elapsed: float,
                 scan_rows: list[dict] | None = None) -> None:
    info = machine_info()
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Benchmarks: speed against error", "",
             f"Generated by `python app.py bench{' --quick' if quick else ''}` on {info['date']} "
             f"({elapsed:.0f} s in all).", "",
             f"Machine: {info['cpu']}, {info['cores']} cores, {info['platform']}; load average at the end "
             f"{info['load_average']:.2f} (other jobs shared the machine: times are wall-clock and noisy)." if
             info["load_average"] is not None else f"Machine: {info['cpu']}, {info['cores']} cores.", "",
             f"Versions: Python {info['python']}, numpy {info['numpy']}, numba {info['numba']}, scipy {info['scipy']}, "
             f"clothsim {info['clothsim']}.", "",
             "Columns: time [s] after JIT warm-up until ||V||_inf (eq. 6) first fell below each level; "
             "`compile` = the first call (numba compile or cache load), not counted in the times; "
             "`err@1e-6` / `err end` = max node-position error [m] against the reference "
             f"(newton to {REFERENCE_E:g} N, or its float64 floor); `RSS` = peak resident memory of the "
             "run's process [MB]. The paper solver is capped by the time limit shown; "
             "\"not reached\" means it did not get there within it.", "",
             "Work units: each level's cell is `seconds (work units)`. A work unit (WU) is one reference "
             "force pass over the scene's springs (`bench.reference_pass`: a plain loop, no clothsim "
             "kernel: length, table lookup, forces and energy), timed in the same process; both the run "
             "and the pass are measured in process CPU time, so a WU count does not move with the "
             "machine's load the way seconds do. `ref ms` is that pass [ms]; `total WU` the whole call "
             "(including the solver's set-up, which the seconds leave out); `sweep WU` the paper solver's "
             "cost of one sweep (it visits every node once, so this is its per-node cost in units of a "
             "reference pass's per-node cost).", ""]
    head = ("| scene | nodes | solver | status | iters | compile s | " + " | ".join(f"{lv:.0e}" for lv in LEVELS)
            + " | final residual N | err@1e-6 m | err end m | RSS MB | ref ms | total WU | sweep WU |")
    sep = "|" + "---|" * (13 + len(LEVELS))
    for group, title in (("main", "Benchmark scenes"), ("hard", "Hard cases"),
                         ("terms", "Cost of the optional terms of eq. (1) (same scene with and without)")):
        g = [r for r in rows if r["group"] == group]
        if not g:
            continue
        lines += [f"## {title}", "", head, sep]
        for r in g:
            cap = f" (cap {r['time_limit_s']:g} s)" if r["time_limit_s"] else ""
            lines.append(
                f"| {r['case']} | {r['nodes']} | {r['solver']}{cap} | {r['status']} | {r['iterations']} | "
                f"{r['compile_s']:.2f} | " + " | ".join(_fmt_tw(r, lv) for lv in LEVELS)
                + f" | {r['residual']:.1e} | {_fmt_e(r['errors'].get(str(1e-6)))} | {_fmt_e(r['error_final'])} | "
                f"{r['peak_rss_mb']:.0f} | {_fmt_ms(r.get('ref_pass_s'))} | {_fmt_wu(r.get('total_wu'))} | "
                f"{_fmt_wu(r.get('sweep_wu'), 2)} |")
        lines.append("")
    # speed-ups
    sp_lines = []
    by = {(r["case"], r["solver"]): r for r in rows}
    for (case, solver), r in by.items():
        if solver != "newton" or (case, "paper") not in by:
            continue
        p = by[(case, "paper")]
        best = None
        for lv in LEVELS:
            tn, tp = r["times"][str(lv)], p["times"][str(lv)]
            if tn is not None and tp is not None and tn > 0:
                best = (lv, tp / tn, tp, tn)
        if best:
            sp_lines.append(f"| {case} | {best[0]:.0e} | {best[2]:.3g} | {best[3]:.3g} | {best[1]:.0f}x |")
    if sp_lines:
        lines += ["## newton against paper", "",
                  "At the tightest level both reached (paper capped by its time limit):", "",
                  "| scene | level N | paper s | newton s | speed-up |", "|---|---|---|---|---|", *sp_lines, ""]
    if scan_rows:
        lines += scan_table(scan_rows)
    elif (out / "benchmarks_scans.md").exists():
        lines += ["## Scan campaign", "", "Run apart (`python app.py bench --scans`): see "
                  "[benchmarks_scans.md](benchmarks_scans.md).", ""]
    lines += ["## References", "", "| scene | reference status | reference residual N |", "|---|---|---|"]
    for case, ref in refs.items():
        lines.append(f"| {case} | {ref['status']} | {ref['residual']:.1e} |")
    lines += ["", "![error against time](speed_vs_error.png)", ""]
    (out / "benchmarks.md").write_text("\n".join(lines))
    (out / "benchmarks.json").write_text(json.dumps({"machine": info, "rows": [
        {k: v for k, v in r.items() if not k.startswith("curve")} for r in rows], "scans": scan_rows or []},
        indent=1))
    _plot(rows, out / "speed_vs_error.png")


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    ax, ax2 = axes
    for r in rows:
        if r["group"] == "terms":
            continue
        ls = "-" if r["solver"] == "newton" else "--"
        pts = [(r["times"][str(lv)], r["errors"].get(str(lv))) for lv in LEVELS]
        pts = [(t, e) for t, e in pts if t is not None and e is not None and t > 0 and e > 0]
        if pts:
            t, e = zip(*pts)
            ax.loglog(t, e, ls, marker="o", ms=3, label=f"{r['case']} / {r['solver']}")
        ct = np.asarray(r["curve_time"])
        cr = np.asarray(r["curve_residual"])
        ok = (ct > 0) & (cr > 0)
        if ok.any():
            ax2.loglog(ct[ok], cr[ok], ls, lw=1, label=f"{r['case']} / {r['solver']}")
    ax.set_xlabel("time after warm-up [s]")
    ax.set_ylabel("max node-position error vs reference [m]")
    ax.set_title("error against time (points: residual levels 1e-2 ... 1e-9 N)")
    ax.grid(True, which="both", alpha=0.3)
    ax2.set_xlabel("time after warm-up [s]")
    ax2.set_ylabel("||V||_inf [N]")
    ax2.set_title("residual against time")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=6, ncol=1, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: why Newton does what it does on the smooth surface (measured; appended to benchmarks_scans_smooth.md)
SMOOTH_SCAN_NOTES = [
    "## Newton on the smooth surface: what changed and why", "",
    "- **The contact's curvature term** (`active_set._curvature_blocks`, "
    "`iteration.CURVATURE = 1`; 3 since, below). A node held on a curved surface and pressed onto it by lam = -F.n "
    "has, along the surface, the Hessian K - lam S (S the shape operator, `smooth.smooth_shape_operator`: "
    "forward differences of grad phi, three phi evaluations, no foot iteration). The tangent-plane model "
    "misses -lam S: on concave parts (S < 0: the small of the back, between ribs) it is too soft, the "
    "step overshoots and the line search halves it step after step. Only the positive semi-definite "
    "part of -lam S is added, so the Hessian stays positive definite. Campaign iterations, 24 cases: "
    "before 58-263 (median 93; 0 of 24 at most 60); positive part 28-91 (median 50.5; 16 of 24 at most "
    "60; 29-88, median 48, 18 of 24 with the cost changes below, which change the rounding); all of -lam S 25-86 (median 49.5), but on the stocking all of it makes the Hessian indefinite "
    "and Newton stalls at 1.8 N after 195 iterations (the lead's wrong equilibrium on "
    "configs/class2_sleeve.yaml is the same failure), while the positive part leaves the stocking at 419 "
    "iterations (before: ~420): the stocking's slow line search is not concave curvature. Only the "
    "smooth surface gets the term (no example's recorded equilibrium changes).",
    "- **Cost per iteration** (smpl_man, y = 1.20, CPU ms per iteration on the shared machine, "
    "30 before): the banded Cholesky on the smooth surface too (`iteration.BAND_ON_SMOOTH`: 28; the "
    "factorisation is a small share here); a node projected onto a converged smooth foot point is not "
    "queried again for penetration (the foot is on the surface to 1e-13 m; the faceted fallback "
    "still is; `active_set.SMOOTH_FOOT_TRUSTED`: 24); `_block_infeasible` skips the smooth surface, "
    "whose answers are all faces (one query per contact node saved, the same steps: 22). "
    "What is left: the line search's projections (about half), the residual's and the active set's "
    "normals and the free nodes' distances (one smooth query each, 20 to 55 us).",
    "- **The Levenberg rule** for line-search steps alpha in [0.1, 1) (shift unchanged) was tried on the "
    "stocking on the smooth surface (419 iterations with the rule as it is): raising the shift tenfold "
    "after alpha = 0.5 (`LM_ALPHA_LOW = 0.6`) took 579 iterations; lowering it after alpha = 0.5 "
    "(`LM_ALPHA_HIGH = 0.5`) had not converged after three times the time. Kept as it is.",
    "- **Issue 12: what limited the steps** (per-iteration traces, `scripts/newton_trace.py`). (1) The "
    "stocking's ~420 iterations: the front's held column (x fixed) was moved onto the foot point along y "
    "and z only, which leaves it inside a curved leg by about its offset times the curvature; every step "
    "longer than ~5e-5 m failed the line search's 1e-10 m penetration check, so alpha sat at 0.25 with the "
    "shift at 1e-3 for 300 iterations. Newton steps along the normal's free part put such nodes on the "
    "surface (`active_set.FIXED_PROJECTION_STEPS`): the energy reached its final value in ~60 "
    "iterations. (2) Then nodes whose multiplier is about 0 churned: released (resultant pointing out), "
    "their coupled step entered the body, the line search stopped them at the surface and cut alpha to "
    "1/128, they were back in contact, and again. Holding every entering node (`iteration.HOLD_SHARE = "
    "0`, projected Newton) ends it: the stocking converges in 60 iterations. (3) Linear tails (the "
    "residual halving per full step, no contact change): the kink stiffness of slack springs in a "
    "gathered rope is comparable to the little that holds the rows along the body axis; it now decays "
    "tenfold after every full step (`iteration.KINK_DECAY`). These three apply on the smooth surface; on "
    "facets (`SCAN_RULES_ON_FACETS`, `FIXED_PROJECTION_EVERYWHERE`) they take the faceted campaign from "
    "36-90 to 29-59 iterations (median 45, 0 of 24 above 60) but move the recorded equilibria of the "
    "faceted stocking and torso_band_held, so they are off there. (4) Cost: the mold's answers at the "
    "nodes are queried once per set of positions (`active_set._query_nodes`): the accepted step's "
    "residual queries them and the next iteration's active set, distances, blocking rules and face "
    "clips read them (they queried the same points three to four times).",
    "- **All of the curvature term where the model has a minimum** (`iteration.CURVATURE = 3`, issue 12 "
    "item 2). The two bands above 60 (smpl_man at y = 1.06 and 1.24 m: 65 and 75 iterations) ended in "
    "linear tails: full steps, no contact change, the residual x0.23 and x0.42 per iteration for 9 and 18 "
    "iterations. The positive part alone leaves out the convex part of -lam S, so the model is too stiff "
    "along the surface: in a gathered rope whose soft direction (along the body axis) is tilted against "
    "the torso's principal directions the step falls short by a fixed share. All of -lam S everywhere "
    "(`CURVATURE = 2`) ends those two bands in 17 and 23 iterations, but at 1.46 and 0.47 J where the "
    "descent reaches 0.98 and 0.33 J: stationary points the positive definite model had left (at 1.06 m "
    "it passed 4e-3 N near 1.458 J at iteration 9 and slid away for 45 iterations), saddles that Newton "
    "with an indefinite Hessian converges to. Now all of the term is added while the projected system "
    "with it is positive definite (the banded Cholesky's or the sparse LU's pivots all positive, "
    "`iteration._lu_positive_definite`, the LU with diagonal pivots only), its positive part otherwise "
    "(the system solved again): exact Newton near a minimum, the descent near a saddle. Levels solved "
    "by CG (above `DIRECT_DOFS`) take the positive part: CG is no test of definiteness (forced onto CG, "
    "the band at 1.24 m converged to the saddle, 0.468 J; a review found it). Every band ends on "
    "the same equilibrium as before (energies within 5e-15 J, positions within 6.5e-10 m); the stocking, "
    "whose slack courses are degenerate, at the same energy (1e-16 relative), 0.4 mm (14 x 30) and 1.2 mm "
    "(28 x 60) along them. Iterations: bands 23-75 (median 34, 2 above 60) -> 19-60 (median 28.5, none "
    "above 60); stocking 14 x 30 77 -> 43, 28 x 60 209 -> 58 while CG counted as a test, 209 again on CG's levels now (its end game was the same linear tail). "
    "The faceted campaign is unchanged (the term is 0 on facets: the same iterations and residuals, case "
    "by case), and so is every example on an analytic or faceted mold. It costs time on the bands: "
    "fewer iterations (870 -> 724 over 23 bands) but more and dearer line-search trials (the softer "
    "model's longer steps are cut more often, and their trial points lie farther from the surface, "
    "where a smooth query is slower: smpl_neutral at y = 1.12 m, 37 trials of 8 ms -> 70 of 23 ms), "
    "so 31-35 -> 49-54 ms per iteration and 27-30 -> 36-39 s of CPU for the 23 bands (two interleaved "
    "runs each; median per band 1.10 -> 1.46 s); the stockings take half the time (14 x 30 4.4 -> "
    "2.4 s, 28 x 60 41 -> 23 s). Tried and not kept: the full term only after a full step (less "
    "CPU on the bands; stockings 19 and 84 iterations) leaves 61 iterations at 1.06 and at 1.24 m, "
    "after a step of alpha >= 0.5 62 and 63. "
    "Left: the middle of the bands "
    "at 1.06 and 1.24 m (about 40 iterations each): full steps raise the energy by 10 to 400 times their "
    "predicted decrease and the line search cuts them to alpha = 1/2-1/16 (by the energy, never by "
    "penetration) while the rope slides along the body by 5-15 cm per predicted step. Also not kept: "
    "restoring the kink stiffness after any cut step (62 and 57 iterations), raising the shift after "
    "alpha < 0.3 (70 and 59).",
    "- **All of the curvature term on CG's levels too, by an eigenvalue test** "
    "(`iteration.CURVATURE_CG_TEST = 5`). The 28 x 60 stocking's fine level (2,946 nodes, 8,838 unknowns)"
    ' is solved by CG, which took the positive part only: 209 iterations, the end game the linear tail '
    'above. The system with all of the term is now tested there by LOBPCG '
    "(`iteration._smallest_eigenpair`: block size 1, 5 iterations from the last test's eigenvector, "
    "preconditioned by the level's V-cycle restricted to the free unknowns) before the first CG solve of "
    'an iteration: all of the term when the estimate theta of the smallest eigenvalue exceeds its '
    "residual's norm |A x - theta x| (|x| = 1), else its positive part. theta is a Rayleigh quotient, so "
    'it lies above the smallest eigenvalue; the margin asks for a converged estimate, and an unconverged '
    'one (a poor preconditioner, a cold start) refuses. The 28 x 60 stocking: 209 -> 50 iterations (all '
    'of the term in 38 of 49 tests), 27-32 -> 7.3-8.1 s of CPU (three runs each, a shared machine), the '
    'same energy (1.00576876261 J, 2e-13 relative), positions within 0.4 mm (median 2e-13 m: along the slack courses). The 14 x 30 stocking and the bands are direct levels:'
    ' unchanged (43, 60, 57 iterations, the same bits). Soundness, checked with every band forced onto CG'
    " (`DIRECT_DOFS = 0`) and the sparse LU's test alongside each LOBPCG test (24 bands, 714 tests): the "
    'term was never taken where the LU found the system indefinite (and refused 12 times where the LU '
    "found it positive definite); every band ended at the direct solve's energy (within 1e-14 relative; "
    '0.33151 J at 1.24 m, not the saddle), in 19-58 iterations (24-68 with the positive part on CG). '
    'Tried and not kept: LOBPCG with 10, 20 or 3 iterations and block size 2, or 10 and block 1: 49-56 '
    'iterations, 10-17 s (5 and block 1: 50, 6.8 s in the same series); the fine level factorised '
    "directly (`DIRECT_DOFS = 9000`, the sparse LU's test): 147 iterations, 27 s, and the system with all"
    ' of the term was positive definite in 145 of the 146 fine iterations, so it is the exact solve, not '
    "the fallback, that is slower there than CG's inexact one (not analysed further); a shift sigma x the"
    ' mean diagonal (sigma = 1e-6, 1e-4, 1e-2 in turn, one factorisation each) before the positive part '
    'on direct levels: the 14 x 30 stocking 43 -> 14 iterations and the band at 1.06 m 60 -> 50, but the '
    'band at 1.24 m ended on the saddle (0.468 J) (sigma = 1e-2 alone: 1.24 m on the saddle, 1.06 m at '
    '1.316 J after 156 iterations; 1e-1 alone: both bands stalled, at 7.5e-3 and 3.4e-3 N; the 14 x 30 '
    'stocking 22 and 18), and the 28 x 60 stocking at the default stays at 209 '
    "(its fine level is CG's).",
    "- **A step along the negative curvature near saddles** (`iteration.NEG_CURV_MOVE = 0.8` lattice "
    "spacings, issue 12 item 2, 2026-12-02). Main at 420f8fd took 62 iterations at smpl_man y = 1.06 m (60 "
    "in the 08:05 run on an AMD EPYC: the path follows the rounding, which the processor and later commits "
    "change). Traced: by its 9th iteration "
    "the band is at 3.9e-3 N and 1.458 J, next to a saddle; the system with all of the curvature term is "
    "indefinite there, its positive part leaves the escape direction nearly flat, and Newton crept away "
    "for 30 iterations with steps growing about 15 % each. Now, on a direct level where the banded "
    "Cholesky (or the sparse LU) finds the system with all of the term indefinite, LOBPCG "
    "(`iteration._negative_curvature`: 5 iterations from the last vector, preconditioned by the positive "
    "part's factor, `linalg._band_factored_solve`, about 3 ms) estimates its smallest eigenpair; when "
    "theta < -|A v - theta v| the step gains v, signed to descend and scaled to a largest coordinate move of "
    "0.8 spacings, and the line search cuts the sum as any step. The 24 bands: 19-62 iterations (744 in "
    "all) -> 18-48 (718), every band at the same energy (within 4e-15 J) and positions (within 7e-10 m); "
    "the estimate was a converged negative eigenvalue in 194 of the campaign's 196 tests (in the first 33, at "
    "1.06 and 1.24 m: theta -3.6e-4 to -0.23 N/m, |A v - theta v| 4e-12 to 2e-5); a test against a "
    "dense eigensolver is in tests/test_newton_scans.py. Scale measured: 0.4 spacings at most 47 iterations, 0.8 46, 1.6 56; 5 LOBPCG iterations "
    "48, 10 46. The stockings never take it (their indefinite systems' estimates are not converged "
    "negative ones): unchanged. The middle of the band at 1.06 m still takes about 25 iterations with "
    "alpha = 1/4-1/8: the rope sliding 10-20 cm down the body.",
    "- **The line search traced and queried once** (`iteration.LINE_SEARCH_RECORDS`, issue 12 item 3). "
    "A shorter step's segment is a prefix of the longer one's (the same start and direction), so its "
    "first entry into the surface is the same point, or none when the prefix ends before it: each free "
    "node's segment is traced once per line search and the shorter steps read the trace "
    "(`_trial_positions_sd`'s memo). The accepted step's mold answers come from its trial pass (the "
    "query of a node left where it was queried; for a node put on the surface its foot point, the "
    "normal there and distance 0), the nodes that did not move keep theirs, and only the rest are "
    "queried (`active_set._complete_queries`: about 100 of 451). Checked in a test against the fresh "
    "pass and the fresh queries (positions within 3e-11 m, answers within 1e-13). smpl_man at 1.10 m "
    "(`scripts/newton_phases.py --surface smooth`): 22.0 -> 14.2 ms per iteration (a line search's "
    "first pass 6.3 ms, its later ones 1.4 ms); the 24 bands 18.7 -> 10.9 s of CPU, 18-52 iterations, the "
    "same minima (`app.py bench --scans --surface smooth` 13:04: 18-52 iterations, median 15.5 ms and 1,578 WU "
    "per iteration, 11.9 s for the 24 bands; 19-60, 33.0 ms, 1,822 WU and 25.6 s in the 08:05 run on a "
    "busier machine). Not kept: the first pass traces grazing free nodes (about 100, 50 us each, up to "
    "500 us: 64 sphere-tracing steps of 5-10 us queries, then the minimum search); capping the steps "
    "at 16 gave 6.1 -> 5.1 ms but moved the iterations, and stopping the minimum search by the "
    "1-Lipschitz bound (the same answers) 6.3 -> 6.1 ms.", "",
]


def write_garment_report(rows: list[dict], out: Path, elapsed: float) -> None:
    """``<out>/benchmarks_garments.md``: the panel scenes against the 201^2 square, in seconds
    and work units, with the ratio to the square's time at 1e-7 N (issue 11's target: 1.5)."""
    info = machine_info()
    sq = next((r for r in rows if r["case"].startswith("sphere cap")), None)
    base = sq["times_wu"].get("1e-07") if sq else None
    lines = ["# Benchmark: panels against the square", "",
             f"Generated by `python app.py bench --garments` on {info['date']} ({elapsed:.0f} s; load average "
             f"{info['load_average']:.1f}); newton, e = 1e-9 N; WU = CPU time / one reference pass over the scene's "
             "springs, measured in the solve's own process before and after the solve (their mean). The scenes "
             "run in rounds of fresh processes, each round every scene once in turn (the machine's load drifts "
             "over minutes; a round's scenes share it); the table gives each scene's run with the fewest work "
             "units to 1e-7 N, `/ square` that best over the square's best, `paired` the median over the rounds "
             "of the scene's figure over the square's of the same round (work units; CPU seconds), and `runs` "
             "every round's work units (a process's reference pass moves by "
             "up to 1.6x from one process to the next). `same process` is the issue's time ratio measured "
             "where the machine's state cannot enter it: in each of as many fresh processes, the scene and "
             f"the square solved alternately ({PAIR_SOLVES} times each, in the order square, scene, scene, "
             "square, ...), each scene's CPU seconds to 1e-7 N over its neighbouring square's; the median "
             "over every pair, with the range and the number of pairs. (A reference pass measured twice in "
             "one process gave 1.24 and 1.87 ms: the work units' ratio between processes carries that "
             "noise.)", "",
             "| scene | nodes | status | iterations | t(1e-7) s | t(1e-7) WU | / square | paired WU / square "
             "| paired s / square | same process s / square | runs (WU) | t(1e-9) WU | error m |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def med(v):
        return f"{float(np.median(v)):.2f}" if v else "-"

    for r in rows:
        wu = r["times_wu"].get("1e-07")
        ratio = f"{wu / base:.2f}" if wu is not None and base else "-"
        pw = med(paired_ratios(sq, r, "wu_runs")) if sq else "-"
        ps = med(paired_ratios(sq, r, "cpu_runs")) if sq else "-"
        runs = ", ".join(_fmt_wu(w) for w in r.get("wu_runs") or [wu])
        sp_r = r.get("same_process_ratios")
        same = (f"{float(np.median(sp_r)):.2f} ({min(sp_r):.2f}-{max(sp_r):.2f}, {len(sp_r)})" if sp_r
                else ("1.00" if r is sq else "-"))
        lines.append(f"| {r['case']} | {r['nodes']} | {r['status']} | {r['iterations']} | {_fmt_t(r['times'].get('1e-07'))} "
                     f"| {_fmt_wu(wu)} | {ratio} | {pw} | {ps} | {same} | {runs} | {_fmt_wu(r['times_wu'].get('1e-09'))} "
                     f"| {_fmt_e(r['error_final'])} |")
    out.mkdir(parents=True, exist_ok=True)
    (out / "benchmarks_garments.md").write_text("\n".join(lines) + "\n")


def write_scan_report(scan_rows: list[dict], out: Path, elapsed: float, surface: str) -> None:
    """``<out>/benchmarks_scans.md`` (``benchmarks_scans_smooth.md`` on the smooth surface): the
    scan campaign alone (``app.py bench --scans [--surface smooth]``)."""
    info = machine_info()
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Benchmarks: the scan campaign", "",
             f"Generated by `python app.py bench --scans{'' if surface == 'faceted' else ' --surface ' + surface}` "
             f"on {info['date']} ({elapsed:.0f} s in all); {info['cpu']}, {info['cores']} cores; numba "
             f"{info['numba']}, clothsim {info['clothsim']}.", ""] + scan_table(scan_rows)
    if not scan_rows:
        lines.append("No body file found (see `bench.SCAN_DIRS`): nothing run.")
    elif surface == "smooth":
        lines += SMOOTH_SCAN_NOTES
    stem = "benchmarks_scans" + ("" if surface == "faceted" else f"_{surface}")
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    (out / f"{stem}.json").write_text(json.dumps({"machine": info, "scans": scan_rows}, indent=1))


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


if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser()
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", default="docs/benchmarks")
    p.add_argument("--scans", action="store_true")
    p.add_argument("--garments", action="store_true")
    p.add_argument("--repeat", type=int, default=GARMENT_REPEAT)
    p.add_argument("--surface", default="faceted", choices=("faceted", "smooth"))
    sys.exit(main(p.parse_args()))
