"""Per-phase CPU cost of the Newton iterations on one scan-campaign case (diagnostics): every kernel
and method the iteration calls is wrapped by a timer (exclusive time: a phase's time excludes the
phases it calls), and the table gives ms per iteration and work units per iteration by phase.
The timers add ~1 us per call. Best of --repeat whole solves (each in the same process, after one
untimed warm-up solve).

    PYTHONPATH=$PWD python scripts/newton_phases.py smpl_man 1.20 [--repeat 3] [--plain]

--plain: no phase timers (the whole solve's CPU ms/it and WU/it only).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

WRAP_FUNCS = ("_query_nodes", "_projectors_q", "_free_distances_q", "_residual_q", "_apply_pi", "_assemble",
              "_curvature_blocks", "_diag_traces", "_complete_queries", "_project_system",
              "_block_infeasible_q", "_block_entering", "_trial_positions_sd", "_contact_faces_q", "_same",
              "_all_finite", "_dot", "forces_and_energy")
WRAP_METHODS = ("iterate", "_line_search", "_solve_linear", "residual", "queries", "energy_forces", "_accept")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("body")
    ap.add_argument("height", type=float)
    ap.add_argument("--surface", default="faceted")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--plain", action="store_true")
    a = ap.parse_args(argv)

    from clothsim import bench
    from clothsim.solvers import solve
    from clothsim.solvers.newton import iteration

    case = bench.Case("phases", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path(a.body), a.height, a.surface), ("newton",))
    model, state0, settings = bench._load(case, "newton", bench.TARGET_E, None, bench.SCAN_MAX_ITERATIONS)
    settings = settings.model_copy(update={"time_limit_s": None})
    solve(model, state0.copy(), settings)  # warm-up (compilation)
    ref_s = bench.reference_pass_time(model, state0.positions)

    acc: dict[str, float] = {}
    calls: dict[str, int] = {}
    stack: list[list] = []

    def timed(name, fn):
        def w(*args, **kw):
            stack.append([name, 0.0])
            t0 = time.process_time()
            try:
                return fn(*args, **kw)
            finally:
                dt = time.process_time() - t0
                _, inner = stack.pop()
                acc[name] = acc.get(name, 0.0) + dt - inner
                calls[name] = calls.get(name, 0) + 1
                if stack:
                    stack[-1][1] += dt
        return w

    if not a.plain:
        for f in WRAP_FUNCS:
            if hasattr(iteration, f):
                setattr(iteration, f, timed(f, getattr(iteration, f)))
        for mname in WRAP_METHODS:
            setattr(iteration.NewtonLevel, mname, timed("." + mname, getattr(iteration.NewtonLevel, mname)))

    best = None
    for _ in range(a.repeat):
        acc.clear()
        calls.clear()
        state = state0.copy()
        c0 = time.process_time()
        res = solve(model, state, settings)
        cpu = time.process_time() - c0
        if best is None or cpu < best[0]:
            best = (cpu, res, dict(acc), dict(calls))
    cpu, res, acc_b, calls_b = best
    it = max(res.iterations, 1)
    print(f"{a.body} y={a.height:.2f} {a.surface}: {res.status} in {res.iterations} iterations, residual "
          f"{res.residual:.2e} N; reference pass {1e6 * ref_s:.1f} us")
    print(f"whole solve: {1e3 * cpu / it:.2f} ms/it CPU, {cpu / ref_s / it:.0f} WU/it (best of {a.repeat})")
    if a.plain:
        return
    tot = sum(acc_b.values())
    print(f"{'phase':24s} {'ms/it':>7s} {'WU/it':>7s} {'share':>6s} {'calls/it':>9s}")
    for k, v in sorted(acc_b.items(), key=lambda kv: -kv[1]):
        print(f"{k:24s} {1e3 * v / it:7.3f} {v / ref_s / it:7.1f} {100 * v / tot:5.1f}% {calls_b[k] / it:9.2f}")
    print(f"{'(timed total)':24s} {1e3 * tot / it:7.3f} {tot / ref_s / it:7.1f}")


if __name__ == "__main__":
    main()
