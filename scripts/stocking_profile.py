"""The stocking's girth-mean pressure along the leg, frictionless against dressed with friction
(docs/method/friction.md, The stocking with friction): 1 cm slices from the ankle to below the knee.

    python scripts/stocking_profile.py docs/stocking_friction_profile.png

solves configs/garments/stocking.yaml (its profile in 1 cm slices) and
configs/garments/stocking_friction.yaml, and prints per slice the girth-mean pressure of each,
Laplace's estimate T / r from the slice's course strain and girth (T the course table's tension at
the mean course strain of the springs within 5 mm of the slice, per current width: divided by
1 + the wale strain there; r = girth / 2 pi, the girth the slice's contact length), and the
figures issue 30 asks for: the largest difference of neighbouring slices over the smaller, the
lowest wale strain and the share of slack wale springs. Beside the profile's mean (over the
slice's contact length) it gives the mean over the whole course (the same integral of pressure
over the fabric's girth, the length of the plane's cut through the garment: stretches off the leg
or without reaction count at zero) and its Laplace estimate T 2 pi / that girth (the integral of
T kappa round a closed course is T 2 pi, however much of it carries no pressure). Writes the plot to the given PNG.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MMHG = 133.322


def analyse(r) -> dict:
    m, X = r.model, np.asarray(r.state.positions)
    from clothsim.kernels import spring_strains_tensions

    strain = np.empty(len(m.spring_rest_length))
    force = np.empty_like(strain)
    spring_strains_tensions(X, *m.spring_args(), strain, force)
    mid = 0.5 * (X[m.spring_nodes[:, 0], 2] + X[m.spring_nodes[:, 1], 2])
    warp, weft = m.spring_family == 0, m.spring_family == 1
    tab = m.table_list[int(m.spring_table[warp][0])]
    from clothsim.compression.probes import _cut, _finite_pressure

    pressure, _ = _finite_pressure(np.asarray(r._f()[3], float))
    rows = []
    for sl in r.summary()["profiles"][0]["slices"]:
        h = sl["height_m"]
        near_c = warp & (np.abs(mid - h) <= 0.005)
        near_w = weft & (np.abs(mid - h) <= 0.005)
        ec = float(strain[near_c].mean())
        ew = float(strain[near_w].mean())
        girth = sl["contact_length_m"]
        T = float(np.interp(ec, tab.strain, tab.tension)) / (1 + ew)
        ends, (pe,) = _cut(X, m.topology.faces, X[:, 2] - h, [pressure])
        seg = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        fabric = float(seg.sum())
        rows.append({"height_m": h, "mean_mmhg": sl["mean_mmhg"], "course_strain": ec, "wale_strain": ew,
                     "girth_m": girth, "laplace_mmhg": T * 2 * np.pi / girth / MMHG if girth > 0 else None,
                     "fabric_girth_m": fabric, "course_mean_mmhg": float((seg * pe.mean(axis=1)).sum()) / fabric / MMHG,
                     "course_laplace_mmhg": T * 2 * np.pi / fabric / MMHG})
    p = np.array([x["mean_mmhg"] for x in rows])
    jump = np.abs(np.diff(p)) / np.minimum(p[:-1], p[1:])
    q = np.array([x["course_mean_mmhg"] for x in rows])
    qjump = np.abs(np.diff(q)) / np.minimum(q[:-1], q[1:])
    lap = np.array([x["laplace_mmhg"] for x in rows])
    qlap = np.array([x["course_laplace_mmhg"] for x in rows])
    s = r.summary()
    return {"slices": rows, "max_neighbour_jump": float(jump.max()),
            "neighbour_jumps_over_10pct": int((jump > 0.10).sum()),
            "course_mean_max_neighbour_jump": float(qjump.max()),
            "course_mean_jumps_over_10pct": int((qjump > 0.10).sum()),
            "off_laplace_over_10pct": int((np.abs(p / lap - 1) > 0.10).sum()),
            "median_off_laplace": float(np.median(np.abs(p / lap - 1))),
            "course_mean_max_off_laplace": float(np.abs(q / qlap - 1).max()),
            "out_of_contact_share_max": float(max(1 - x["girth_m"] / x["fabric_girth_m"] for x in rows)),
            "min_wale_strain": float(strain[weft].min()),
            "wale_below_minus_10pct": int((strain[weft] < -0.10).sum()),
            "slack_wale_share": float((strain[weft] <= 0).mean()),
            "iterations": int(r.solve.iterations), "converged": bool(r.solve.converged),
            "probes": {p["name"]: p["pressure_mmhg"] for p in s["probes"]},
            "friction": {k: v for k, v in (s.get("friction") or {}).items() if k != "steps"}}


def plot(a: dict, b: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10.4, 5.4), dpi=110, sharey=True)
    for ax, key, lap, title in ((axes[0], "mean_mmhg", "laplace_mmhg", "mean over the contact length"),
                                (axes[1], "course_mean_mmhg", "course_laplace_mmhg", "mean over the whole course")):
        for d, label, c in ((a, "frictionless", "tab:red"), (b, "with friction (mu = 0.4)", "tab:blue")):
            h = [100 * x["height_m"] for x in d["slices"]]
            ax.plot([x[key] for x in d["slices"]], h, "o-", color=c, ms=4, label=f"{label}")
            ax.plot([x[lap] for x in d["slices"]], h, "--", color=c, alpha=0.7, label=f"{label}: Laplace T / r")
        ax.set_xlabel("pressure [mmHg]")
        ax.set_title(f"{title}, 1 cm slices", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("height above the sole [cm]")
    fig.suptitle("Stocking on the scanned leg (row ends on the outline)", fontsize=11)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp)
    tmp.replace(path)


def main(out: str) -> None:
    import clothsim

    res = {}
    for key, scene, over in (("frictionless", "configs/garments/stocking.yaml", ["profiles.0.step=0.01"]),
                             ("friction", "configs/garments/stocking_friction.yaml", [])):
        t = time.perf_counter()
        r = clothsim.solve(clothsim.load_scene(ROOT / scene, over))
        res[key] = analyse(r)
        res[key]["seconds"] = time.perf_counter() - t
        print(key, json.dumps({k: v for k, v in res[key].items() if k != "slices"}), flush=True)
    print(f"{'z [cm]':>6} | {'frictionless':>12} {'Laplace':>8} {'course':>7} {'wale':>7} | "
          f"{'friction':>9} {'Laplace':>8} {'course':>7} {'wale':>7} {'contact':>7} {'girth':>6} "
          f"{'course mean':>11} {'Laplace':>8}")
    for x, y in zip(res["frictionless"]["slices"], res["friction"]["slices"]):
        print(f"{100 * x['height_m']:6.0f} | {x['mean_mmhg']:12.1f} {x['laplace_mmhg']:8.1f} {x['course_strain']:7.3f} "
              f"{x['wale_strain']:7.3f} | {y['mean_mmhg']:9.1f} {y['laplace_mmhg']:8.1f} {y['course_strain']:7.3f} "
              f"{y['wale_strain']:7.3f} {100 * y['girth_m']:7.1f} {100 * y['fabric_girth_m']:6.1f} "
              f"{y['course_mean_mmhg']:11.1f} {y['course_laplace_mmhg']:8.1f}")
    plot(res["frictionless"], res["friction"], Path(out))
    Path(out).with_suffix(".json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/stocking_friction_profile.png")
