"""The stocking's reported pressure profile along the leg, frictionless against dressed with friction
(docs/method/friction.md, The stocking with friction): 1 cm slices from the ankle to below the knee.

    python scripts/stocking_profile.py docs/stocking_friction_profile.png

solves configs/garments/stocking.yaml (its profile in 1 cm slices) and
configs/garments/stocking_friction.yaml, and prints per slice the reported profile (summary.json's
girth mean: the integral of pressure round the slice over the fabric's girth on the leg, nodes
within 0.5 mm of it without reaction counting at zero, clothsim/compression/probes.py) of each,
Laplace's estimate T 2 pi / girth from the slice's course strain and girth (T the course table's
tension at the mean course strain of the springs within 5 mm of the slice, per current width:
divided by 1 + the wale strain there; round a closed course the integral of T kappa is T 2 pi), the
contact mean (over the contact length alone) beside it, and the figures issue 30 asks for: the
largest difference of neighbouring slices over the smaller, the lowest wale strain and the share
of slack wale springs. Writes the plot to the given PNG and the figures beside it (.json).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def analyse(r) -> dict:
    from clothsim.kernels import spring_strains_tensions
    from clothsim.units import MMHG

    m, X = r.model, np.asarray(r.state.positions)
    strain = np.empty(len(m.spring_rest_length))
    force = np.empty_like(strain)
    spring_strains_tensions(X, *m.spring_args(), strain, force)
    mid = 0.5 * (X[m.spring_nodes[:, 0], 2] + X[m.spring_nodes[:, 1], 2])
    warp, weft = m.spring_family == 0, m.spring_family == 1
    tab = m.table_list[int(m.spring_table[warp][0])]
    s = r.summary()
    rows = []
    for sl in s["profiles"][0]["slices"]:
        h = sl["height_m"]
        ec = float(strain[warp & (np.abs(mid - h) <= 0.005)].mean())
        ew = float(strain[weft & (np.abs(mid - h) <= 0.005)].mean())
        T = float(np.interp(ec, tab.strain, tab.tension)) / (1 + ew)
        rows.append({"height_m": h, "girth_mean_mmhg": sl["girth_mean_mmhg"], "mean_mmhg": sl["mean_mmhg"],
                     "course_strain": ec, "wale_strain": ew, "girth_m": sl["girth_m"],
                     "contact_length_m": sl["contact_length_m"],
                     "laplace_mmhg": T * 2 * np.pi / sl["girth_m"] / MMHG})

    def jumps(key):
        v = np.array([x[key] for x in rows])
        return np.abs(np.diff(v)) / np.minimum(v[:-1], v[1:])

    g = np.array([x["girth_mean_mmhg"] for x in rows])
    lap = np.array([x["laplace_mmhg"] for x in rows])
    return {"slices": rows, "max_neighbour_jump": float(jumps("girth_mean_mmhg").max()),
            "neighbour_jumps_over_10pct": int((jumps("girth_mean_mmhg") > 0.10).sum()),
            "contact_mean_max_neighbour_jump": float(jumps("mean_mmhg").max()),
            "contact_mean_jumps_over_10pct": int((jumps("mean_mmhg") > 0.10).sum()),
            "off_laplace_over_10pct": int((np.abs(g / lap - 1) > 0.10).sum()),
            "median_off_laplace": float(np.median(np.abs(g / lap - 1))),
            "max_off_laplace": float(np.abs(g / lap - 1).max()),
            "out_of_contact_share_max": float(max(1 - x["contact_length_m"] / x["girth_m"] for x in rows)),
            "min_wale_strain": float(strain[weft].min()),
            "wale_below_minus_10pct": int((strain[weft] < -0.10).sum()),
            "slack_wale_share": float((strain[weft] <= 0).mean()),
            "iterations": int(r.solve.iterations), "converged": bool(r.solve.converged),
            "probes": {p["name"]: p["pressure_mmhg"] for p in s["probes"]},
            "gradient": s["profiles"][0]["gradient"].get("note"),
            "friction": {k: v for k, v in (s.get("friction") or {}).items() if k != "steps"}}


def plot(a: dict, b: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 5.6), dpi=110)
    for d, label, c in ((a, "frictionless", "tab:red"), (b, "with friction (mu = 0.4)", "tab:blue")):
        h = [100 * x["height_m"] for x in d["slices"]]
        ax.plot([x["girth_mean_mmhg"] for x in d["slices"]], h, "o-", color=c, ms=4, label=f"{label}: reported (girth mean)")
        ax.plot([x["laplace_mmhg"] for x in d["slices"]], h, "--", color=c, alpha=0.7,
                label=f"{label}: Laplace T 2 pi / girth")
    h = [100 * x["height_m"] for x in b["slices"]]
    ax.plot([x["mean_mmhg"] for x in b["slices"]], h, ":", color="0.4", lw=1.2,
            label="with friction: mean over the contact length only")
    ax.set_xlabel("pressure [mmHg]")
    ax.set_ylabel("height above the sole [cm]")
    ax.set_title("Stocking on the scanned leg: reported profile, 1 cm slices", fontsize=10)
    ax.set_xlim(0, None)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7.5, loc="lower left")
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
    print(f"{'z [cm]':>6} | {'frictionless':>12} {'Laplace':>8} {'contact':>8} | {'friction':>9} {'Laplace':>8} "
          f"{'contact':>8} {'course':>7} {'wale':>7} {'contact/girth [cm]':>18}")
    for x, y in zip(res["frictionless"]["slices"], res["friction"]["slices"]):
        print(f"{100 * x['height_m']:6.0f} | {x['girth_mean_mmhg']:12.1f} {x['laplace_mmhg']:8.1f} {x['mean_mmhg']:8.1f} | "
              f"{y['girth_mean_mmhg']:9.1f} {y['laplace_mmhg']:8.1f} {y['mean_mmhg']:8.1f} {y['course_strain']:7.3f} "
              f"{y['wale_strain']:7.3f} {100 * y['contact_length_m']:8.1f} / {100 * y['girth_m']:.1f}")
    plot(res["frictionless"], res["friction"], Path(out))
    Path(out).with_suffix(".json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/stocking_friction_profile.png")
