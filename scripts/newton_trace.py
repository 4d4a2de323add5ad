"""Per-iteration trace of the Newton solver (diagnostics): residual, energy, the line search's
accepted step length and trial count, the Levenberg shift, the contact set's churn (nodes entering
and leaving contact), the nodes released by the active set and those held by the blocking rules.

    PYTHONPATH=$PWD python scripts/newton_trace.py --scan smpl_man 1.08 [--surface smooth]
    PYTHONPATH=$PWD python scripts/newton_trace.py configs/garments/stocking.yaml [--set k=v ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--scan", nargs=2, metavar=("BODY", "HEIGHT"))
    ap.add_argument("--surface", default="faceted")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("-e", type=float, default=None)
    ap.add_argument("--max", type=int, default=400)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--param", action="append", default=[], help="field=value of clothsim.solvers.tuning.NewtonTuning, "
                    "e.g. hold_share=1")
    a = ap.parse_args(argv)

    from clothsim import bench
    from clothsim.solvers.newton import NewtonSolver, iteration
    from clothsim.solvers.options import newton_options

    if a.scan:
        case = bench.Case("trace", "configs/torso_band.yaml",
                          bench.scan_band_overrides(bench.scan_body_path(a.scan[0]), float(a.scan[1]), a.surface) + list(a.set),
                          ("newton",))
        e = a.e or bench.TARGET_E
    else:
        case = bench.Case("trace", str(Path(a.config).resolve().relative_to(ROOT)), list(a.set), ("newton",))
        e = a.e
    model, state, settings = bench._load(case, "newton", e or 1e-9, None)
    if e is None:
        from clothsim.config import load_scene
        e = load_scene(ROOT / case.config, list(case.overrides)).solver.e

    import ast
    from dataclasses import replace

    from clothsim.solvers.tuning import NewtonTuning

    tuning = NewtonTuning(**{k: ast.literal_eval(v) for k, v in (kv.split("=", 1) for kv in a.param)})

    rec = {}
    orig_ls = iteration.NewtonLevel._line_search
    orig_be = iteration._block_entering
    orig_bi = iteration._block_infeasible_q
    orig_tp = iteration._trial_positions_sd

    def ls(self, state, dx, E0, slope, v_base):
        rec["ls_calls"] = rec.get("ls_calls", 0) + 1
        rec["dxmax"] = float(np.abs(dx).max())
        return orig_ls(self, state, dx, E0, slope, v_base)

    def be(*args):
        n = orig_be(*args)
        rec["held"] = rec.get("held", 0) + n
        return n

    def bi(*args):
        n = orig_bi(*args)
        rec["blocked"] = rec.get("blocked", 0) + n
        return n

    def tp(*args):
        rec["trials"] = rec.get("trials", 0) + 1
        if args[8]:
            rec["clip_trials"] = rec.get("clip_trials", 0) + 1
        return orig_tp(*args)

    iteration.NewtonLevel._line_search = ls
    iteration._block_entering = be
    iteration._block_infeasible_q = bi
    iteration._trial_positions_sd = tp

    solver = NewtonSolver(model, replace(newton_options(settings), tuning=tuning))
    fine = solver.fine
    print(f"nodes {model.node_count}  e {e:g}")
    print(" it   residual N      energy J   alpha  trials clip   lm        |dx|max   in  out contact held blk  ms")
    t_all = time.process_time()
    alphas = []
    for it in range(a.max):
        rec.clear()
        c_before = state.in_contact.copy()
        t0 = time.process_time()
        rep = solver.step(state, 1, e=e)
        dt = 1e3 * (time.process_time() - t0)
        c_after = state.in_contact
        enter = int((~c_before & c_after).sum())
        leave = int((c_before & ~c_after).sum())
        r = rep.residual if rep.iterations else float("nan")
        En = rep.energies[-1] if rep.iterations else float("nan")
        alphas.append(fine.ls_alpha)
        if not a.quiet:
            print(f"{it:3d} {r:12.4e} {En:14.8e} {fine.ls_alpha:7.4f} {rec.get('trials', 0):4d} {rec.get('clip_trials', 0):4d} "
                  f"{fine.lm:9.1e} {rec.get('dxmax', 0):9.2e} {enter:4d} {leave:4d} {int(c_after.sum()):5d} "
                  f"{rec.get('held', 0):4d} {rec.get('blocked', 0):4d} {dt:6.1f}")
        if rep.status != "ok":
            print("status", rep.status)
            break
    tot = time.process_time() - t_all
    print(f"iterations {it + 1}  cpu {tot:.2f} s  {1e3 * tot / (it + 1):.1f} ms/it; alpha=1 in "
          f"{sum(1 for x in alphas if x >= 1)}; alpha<1 in {sum(1 for x in alphas if x < 1)}")


if __name__ == "__main__":
    main()
