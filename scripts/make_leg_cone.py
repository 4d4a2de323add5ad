"""Generate static/molds/leg_cone.stl: a conical lower leg for the compression examples
(deterministic; authored here).

    python scripts/make_leg_cone.py [--out static/molds]

A closed frustum on the z axis from z = -0.02 (radius 0.034 m) to z = 0.18 (radius 0.044 m):
r(z) = 0.035 + 0.05 z, so the ankle (z = 0) is 22 cm round and z = 0.16 is 27 cm round (the leg
above the ankle, gently tapered); 360 facets round (the facets' chord error, r (1 - cos(pi / 360)), is under 2 micrometres).
Outward normals, metres.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]


def frustum(r0: float, slope: float, z0: float, z1: float, n: int = 360) -> trimesh.Trimesh:
    """r(z) = r0 + slope z from z0 to z1, capped, n facets round."""
    th = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    V = [[(r0 + slope * z) * np.cos(t), (r0 + slope * z) * np.sin(t), z] for z in (z0, z1) for t in th]
    V += [[0.0, 0.0, z0], [0.0, 0.0, z1]]
    F = []
    for k in range(n):
        a, b = k, (k + 1) % n
        F += [[a, b, n + b], [a, n + b, n + a], [2 * n, b, a], [2 * n + 1, n + a, n + b]]
    return trimesh.Trimesh(np.array(V), np.array(F), process=False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "static" / "molds"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mesh = frustum(0.035, 0.05, -0.02, 0.18)
    assert mesh.is_watertight and mesh.volume > 0
    mesh.export(out / "leg_cone.stl")
    print(f"wrote {out / 'leg_cone.stl'}")


if __name__ == "__main__":
    main()
