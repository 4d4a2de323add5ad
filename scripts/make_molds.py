"""Generate the bundled molds in static/molds/ (deterministic; authored here, nothing copied).

    python scripts/make_molds.py [--out static/molds]

Writes
* ``thermoform_mold.stl``: a thermoforming mold under a 0.10 x 0.10 m sheet lying at z = 0 over
  x, y in [0, 0.1]: a super-elliptic plate (x, y within [0.015, 0.085], top at z = -0.005,
  bottom at z = -0.015) carrying a rounded super-elliptic dome 0.06 m across whose top reaches
  z = 0.02, with a groove across the top along y (non-convex). Closed, outward normals, metres.
* ``thermoform_mold.txt``: a coarser version in the paper's text format (``index x y z`` point
  lines, then ``n1 n2 n3`` triangle lines, 1-based).
* ``torso.stl``: a parametric female torso from the hips (z = 0) to the shoulders (z = 0.6),
  body axis +z, centred on the z axis; girths: hip 0.95 m (z = 0.08), waist 0.70 m (z = 0.30),
  bust 0.90 m (z = 0.47). Stacked cross-sections (ellipse x bust / seat terms, each rescaled to
  the target girth), lofted and capped. Closed, outward normals, metres.
* ``pyramid.vtk``: a tiny legacy-VTK example (square pyramid; the base is one quad, fanned on
  load into two triangles).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh
from scipy.interpolate import PchipInterpolator

ROOT = Path(__file__).resolve().parents[1]

# ---- thermoforming mold --------------------------------------------------------------------
SHEET_CENTER = (0.05, 0.05)
PLATE_HALF = 0.035        # plate reaches x, y in [0.015, 0.085]
DOME_HALF = 0.030         # dome 0.06 m across
PLATE_TOP = -0.005
PLATE_BOTTOM = -0.015
DOME_TOP = 0.020
SUPER_N = 4.0             # plan shape |x|^n + |y|^n = r^n (rounded square)
DOME_P = 2.5              # profile z = PLATE_TOP + H (1 - s^p)^(1/p)
GROOVE_DEPTH = 0.004
GROOVE_HALF_WIDTH = 0.004


def _super_radius(theta: np.ndarray, n: float = SUPER_N) -> np.ndarray:
    """Radius of the unit super-ellipse |x|^n + |y|^n = 1 in direction theta."""
    return (np.abs(np.cos(theta)) ** n + np.abs(np.sin(theta)) ** n) ** (-1.0 / n)


def _dome_height(x: np.ndarray, y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Top surface over the dome footprint; s in [0, 1] is the normalised super-elliptic radius."""
    H = DOME_TOP - PLATE_TOP
    base = PLATE_TOP + H * np.clip(1.0 - s ** DOME_P, 0.0, None) ** (1.0 / DOME_P)
    fade = np.clip(1.0 - (s / 0.8) ** 2, 0.0, None) ** 2          # groove fades out before the foot
    groove = GROOVE_DEPTH * np.exp(-0.5 * ((x - SHEET_CENTER[0]) / GROOVE_HALF_WIDTH) ** 2) * fade
    return base - groove


def _polar_solid(n_theta: int, s_rings: np.ndarray, z_of, plate_outer: float):
    """Closed mesh: centre vertex, rings at normalised radius s (dome), flange ring, wall, bottom.

    ``z_of(x, y, s)`` gives the top height on the dome rings; the outer ring of the dome sits at
    s = 1, the flange ring at ``plate_outer`` (relative to the dome half-width) on PLATE_TOP.
    """
    cx, cy = SHEET_CENTER
    th = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
    rs = _super_radius(th)
    verts = [[cx, cy, float(z_of(np.array(cx), np.array(cy), np.array(0.0)))]]
    rings = []
    for s in s_rings:
        x = cx + DOME_HALF * s * rs * np.cos(th)
        y = cy + DOME_HALF * s * rs * np.sin(th)
        z = z_of(x, y, np.full_like(x, s))
        rings.append(len(verts))
        verts.extend(np.column_stack([x, y, z]).tolist())
    for z in (PLATE_TOP, PLATE_BOTTOM):   # flange edge (top), then wall bottom
        x = cx + DOME_HALF * plate_outer * rs * np.cos(th)
        y = cy + DOME_HALF * plate_outer * rs * np.sin(th)
        rings.append(len(verts))
        verts.extend(np.column_stack([x, y, np.full_like(x, z)]).tolist())
    bottom_center = len(verts)
    verts.append([cx, cy, PLATE_BOTTOM])
    faces = []
    j = np.arange(n_theta)
    jn = (j + 1) % n_theta
    r0 = rings[0]
    faces += np.column_stack([np.zeros(n_theta, int), r0 + j, r0 + jn]).tolist()
    for a, b in zip(rings[:-1], rings[1:]):
        faces += np.column_stack([a + j, b + j, b + jn]).tolist()
        faces += np.column_stack([a + j, b + jn, a + jn]).tolist()
    rl = rings[-1]
    faces += np.column_stack([np.full(n_theta, bottom_center), rl + jn, rl + j]).tolist()
    m = trimesh.Trimesh(np.asarray(verts), np.asarray(faces), process=False)
    if m.volume < 0:
        m.invert()
    return m


def thermoform_mold(n_theta: int = 160, n_rings: int = 36) -> trimesh.Trimesh:
    # rings denser near the dome's steep foot (s -> 1): s = sin(pi/2 * u)
    u = np.linspace(0.0, 1.0, n_rings + 1)[1:]
    s_rings = np.sin(0.5 * np.pi * u)
    m = _polar_solid(n_theta, s_rings, _dome_height, PLATE_HALF / DOME_HALF)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    return m


