"""Contact pressure under lattice refinement: the node peak, the sensor peak and facet stripes
(issue 12 item 1; docs/pressure_convergence.md).

Per run it prints (JSON lines): iterations, contact nodes, the node pressure's peak and 95th
percentile over the contact nodes, the same for the sensor reading (results.sensor_pressure, a
5 mm disc) and a stripe index (below). With --profile it also prints the pressure along the
lattice line through the node peak, across the lift-off line.

Stripe index: over interior contact nodes (the node and its two neighbours along a lattice line
in contact, none of them next to a free node), the median of |p[i-1] - 2 p[i] + p[i+1]| / p[i]
along warp and weft lines. A smooth field gives a few 1e-3 (its second difference over a cell);
stripes along the facets of a mesh give O(0.1).

    PYTHONPATH=. python scripts/pressure_convergence.py thermoform --divisions 80 160 320
    PYTHONPATH=. python scripts/pressure_convergence.py stocking --scale 1 2
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import clothsim
from clothsim.results import MMHG, SENSOR_RADIUS_M, pressure_area, sensor_pressure

ROOT = Path(__file__).resolve().parents[1]


def stripe_index(model, p: np.ndarray, c: np.ndarray) -> float:
    """The median relative second difference of the pressure p (N,) [Pa] along lattice lines over
    interior contact nodes (c (N,) bool: in contact)."""
    topo = model.topology
    vals = []
    for panel in range(topo.panel_count):
        P = topo.to_grid(np.where(c, p, np.nan), panel)
        ok = np.isfinite(P) & (P > 0)
        for ax in (0, 1):
            Q, O = (P, ok) if ax == 0 else (P.T, ok.T)
            inner = O[:-2] & O[1:-1] & O[2:]
            # and none of the three next to a free node across the line
            if Q.shape[1] > 2:
                side = np.zeros_like(O)
                side[:, 1:-1] = O[:, :-2] & O[:, 2:]
                inner &= side[:-2] & side[1:-1] & side[2:]
            d2 = np.abs(Q[:-2] - 2 * Q[1:-1] + Q[2:]) / Q[1:-1]
            vals.append(d2[inner])
    v = np.concatenate(vals) if vals else np.empty(0)
    return float(np.median(v)) if v.size else float("nan")


def measure(scene, label: dict, profile: bool = False) -> dict:
    t0 = time.perf_counter()
    res = clothsim.solve(scene)
    wall = time.perf_counter() - t0
    m, x, c = res.model, res.state.positions, res.state.in_contact
    f = np.asarray(res._f()[2])
    p = np.asarray(res._f()[3])
    ok = c & np.isfinite(p) & (f > 0)
    if not ok.any():   # every loaded contact node gathered into a rope: no pressure (a line load)
        return dict(label, converged=bool(res.converged), iterations=int(res.solve.iterations),
                    wall_s=round(wall, 1), nodes=int(m.node_count), contact_nodes=int(c.sum()),
                    note="no defined contact pressure: " + str(res.diagnostics().get("contact_pressure_note")))
    S = sensor_pressure(x, np.where(np.isfinite(f), f, 0.0), pressure_area(m, x), np.nonzero(ok)[0])
    row = dict(label, converged=bool(res.converged), iterations=int(res.solve.iterations),
               wall_s=round(wall, 1), nodes=int(m.node_count), contact_nodes=int(c.sum()),
               node_peak_mmhg=float(p[ok].max() / MMHG), node_p95_mmhg=float(np.percentile(p[ok], 95) / MMHG),
               sensor_peak_mmhg=float(S.max() / MMHG), sensor_p95_mmhg=float(np.percentile(S, 95) / MMHG),
               sensor_radius_m=SENSOR_RADIUS_M, stripe_index=stripe_index(m, p, c),
               total_force_n=float(f[np.isfinite(f)].sum()))
    if profile and m.topology.is_grid:
        k = int(np.argmax(np.where(ok, p, 0)))
        i, j = m.topology.node_ij[k]
        X, P, C = (m.topology.to_grid(a) for a in (x, p, c))
        lo, hi = max(0, i - 8), min(X.shape[0] - 1, i + 8)
        row["profile_through_peak"] = [[round(float(X[ii, j, 0]) * 1e3, 3), int(C[ii, j]),
                                        round(float(P[ii, j]) / MMHG, 3)] for ii in range(lo, hi + 1)]
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("case", choices=["thermoform", "stocking"])
    ap.add_argument("--divisions", type=int, nargs="+", default=[80, 160], help="thermoform: n for n x n")
    ap.add_argument("--scale", type=int, nargs="+", default=[1, 2], help="stocking: the panels' divisions x this")
    ap.add_argument("--surfaces", nargs="+", default=["smooth", "faceted"])
    ap.add_argument("--profile", action="store_true")
    a = ap.parse_args()
    for surface in a.surfaces:
        if a.case == "thermoform":
            for n in a.divisions:
                scene = clothsim.load_scene(ROOT / "configs" / "thermoform.yaml",
                                            [f"fabric.divisions=[{n},{n}]", f"mold.surface={surface}"])
                print(json.dumps(measure(scene, {"case": "thermoform", "surface": surface, "divisions": n},
                                         a.profile)), flush=True)
        else:
            for k in a.scale:
                scene = clothsim.load_scene(ROOT / "configs" / "garments" / "stocking.yaml",
                                            [f"panels.0.divisions=[{14 * k},{30 * k}]",
                                             f"panels.1.divisions=[{14 * k},{30 * k}]",
                                             f"mold.surface={surface}", "solver.method=newton"])
                print(json.dumps(measure(scene, {"case": "stocking", "surface": surface,
                                                 "divisions": f"2 x {14 * k}x{30 * k}"})), flush=True)


if __name__ == "__main__":
    main()
