"""Time per mold query [us], faceted vs smooth mesh surface, on a mesh file (issue 12 item 1).

Points are drawn near the surface (within half the smoothing radius: where contact nodes are);
each surface is timed on the same points after a warm-up (JIT). Prints one JSON line per surface,
with the plain-force-pass work unit of ``app.py bench`` not applying here (these are per-query
costs; the solver-level cost is in ``app.py bench``).

    PYTHONPATH=. python scripts/smooth_query_timing.py static/molds/thermoform_mold.stl
"""

import argparse
import json
import time

import numpy as np

from clothsim.mold import load_mold, mold_query_many, mold_segment_hit


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mesh")
    ap.add_argument("--points", type=int, default=20000)
    a = ap.parse_args()
    smooth = load_mold({"path": a.mesh, "surface": "smooth"})
    faceted = load_mold({"path": a.mesh, "surface": "faceted"})
    V = smooth.vertices
    rng = np.random.default_rng(0)
    n = a.points
    P = V[rng.integers(0, len(V), n)] + rng.normal(scale=0.5 * smooth.smoothing / np.sqrt(3), size=(n, 3))
    Q = P + rng.normal(scale=0.5 * smooth.smoothing / np.sqrt(3), size=(n, 3))
    for name, mold in (("faceted", faceted), ("smooth", smooth)):
        ma = mold.kernel_args()
        sd, cp, nr, ft = np.empty(n), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2), np.int64)
        mold_query_many(ma, P[:10], sd[:10], cp[:10], nr[:10], ft[:10])
        mold_segment_hit(ma, P[0], Q[0])
        t0 = time.perf_counter()
        mold_query_many(ma, P, sd, cp, nr, ft)
        tq = (time.perf_counter() - t0) / n * 1e6
        m = min(n, 5000)
        t0 = time.perf_counter()
        for i in range(m):
            mold_segment_hit(ma, P[i], Q[i])
        ts = (time.perf_counter() - t0) / m * 1e6
        print(json.dumps({"mesh": a.mesh, "surface": name, "faces": len(mold.faces),
                          "smoothing_m": mold.smoothing, "query_us": round(tq, 2),
                          "segment_hit_us_incl_python_call": round(ts, 2)}), flush=True)


if __name__ == "__main__":
    main()
