"""The friction benchmark (``python app.py bench --friction``): what a frictional load step costs
against the frictionless solve of the same scene, and the capstan's error against e^(mu phi) as
the lattice refines (issue 30: a frictional load step at most 3 times the frictionless solve).

Times are CPU seconds of this process and work units (WU: the time over one plain reference force
pass over the scene's springs, ``bench.reference_pass_time``, measured in the same process), warm
kernels (each scene is solved once before it is timed). Rows:

- the capstan (``configs/cylinder_wrap.yaml`` at 20 to 160 divisions along the strip): draped
  frictionless, then with mu = 0.3 its right end pulled 0.06 m down in 20 load steps (past slip);
  against the frictionless solve, from its compiled start, of the same scene with the end pulled;
- the tube on the leg cone (``configs/tube_on_leg_cone.yaml``, 34 x 16): solved frictionless with
  its cuffs held along the leg, then the cuffs released with mu = 0.1 in one load step; against
  that frictionless solve;
- the stocking with friction (``configs/garments/stocking_friction.yaml``): its relax stage's 10
  load steps with mu = 0.4 (mean and largest); against the frictionless one-go solve of the same
  garment (``configs/garments/stocking.yaml``).

Writes ``benchmarks_friction.md`` and ``benchmarks_friction.json`` into the output folder.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from ..compile import compile_model, compile_state
from ..config import load_scene
from ..fileio import atomic_write_bytes
from ..kernels import spring_strains_tensions
from ..model import SpringFamily
from ..simulation import Simulation
from ..solvers import Control, load_steps, solve
from ..solvers.friction import solve_steps
from . import machine_info, reference_pass_time

ROOT = Path(__file__).resolve().parents[2]
MU_CAPSTAN = 0.3
CAPSTAN_DIVISIONS = (20, 40, 80, 160)
CAPSTAN_PULL = 0.06  # [m]
CAPSTAN_STEPS = 20
MU_CONE = 0.1
TARGET_RATIO = 3.0


def column_tensions(model, pos, xs=None):
    """[(T, d)] for columns of warp springs, each the column whose rest midpoints lie nearest
    one of ``xs`` [m] (None: the strip's first and last columns, the straight free ends of the
    capstan): their summed force [N] and mean unit direction."""

    s = np.empty(model.spring_count)
    f = np.empty(model.spring_count)
    spring_strains_tensions(pos, *model.spring_args(), s, f)
    warp = model.spring_family == SpringFamily.WARP
    a, b = model.spring_nodes[warp].T
    xm = 0.5 * (model.rest_positions[a, 0] + model.rest_positions[b, 0])
    out = []
    for x in ((xm.min(), xm.max()) if xs is None else xs):
        sel = np.isclose(xm, xm[np.argmin(np.abs(xm - x))])
        d = pos[b[sel]] - pos[a[sel]]
        d = (d / np.linalg.norm(d, axis=1)[:, None]).mean(axis=0)
        out.append((float(f[warp][sel].sum()), d / np.linalg.norm(d)))
    return out


def turn_angle(d1, d2) -> float:
    """The angle [rad] a strip turns through from direction d1 to direction d2 in the x-z plane
    (the capstan's wrap phi between its straight ends)."""
    return (math.atan2(d1[2], d1[0]) - math.atan2(d2[2], d2[0])) % (2 * math.pi)


def end_tensions(model, pos):
    """[(T, d)] for the strip's first and last columns of warp springs (:func:`column_tensions`)."""
    return column_tensions(model, pos)


def _cpu(fn):
    """(fn's value, CPU seconds it took)."""
    c0 = time.process_time()
    v = fn()
    return v, time.process_time() - c0


def _wu(seconds: float, ref: float) -> float:
    return seconds / ref if ref > 0 else math.nan


def capstan_row(nx: int) -> dict:
    """The capstan at ``nx`` divisions along the strip (see the module docstring)."""

    over = [f"fabric.divisions=[{nx},{max(2, nx // 20)}]", "solver.method=newton", "solver.e=1e-7"]
    sc = load_scene(ROOT / "configs" / "cylinder_wrap.yaml", over)

    def draped():
        model = compile_model(sc)
        state = compile_state(sc, model)
        assert solve(model, state, sc.solver).converged
        return model, state

    def pull(model, state):
        target = model.prescribed_positions.copy()
        right = model.fixed_axes[:, 2] & (model.rest_positions[:, 0] > 0.1)
        target[right, 2] -= CAPSTAN_PULL
        return target

    # the frictionless solve of the pulled scene from its compiled start (twice: the first warms)
    model, state = draped()
    target = pull(model, state)
    pulled = dataclasses.replace(model, prescribed_positions=target)
    for _ in range(2):
        st = compile_state(sc, model)
        st.positions[pulled.fixed_axes] = target[pulled.fixed_axes]
        res0, t_free = _cpu(lambda: solve(pulled, st, sc.solver))
    assert res0.converged, res0.message
    ref = reference_pass_time(model, state.positions)
    # the frictional pull (twice: the first warms the friction kernels)
    for _ in range(2):
        model, state = draped()
        controls = load_steps(model.prescribed_positions, target, CAPSTAN_STEPS)
        (_, res), t_fric = _cpu(lambda: solve_steps(dataclasses.replace(model, friction_mu=MU_CAPSTAN), state,
                                                    controls, sc.solver))
    assert res.converged, res.message
    (tl, dl), (tr, dr) = end_tensions(model, state.positions)
    phi = turn_angle(dl, dr)
    steps = res.friction["steps"]
    per = [s["seconds"] for s in steps]
    return {"scene": f"capstan {nx} x {max(2, nx // 20)}", "nodes": int(model.node_count),
            "ref_pass_s": ref, "free_s": t_free, "free_it": int(res0.iterations),
            "fric_total_s": t_fric, "fric_it": int(res.iterations), "steps": len(steps),
            "step_mean_s": t_fric / len(steps), "step_max_wall_s": max(per), "step_mean_wall_s": float(np.mean(per)),
            "refreshes": int(res.friction["refreshes"]), "stick": res.friction["stick"], "slip": res.friction["slip"],
            "cone_violation": res.friction["cone_violation"], "phi": phi, "ratio": tr / tl,
            "capstan_error": tr / tl / math.exp(MU_CAPSTAN * phi) - 1.0}


def cone_row() -> dict:
    """The tube on the leg cone (see the module docstring)."""

    sc = load_scene(ROOT / "configs" / "tube_on_leg_cone.yaml",
                    ["constraints.1.displacement=[0,0,0]", "fabric.divisions=[34,16]", "solver.e=3e-6",
                     "solver.time_limit_s=300"])
    for _ in range(2):
        model = compile_model(sc)
        state = compile_state(sc, model)
        res0, t_free = _cpu(lambda: solve(model, state, sc.solver))
        assert res0.converged, res0.message
        fixed = model.fixed_axes.copy()
        fixed[:, 2] = False  # the cuffs let go along the leg
        m = dataclasses.replace(model, fixed_axes=fixed, friction_mu=MU_CONE)
        (_, res), t_fric = _cpu(lambda: solve_steps(m, state, [Control(m.prescribed_positions)], sc.solver))
    assert res.converged, res.message
    ref = reference_pass_time(model, state.positions)
    return {"scene": "tube on leg cone 34 x 16", "nodes": int(model.node_count), "ref_pass_s": ref,
            "free_s": t_free, "free_it": int(res0.iterations), "fric_total_s": t_fric, "fric_it": int(res.iterations),
            "steps": 1, "step_mean_s": t_fric, "refreshes": int(res.friction["refreshes"]),
            "stick": res.friction["stick"], "slip": res.friction["slip"],
            "cone_violation": res.friction["cone_violation"]}


def stocking_row() -> dict:
    """The stocking with friction's relax stage against the frictionless stocking's solve."""

    for _ in range(2):  # the first of each warms the kernels of the leg's surface
        free = Simulation(load_scene(ROOT / "configs" / "garments" / "stocking.yaml"))
        res0, t_free = _cpu(free.run)
        assert res0.converged, res0.message
    for _ in range(2):
        sim = Simulation(load_scene(ROOT / "configs" / "garments" / "stocking_friction.yaml"))
        res, t_all = _cpu(sim.run)
        assert res.converged, res.message
    ref = reference_pass_time(sim.model, sim.state.positions)
    relax = res.friction["stages"][-1]["friction"]
    per = [s["seconds"] for s in relax["steps"]]
    # the relax stage's CPU time: the whole run's, less the "on" stage's share of the wall time
    on = res.friction["stages"][0]["friction"]["steps"]
    wall_on = sum(s["seconds"] for s in on)
    share = sum(per) / max(sum(per) + wall_on, 1e-12)
    t_relax = t_all * share
    return {"scene": "stocking with friction (relax)", "nodes": int(sim.model.node_count), "ref_pass_s": ref,
            "free_s": t_free, "free_it": int(res0.iterations), "fric_total_s": t_relax,
            "fric_it": int(res.friction["stages"][-1]["iterations"]), "steps": len(per),
            "step_mean_s": t_relax / len(per), "step_max_s": t_relax * max(per) / sum(per),
            "refreshes": int(relax["refreshes"]), "stick": relax["stick"], "slip": relax["slip"],
            "cone_violation": relax["cone_violation"]}


def table(rows: list[dict]) -> list[str]:
    """The markdown table of the rows: seconds (work units)."""
    def tw(s, ref):
        return f"{s:.3g} s ({_wu(s, ref):,.0f} WU)"

    out = ["| scene | nodes | frictionless solve | frictional load step (mean) | largest step | "
           "load steps, Newton iterations, refreshes | mean step / solve | largest step / solve | "
           "stick / slip, cone violation |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ref = r["ref_pass_s"]
        big = r.get("step_max_s")
        if big is None and "step_max_wall_s" in r:  # CPU time shared out as the steps' wall times
            big = r["fric_total_s"] * r["step_max_wall_s"] / max(r["step_mean_wall_s"] * r["steps"], 1e-12)
        out.append(f"| {r['scene']} | {r['nodes']} | {tw(r['free_s'], ref)}, {r['free_it']} it | "
                   f"{tw(r['step_mean_s'], ref)} | {tw(big, ref) if big is not None else '-'} | "
                   f"{r['steps']}, {r['fric_it']}, {r['refreshes']} | {r['step_mean_s'] / r['free_s']:.2f} | "
                   f"{(big if big is not None else r['step_mean_s']) / r['free_s']:.2f} | "
                   f"{r['stick']} / {r['slip']}, {r['cone_violation']:.1e} |")
    return out


def capstan_table(rows: list[dict]) -> list[str]:
    out = ["| divisions | nodes | wrap angle phi [rad] | T_right / T_left | e^(mu phi) | error |",
           "|---|---|---|---|---|---|"]
    for r in rows:
        if "capstan_error" in r:
            out.append(f"| {r['scene'].removeprefix('capstan ')} | {r['nodes']} | {r['phi']:.4f} | {r['ratio']:.4f} | "
                       f"{math.exp(MU_CAPSTAN * r['phi']):.4f} | {r['capstan_error']:+.1e} |")
    return out


def run(out: str | Path, log=None, stocking: bool = True) -> list[dict]:
    """Measure every row, write ``benchmarks_friction.md`` and ``.json`` into ``out``."""

    t0 = time.perf_counter()
    rows = []
    jobs = [(capstan_row, (nx,)) for nx in CAPSTAN_DIVISIONS] + [(cone_row, ())]
    if stocking:
        jobs.append((stocking_row, ()))
    for fn, args in jobs:
        r = fn(*args)
        rows.append(r)
        if log:
            log(f"{r['scene']:34s} solve {r['free_s']:.3f} s  step {r['step_mean_s']:.3f} s  "
                f"ratio {r['step_mean_s'] / r['free_s']:.2f}"
                + (f"  capstan error {r['capstan_error']:+.1e}" if "capstan_error" in r else ""))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    info = machine_info()
    lines = ["# Friction benchmark", "",
             f"`python app.py bench --friction` ({time.perf_counter() - t0:.0f} s; {info.get('cpu', '')}, "
             f"{info.get('cores', '')} cores). CPU seconds of one process with warm kernels, and work units "
             "(WU: the time over one reference force pass over the scene's springs, measured in the same "
             f"process). Target: a frictional load step at most {TARGET_RATIO:g} x the frictionless solve "
             "of the same scene. See `clothsim/bench/friction.py` for what each row solves.", ""]
    lines += table(rows) + ["", "The capstan's tension ratio against Euler-Eytelwein's e^(mu phi), mu = 0.3, "
                                "pulled past slip:", ""] + capstan_table(rows) + [""]

    atomic_write_bytes(out / "benchmarks_friction.md", "\n".join(lines).encode())
    atomic_write_bytes(out / "benchmarks_friction.json", json.dumps({"machine": info, "rows": rows}, indent=1).encode())
    return rows


def main(args) -> int:
    out = getattr(args, "out", None) or "results/bench"
    run(out, log=lambda s: print(s, flush=True), stocking=not getattr(args, "quick", False))
    print(f"wrote {Path(out) / 'benchmarks_friction.md'}")
    return 0
