"""What the viewer shows of the measuring levels (clothsim.compression.levels), computed from
(scene, model, positions, in_contact) without viser, so that the Levels panel runs it on a
thread of its own and tests call it directly:

- :func:`level_rings`: each level as a closed ring round the body at its height (the chart
  leg's exact section, or the scan's loop round the level's centre), pushed outwards by
  ``lift`` so that it shows over the garment lying on the body, with a label point in front;
- :func:`read_view`: the levels' readings (girth mean, four sides, per cent of B; the course
  strain and the reduction on the body) and the girth-mean profile from the lowest contact to
  the highest, both from the same pressure field;
- :func:`class_band`: the band [min, max] mmHg of the class B's girth mean falls in (or the
  nearest class) under the scene's first standard (RAL-GZ 387 by default);
- :func:`profile_series`: the arrays of the profile plot (heights in cm above the floor).
"""

from __future__ import annotations

import math

import numpy as np

from ..compression.levels import level_set, read_levels, section_loop
from ..compression.probes import read_profile
from ..compression.spec import Profile
from ..compression.standards import STANDARDS, standard
from ..kernels import spring_strains_tensions
from ..mold.leg import leg_radius
from .fields import contact_pressure

#: points on a ring
RING_POINTS = 96
#: the ring's distance outside the body [m] (a stocking is about a millimetre thick)
RING_LIFT = 0.003
#: the profile's slice spacing [m]
PROFILE_STEP = 0.005


def _ring_segments(pts: np.ndarray) -> np.ndarray:
    """(n, 3) points of a closed loop -> (n, 2, 3) segments."""
    return np.stack([pts, np.roll(pts, -1, axis=0)], axis=1)


def _chart_loop(mold, lv: dict, n: int) -> np.ndarray:
    cx, cy = lv["center"][:2]
    t = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    r = np.array([leg_radius(mold.params, lv["z_m"], float(a))[0] for a in t])
    return np.column_stack([cx + r * np.cos(t), cy + r * np.sin(t)])


def _scan_loop(mesh, lv: dict) -> np.ndarray | None:
    sec = mesh.section(plane_origin=[0.0, 0.0, lv["z_m"]], plane_normal=[0.0, 0.0, 1.0])
    if sec is None:
        return None
    return section_loop(sec, np.asarray(lv["center"][:2], float))[0]


def level_rings(scene, mold, lset: dict | None = None, n: int = RING_POINTS, lift: float = RING_LIFT) -> list[dict]:
    """[{name, z_m, girth_m, segments (k, 2, 3), label (3,)}] per level of the scene on ``mold``
    (empty when the scene has none): the body's section at the level's height, each point moved
    ``lift`` [m] away from the level's centre; the label sits on the anterior side, a centimetre
    out."""
    lset = lset if lset is not None else level_set(scene, mold)
    mesh = None
    out = []
    for lv in lset["levels"]:
        if lset["source"] == "chart":
            xy = _chart_loop(mold, lv, n)
        else:
            if mesh is None:
                import trimesh

                V, F = mold.surface_mesh()
                mesh = trimesh.Trimesh(np.asarray(V, float), np.asarray(F, np.int64), process=False)
            xy = _scan_loop(mesh, lv)
            if xy is None:
                continue
        c = np.asarray(lv["center"][:2], float)
        d = xy - c
        dist = np.linalg.norm(d, axis=1, keepdims=True)
        xy = xy + lift * d / np.where(dist > 0, dist, 1.0)
        pts = np.column_stack([xy, np.full(len(xy), lv["z_m"])])
        front = np.asarray(lv["sides"]["anterior"], float)
        a = front[:2] - c
        a = a / (np.linalg.norm(a) or 1.0)
        label = np.array([*(front[:2] + (lift + 0.01) * a), lv["z_m"]])
        out.append({"name": lv["name"], "z_m": float(lv["z_m"]), "girth_m": float(lv["girth_m"]),
                    "segments": _ring_segments(pts), "label": label})
    return out


def ring_label(ring: dict, reading: dict | None = None) -> str:
    """``B 22.4 cm`` (the level's girth), then `` · 27.1 mmHg`` once its girth mean is read."""
    text = f"{ring['name']} {ring['girth_m'] * 100:.1f} cm"
    if reading is not None and reading.get("mean_mmhg") is not None:
        text += f" · {reading['mean_mmhg']:.1f} mmHg"
    return text


def warp_strains(model, positions: np.ndarray) -> np.ndarray:
    """The warp (course) springs' engineering strains (as Result's)."""
    wc = model.warp_count
    strain = np.empty(wc)
    force = np.empty(wc)
    nodes, rest, width, table, *tabs = model.spring_args()
    spring_strains_tensions(positions, nodes[:wc], rest[:wc], width[:wc], table[:wc], *tabs, strain, force)
    return strain


