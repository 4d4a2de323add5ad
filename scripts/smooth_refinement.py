"""Contact pressure under lattice refinement, faceted vs smooth mesh surface (issue 12 item 1).

Runs configs/thermoform.yaml (or the scene given) at several divisions with mold.surface faceted
and smooth and prints, per run: iterations, peak and 95th-percentile contact pressure [mmHg]
over the contact nodes, total contact force [N] and the relaxation time [s].

    PYTHONPATH=. python scripts/smooth_refinement.py [scene.yaml] --divisions 40 80 160
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import clothsim

MMHG = 133.322387415


def run(scene_path, n, surface, extra=()):
    scene = clothsim.load_scene(scene_path, [f"fabric.divisions=[{n},{n}]", f"mold.surface={surface}", *extra])
    t0 = time.perf_counter()
    res = clothsim.solve(scene)
    wall = time.perf_counter() - t0
    p = np.asarray(res.contact_pressure).ravel()
    f = np.asarray(res.contact_force).ravel()
    c = np.asarray(res.in_contact).ravel()
    pc = p[c & np.isfinite(p)]
    return {"divisions": n, "surface": surface, "converged": bool(res.converged),
            "iterations": int(res.solve.iterations), "contact_nodes": int(c.sum()),
            "peak_mmhg": float(pc.max() / MMHG) if len(pc) else None,
            "p95_mmhg": float(np.percentile(pc, 95) / MMHG) if len(pc) else None,
            "total_force_n": float(f[np.isfinite(f)].sum()), "wall_s": wall}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", nargs="?", default=str(Path(__file__).resolve().parents[1] / "configs" / "thermoform.yaml"))
    ap.add_argument("--divisions", type=int, nargs="+", default=[40, 80, 160])
    ap.add_argument("--surfaces", nargs="+", default=["faceted", "smooth"])
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    for surface in a.surfaces:
        for n in a.divisions:
            print(json.dumps(run(a.scene, n, surface, a.set)), flush=True)


if __name__ == "__main__":
    main()
