"""Contact pressure under lattice refinement: the node peak, the sensor peak and facet stripes
(issue 12 item 1; docs/method/pressure_convergence.md).

Per run it prints (JSON lines): iterations, contact nodes, the node pressure's peak and 95th
percentile over the contact nodes, the same for the sensor reading (pressure.sensor_pressure, a
5 mm disc) and a stripe index (below). With --profile it also prints the pressure along the
lattice line through the node peak, across the lift-off line.

Stripe index: over interior contact nodes (the node and its two neighbours along a lattice line
in contact, none of them next to a free node), the median of |p[i-1] - 2 p[i] + p[i+1]| / p[i]
along warp and weft lines. A smooth field gives a few 1e-3 (its second difference over a cell);
stripes along the facets of a mesh give O(0.1).

    PYTHONPATH=. python scripts/pressure_convergence.py thermoform --divisions 80 160 320
    PYTHONPATH=. python scripts/pressure_convergence.py stocking --scale 1 2
    PYTHONPATH=. python scripts/pressure_convergence.py calf_band --divisions 80 160

calf_band (configs/garments/calf_band.yaml): n divisions round the leg, n / 4 along it (square
cells), the held column at i = n / 2. Besides the whole band's figures it prints the same figures
over the band's interior (nodes at least INTERIOR_M of rest length from the held top and bottom
rows; the sensors centred there still sum every node's force) and where the node and sensor peaks
sit (height z, angle round the leg's axis from +x towards +y, rest distance from the nearer held
row).
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import clothsim
from clothsim.pressure import MMHG, SENSOR_RADIUS_M, max_sensor_pressure, pressure_area, sensor_pressure

ROOT = Path(__file__).resolve().parents[1]

#: calf_band: the interior is the band at least this rest distance [m] from its held edge rows
INTERIOR_M = 0.01
#: calf_band: a point on the leg's axis (the config's wrap_hull centre) [m]
LEG_AXIS = (-0.104, 0.034)


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


def _where(x: np.ndarray, edge_m: np.ndarray, k: int) -> dict:
    """Where node k sits on the calf band: height z [m], angle round the leg's axis [deg] and rest
    distance from the nearer held row [m]."""
    ang = np.degrees(np.arctan2(x[k, 1] - LEG_AXIS[1], x[k, 0] - LEG_AXIS[0]))
    return {"z_m": round(float(x[k, 2]), 4), "angle_deg": round(float(ang), 1),
            "from_edge_m": round(float(edge_m[k]), 4)}


def band_readings(res, p: np.ndarray, ok: np.ndarray, S: np.ndarray, F: np.ndarray, A: np.ndarray) -> dict:
    """The calf band's interior readings and where its peaks sit (see the module docstring).
    p (N,) node pressure [Pa]; ok (N,) bool: contact nodes with a pressure;
    S: the sensor reading [Pa] at each of np.nonzero(ok)[0]; F, A (N,): the node reactions [N]
    and areas [m^2] (the interior sensor peak is searched between the interior's nodes too,
    pressure.max_sensor_pressure; its place is the node with the largest node-centred reading)."""
    m, x = res.model, res.state.positions
    ly = float(res.scene.fabric.size[1])
    ny = int(res.scene.fabric.divisions[1])
    v = m.topology.node_ij[:, 1] * (ly / ny)
    edge_m = np.minimum(v, ly - v)
    centers = np.nonzero(ok)[0]
    inner = edge_m[centers] >= INTERIOR_M - 1e-12
    kn = int(np.argmax(np.where(ok, p, -np.inf)))
    ks = int(centers[np.argmax(S)])
    pin = p[centers[inner]]
    Sin = S[inner]
    kin = int(centers[inner][np.argmax(pin)])
    ksin = int(centers[inner][np.argmax(Sin)])
    return {"interior_m": INTERIOR_M, "interior_nodes": int(inner.sum()),
            "interior_node_peak_mmhg": float(pin.max() / MMHG),
            "interior_node_p95_mmhg": float(np.percentile(pin, 95) / MMHG),
            "interior_sensor_peak_mmhg": float(max_sensor_pressure(x, F, A, centers[inner], m.topology.cells) / MMHG),
            "interior_sensor_p95_mmhg": float(np.percentile(Sin, 95) / MMHG),
            "node_peak_at": _where(x, edge_m, kn), "sensor_peak_at": _where(x, edge_m, ks),
            "interior_node_peak_at": _where(x, edge_m, kin), "interior_sensor_peak_at": _where(x, edge_m, ksin)}


def measure(scene, label: dict, profile: bool = False, band: bool = False) -> dict:
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
    F, A = np.where(np.isfinite(f), f, 0.0), pressure_area(m, x)
    S = sensor_pressure(x, F, A, np.nonzero(ok)[0])
    row = dict(label, converged=bool(res.converged), iterations=int(res.solve.iterations),
               residual_n=float(res.solve.residual), wall_s=round(wall, 1), nodes=int(m.node_count), contact_nodes=int(c.sum()),
               node_peak_mmhg=float(p[ok].max() / MMHG), node_p95_mmhg=float(np.percentile(p[ok], 95) / MMHG),
               sensor_peak_mmhg=float(max_sensor_pressure(x, F, A, np.nonzero(ok)[0], m.topology.cells) / MMHG),
               sensor_node_peak_mmhg=float(S.max() / MMHG), sensor_p95_mmhg=float(np.percentile(S, 95) / MMHG),
               sensor_radius_m=SENSOR_RADIUS_M, stripe_index=stripe_index(m, p, c),
               total_force_n=float(f[np.isfinite(f)].sum()))
    if band:
        row.update(band_readings(res, p, ok, S, F, A))
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
    ap.add_argument("case", choices=["thermoform", "stocking", "calf_band"])
    ap.add_argument("--divisions", type=int, nargs="+", default=[80, 160], help="thermoform: n for n x n; calf_band: n round the leg")
    ap.add_argument("--scale", type=int, nargs="+", default=[1, 2], help="stocking: the panels' divisions x this")
    ap.add_argument("--surfaces", nargs="+", default=["smooth", "faceted"])
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--no-stretch", action="store_true",
                    help="calf_band: the edge rows held where they start (no 5 %% stretch along the leg)")
    a = ap.parse_args()
    for surface in a.surfaces:
        if a.case == "thermoform":
            for n in a.divisions:
                scene = clothsim.load_scene(ROOT / "configs" / "thermoform.yaml",
                                            [f"fabric.divisions=[{n},{n}]", f"mold.surface={surface}"])
                print(json.dumps(measure(scene, {"case": "thermoform", "surface": surface, "divisions": n},
                                         a.profile)), flush=True)
        elif a.case == "calf_band":
            for n in a.divisions:
                scene = clothsim.load_scene(ROOT / "configs" / "garments" / "calf_band.yaml",
                                            [f"fabric.divisions=[{n},{n // 4}]",
                                             f"mold.surface={surface}", "solver.time_limit_s=3600"]
                                            + (["constraints.0.displacement=[0,0,0]", "constraints.1.displacement=[0,0,0]"]
                                               if a.no_stretch else []))
                print(json.dumps(measure(scene, {"case": "calf_band", "surface": surface,
                                                 "divisions": f"{n}x{n // 4}", "stretch": not a.no_stretch},
                                         a.profile, band=True)), flush=True)
        else:
            for k in a.scale:
                scene = clothsim.load_scene(ROOT / "configs" / "garments" / "stocking.yaml",
                                            [f"panels.0.divisions=[{14 * k},{30 * k}]",
                                             f"panels.1.divisions=[{14 * k},{30 * k}]",
                                             # the ankle's single-node seams name the bottom row's
                                             # end columns (the held middle column is i: 50%)
                                             f"seams.2.a.i={11 * k}", f"seams.2.b.i={3 * k}",
                                             f"seams.3.a.i={11 * k}", f"seams.3.b.i={3 * k}",
                                             f"mold.surface={surface}", "solver.method=newton"])
                print(json.dumps(measure(scene, {"case": "stocking", "surface": surface,
                                                 "divisions": f"2 x {14 * k}x{30 * k}"})), flush=True)


if __name__ == "__main__":
    main()