# ---- torso ---------------------------------------------------------------------------------
TORSO_HEIGHT = 0.60
# target girth [m] at height z [m]: hip maximum, waist minimum, bust maximum
GIRTH_KNOTS = [(0.00, 0.92), (0.08, 0.95), (0.19, 0.84), (0.30, 0.70), (0.39, 0.78),
               (0.47, 0.90), (0.535, 0.85), (0.60, 0.87)]
# half-width / half-depth of the base ellipse
ASPECT_KNOTS = [(0.00, 1.40), (0.08, 1.38), (0.30, 1.30), (0.47, 1.25), (0.60, 1.55)]


def _section_shape(theta: np.ndarray, z: float) -> np.ndarray:
    """Unscaled polar radius of the cross-section at height z (front = +y, left = +x)."""
    aspect = float(PchipInterpolator(*zip(*ASPECT_KNOTS))(z))
    a, b = aspect, 1.0
    r = a * b / np.sqrt((b * np.cos(theta)) ** 2 + (a * np.sin(theta)) ** 2)

    def bump(center, width):
        d = np.angle(np.exp(1j * (theta - center)))
        return np.exp(-0.5 * (d / width) ** 2)

    bust = 0.16 * np.exp(-0.5 * ((z - 0.47) / 0.045) ** 2)
    seat = 0.08 * np.exp(-0.5 * ((z - 0.09) / 0.06) ** 2)
    r = r * (1.0 + bust * (bump(np.radians(90 - 24), 0.32) + bump(np.radians(90 + 24), 0.32))
             + seat * (bump(np.radians(270 - 30), 0.45) + bump(np.radians(270 + 30), 0.45)))
    return r


def _perimeter(x: np.ndarray, y: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(np.r_[x, x[0]]), np.diff(np.r_[y, y[0]]))))


def torso(n_theta: int = 144, n_z: int = 90) -> trimesh.Trimesh:
    girth = PchipInterpolator(*zip(*GIRTH_KNOTS))
    th = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)
    zs = np.linspace(0.0, TORSO_HEIGHT, n_z)
    zs = np.unique(np.r_[zs, [k[0] for k in GIRTH_KNOTS]])  # sections exactly at the knots
    fine = np.linspace(0.0, 2 * np.pi, 2048, endpoint=False)
    verts = []
    for z in zs:
        rf = _section_shape(fine, z)
        scale = float(girth(z)) / _perimeter(rf * np.cos(fine), rf * np.sin(fine))
        r = scale * _section_shape(th, z)
        verts.append(np.column_stack([r * np.cos(th), r * np.sin(th), np.full(n_theta, z)]))
    V = np.concatenate(verts + [np.array([[0.0, 0.0, 0.0], [0.0, 0.0, TORSO_HEIGHT]])])
    nz = len(zs)
    j = np.arange(n_theta)
    jn = (j + 1) % n_theta
    F = []
    for k in range(nz - 1):
        a, b = k * n_theta, (k + 1) * n_theta
        F.append(np.column_stack([a + j, a + jn, b + jn]))
        F.append(np.column_stack([a + j, b + jn, b + j]))
    bot, top = nz * n_theta, nz * n_theta + 1
    F.append(np.column_stack([np.full(n_theta, bot), jn, j]))
    last = (nz - 1) * n_theta
    F.append(np.column_stack([np.full(n_theta, top), last + j, last + jn]))
    m = trimesh.Trimesh(V, np.concatenate(F), process=False)
    if m.volume < 0:
        m.invert()
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    return m


# ---- writers -------------------------------------------------------------------------------

def write_paper_text(m: trimesh.Trimesh, path: Path) -> None:
    """The paper's format: 1-based ``index x y z`` lines, then ``n1 n2 n3`` lines."""
    lines = ["# clothsim thermoforming mold (coarse), paper text format, metres, 1-based",
             f"# {len(m.vertices)} points, then {len(m.faces)} triangles"]
    lines += [f"{i + 1} {x:.9g} {y:.9g} {z:.9g}" for i, (x, y, z) in enumerate(m.vertices)]
    lines += [f"{a + 1} {b + 1} {c + 1}" for a, b, c in m.faces]
    path.write_text("\n".join(lines) + "\n")


PYRAMID_VTK = """# vtk DataFile Version 3.0
clothsim example: square pyramid 0.04 x 0.04 m base at z = -0.01, apex at z = 0.02
ASCII
DATASET POLYDATA
POINTS 5 double
0.03 0.03 -0.01
0.07 0.03 -0.01
0.07 0.07 -0.01
0.03 0.07 -0.01
0.05 0.05 0.02
POLYGONS 5 21
4 0 3 2 1
3 0 1 4
3 1 2 4
3 2 3 4
3 3 0 4
"""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "static" / "molds")
    args = ap.parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    tm = thermoform_mold()
    tm.export(out / "thermoform_mold.stl")
    write_paper_text(thermoform_mold(n_theta=48, n_rings=12), out / "thermoform_mold.txt")
    to = torso()
    to.export(out / "torso.stl")
    (out / "pyramid.vtk").write_text(PYRAMID_VTK)
    for name, m in (("thermoform_mold.stl", tm), ("torso.stl", to)):
        print(f"{name}: {len(m.faces)} triangles, bounds {np.round(m.bounds, 4).tolist()}, "
              f"volume {m.volume:.4g} m^3, convex hull {m.convex_hull.volume:.4g} m^3")


if __name__ == "__main__":
    main()