def read_view(scene, model, positions: np.ndarray, in_contact: np.ndarray, lset: dict | None = None,
              step: float = PROFILE_STEP) -> dict:
    """{"levels": read_levels(...), "profile": read_profile(...) of the girth mean every ``step``
    [m] over the sheet's height, "floor": the body's floor height [m] (level heights are above
    it)}."""
    lset = lset if lset is not None else level_set(scene, model.mold)
    X = np.asarray(positions, float)
    p = contact_pressure(model, X, in_contact)
    lv = read_levels(scene, model, X, in_contact, p, warp_strains(model, X), lset)
    z = X[:, 2]
    lo, hi = float(z.min()), float(z.max())
    k = max(1, int(math.floor((hi - lo) / step)))
    prof = read_profile(model, X, in_contact, p, Profile.model_validate(
        {"name": "girth mean", "axis": "z", "from": lo + 0.5 * step, "to": lo + 0.5 * step + (k - 1) * step,
         "step": step}) if k > 1 else Profile.model_validate(
        {"name": "girth mean", "axis": "z", "from": 0.5 * (lo + hi), "to": 0.5 * (lo + hi), "step": 1.0}))
    levels = lset["levels"]
    floor = float(levels[0]["z_m"] - levels[0]["height_m"]) if levels else 0.0
    return {"levels": lv, "profile": prof, "floor": floor}


def class_band(b_mmhg: float | None, scene=None) -> dict | None:
    """{standard, class, min, max} [mmHg]: the class of the scene's first standard (``classes.
    standards``; RAL-GZ 387 by default) that B's girth mean falls in, else the nearest one; the
    open-ended top class's max is drawn at 1.25 x its min. None without a reading at B."""
    if b_mmhg is None or not math.isfinite(b_mmhg):
        return None
    cl = getattr(scene, "classes", None)
    names = getattr(cl, "standards", None) if cl is not None else None
    extra = getattr(cl, "extra", None) if cl is not None else None
    std = standard(names[0], extra) if names else (extra[0] if extra else STANDARDS[0])

    def gap(c) -> float:
        hi = math.inf if c.max is None else c.max
        return 0.0 if c.min <= b_mmhg <= hi else min(abs(b_mmhg - c.min), abs(b_mmhg - hi))

    c = min(std.classes, key=gap)
    return {"standard": std.name, "class": c.name, "min": float(c.min),
            "max": float(c.max if c.max is not None else 1.25 * c.min)}


def profile_series(view: dict, band: dict | None) -> tuple[np.ndarray, ...]:
    """The profile plot's arrays: (height [cm above the floor], girth mean [mmHg], the levels'
    girth means at their heights (NaN elsewhere), the class band's min, its max), sorted by
    height; the slices without contact are left out. Each level's height is one of the x's."""
    floor = view["floor"]
    pts = {}
    for s in view["profile"]["slices"]:
        if s["mean_mmhg"] is not None:
            pts[round((s["height_m"] - floor) * 100, 6)] = (s["mean_mmhg"], math.nan)
    for r in view["levels"]["levels"]:
        if r["mean_mmhg"] is not None:
            pts[round(r["height_m"] * 100, 6)] = (r["mean_mmhg"], r["mean_mmhg"])
    x = np.array(sorted(pts), float)
    y = np.array([pts[k][0] for k in sorted(pts)], float)
    m = np.array([pts[k][1] for k in sorted(pts)], float)
    # no band (no reading at B): both on the curve, drawn under it
    lo = np.full_like(x, band["min"]) if band else y.copy()
    hi = np.full_like(x, band["max"]) if band else y.copy()
    return x, y, m, lo, hi


def levels_table(view: dict, band: dict | None) -> str:
    """A markdown table per level: height, girth, girth mean, per cent of B (and the class band)."""
    rows = ["| level | cm up | girth cm | mmHg | % of B |", "|:---|---:|---:|---:|---:|"]
    f = lambda v, fmt: "–" if v is None else format(v, fmt)  # noqa: E731
    for r in view["levels"]["levels"]:
        rows.append(f"| {r['level']} | {r['height_m'] * 100:.1f} | {r['girth_m'] * 100:.1f} | "
                    f"{f(r['mean_mmhg'], '.1f')} | {f(r['percent_of_b'], '.0f')} |")
    text = "\n".join(rows)
    if band is not None:
        text += f"\n\nBand: {band['standard']} class {band['class']}, {band['min']:g}–{band['max']:g} mmHg at B"
    return text
