"""The standard's measuring levels on a body, and a stocking's pressure read there as the
standards read it.

**Levels.** On a limb built from a size chart (``mold: {leg: ...}``) the chart's levels are the
levels: their heights, and their girths exact (the perimeter of the smooth section's convex
hull, as on a scan; the outline's own length beside it). On a mesh
(a scan) the chosen leg is cut by horizontal planes every 2.5 mm (trimesh plane sections); at
each height the closed loop round the leg is the one holding the seed point (``levels.center``,
then the loop's own centroid below, so the cut follows the leg's axis up), until the loops of
the two legs merge (a girth jump of more than 30 %: the crotch). Each loop's girth is the
perimeter of its convex hull: what a tape measure reads (it bridges the hollows between the
tendons); the loop's own length is reported beside it. Found, on the girths lightly smoothed
over 1 cm:

- B: the narrowest girth in the lowest 40 % of the leg (the ankle's narrowest, above the
  malleoli: the foot below is wider);
- C: the first widest girth above B (the girth has fallen 2 % below it above);
- D: the first narrowest girth above C (below the knee: it has risen 2 % above it above).

Other levels (B1, E, F, G, ...) are taken at given heights (``levels.heights``).

**Readings** per level (the standards' way: a girth mean and sensor discs on four sides):

- mean: the girth mean, the contact pressure integrated along the sheet's cut at the level's
  height over the fabric's girth on the body (the profile's slice girth mean,
  :func:`.probes.read_profile`; not the contact mean, which leaves out fabric lying on a flat);
- anterior, posterior, medial, lateral: a sensor disc (:func:`.probes.read_probe`, radius
  ``levels.radius``) centred on the body's surface point in that direction from the level's
  centre (the leg's axis; a loop's centroid on a scan);
- course strain: the strain of the warp (course) springs at the level's height, interpolated
  linearly between the rows of springs above and below it (hat weights over the median row
  spacing); the reduction on the body is then 100 e / (1 + e) per cent (a course of
  length girth (1 - reduction) stretched round the girth);
- per cent of B: the level's mean over B's, against the user's ``levels.gradient`` [min, max];
- B's girth mean classed under every known standard (``b_classes``).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from ..mold.leg import leg_girth, leg_loop_length, leg_radius
from .levelspec import SIDES
from .probes import read_probe, read_profile, reported_mmhg
from .spec import Probe, Profile
from .standards import classify_all

#: slices of a scan's leg [m]
SCAN_STEP = 0.0025
#: a girth that jumps by more than this share from the slice below ends the leg (the crotch)
MERGE_JUMP = 0.30
#: B is sought in the lowest share of the leg
B_SHARE = 0.4
#: C and D: the girth must fall (rise) this share past them to confirm them
CONFIRM = 0.02


class LevelError(ValueError):
    """Levels cannot be found or read (the message says which and why)."""


# ------------------------------------------------------------------------------------------
# girths on a mesh
# ------------------------------------------------------------------------------------------


def hull_girth(xy: np.ndarray) -> float:
    """The girth [m] a tape measure reads round a section's points ``xy`` (k, 2): the perimeter
    of their convex hull (it bridges the hollows). The one girth measurement of meshes: the
    levels here and a garment's sizing (:func:`clothsim.sizing.body_girth`) read it."""
    from shapely.geometry import MultiPoint

    return float(MultiPoint([tuple(p) for p in np.asarray(xy, float)]).convex_hull.length)


_hull_length = hull_girth


def section_loop(section, seed) -> tuple[np.ndarray | None, float]:
    """The loop of a mesh's plane section (trimesh's Path3D) round ``seed`` (x, y) [m], else the
    one whose mean is nearest to it: (its (k, 2) points, 0 or that distance [m]); (None, inf)
    when no loop has 4 points. The scan's girths here and the viewer's level rings read it."""
    from shapely.geometry import Point, Polygon

    best, best_d = None, math.inf
    for loop in section.discrete:
        xy = np.asarray(loop)[:, :2]
        if len(xy) < 4:
            continue
        poly = Polygon(xy)
        d = 0.0 if poly.is_valid and poly.contains(Point(*seed)) else float(np.linalg.norm(xy.mean(0) - seed))
        if d < best_d:
            best, best_d = xy, d
    return best, best_d


def scan_girths(vertices: np.ndarray, faces: np.ndarray, seed_xy, z_from: float | None = None,
                z_to: float | None = None, step: float = SCAN_STEP) -> dict:
    """The girths of one leg of a mesh along z: {z, girth (convex hull) [m], loop [m],
    centroid (n, 2) [m], loops (list of (k, 2) arrays)}, from the lowest slice holding the seed
    up to where the legs merge (see the module docstring)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    lo, hi = mesh.bounds[:, 2]
    z0 = lo + step if z_from is None else max(z_from, lo + step)
    z1 = hi - step if z_to is None else min(z_to, hi - step)
    seed = np.asarray(seed_xy, float)
    out = {"z": [], "girth": [], "loop": [], "centroid": [], "loops": []}
    for z in np.arange(z0, z1 + 0.5 * step, step):
        sec = mesh.section(plane_origin=[0.0, 0.0, float(z)], plane_normal=[0.0, 0.0, 1.0])
        if sec is None:
            if out["z"]:
                break
            continue
        best, best_d = section_loop(sec, seed)
        if best is None or (best_d > 0.05 and out["z"]):
            if len(out["z"]) >= 8:
                break
            # lost within the first 2 cm: a toe's or heel's island held the seed; start again
            out = {k: [] for k in out}
            seed = np.asarray(seed_xy, float)
            continue
        if best_d > 0.0 and not out["z"]:
            continue  # below the leg: no loop round the seed yet
        g = _hull_length(best)
        if out["girth"] and g > (1.0 + MERGE_JUMP) * out["girth"][-1]:
            break
        L = float(np.linalg.norm(np.diff(np.vstack([best, best[:1]]), axis=0), axis=1).sum())
        c = best.mean(0)
        out["z"].append(float(z))
        out["girth"].append(g)
        out["loop"].append(L)
        out["centroid"].append(c)
        out["loops"].append(best)
        seed = c
    if len(out["z"]) < 5:
        raise LevelError(f"no leg found round the point {list(np.round(np.asarray(seed_xy, float), 4))} "
                         f"(levels.center: a point inside the leg's section at the ankle)")
    for k in ("z", "girth", "loop", "centroid"):
        out[k] = np.asarray(out[k], float)
    return out


def find_levels(z: np.ndarray, girth: np.ndarray, names=("B", "C", "D")) -> dict:
    """{name: index into z} of the levels found on a girth profile (module docstring); a level
    that cannot be confirmed is left out."""
    g = np.convolve(np.pad(girth, 2, mode="edge"), np.ones(5) / 5, mode="valid")   # 1 cm at 2.5 mm
    n = len(z)
    top = z[0] + B_SHARE * (z[-1] - z[0])
    low = np.nonzero(z <= top)[0]
    found: dict = {}
    if len(low) < 3:
        return found
    b = int(low[np.argmin(g[low])])
    found["B"] = b
    c = None
    k = b
    best = b
    while k + 1 < n:
        k += 1
        if g[k] > g[best]:
            best = k
        elif g[k] < (1.0 - CONFIRM) * g[best]:
            c = best
            break
    if c is None:
        return {x: v for x, v in found.items() if x in names}
    found["C"] = c
    k = c
    best = c
    while k + 1 < n:
        k += 1
        if g[k] < g[best]:
            best = k
        elif g[k] > (1.0 + CONFIRM) * g[best]:
            found["D"] = best
            break
    return {x: v for x, v in found.items() if x in names}


# ------------------------------------------------------------------------------------------
# the level set of a scene
# ------------------------------------------------------------------------------------------


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _ray_exit(xy: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The farthest point where the ray c + s d (s > 0) crosses the closed loop xy (k, 2)."""
    best, best_s = None, -1.0
    P = np.vstack([xy, xy[:1]])
    for a, b in zip(P[:-1], P[1:]):
        e = b - a
        den = d[0] * (-e[1]) + d[1] * e[0]
        if den == 0.0:
            continue
        w = a - c
        s = (w[0] * (-e[1]) + w[1] * e[0]) / den
        u = (d[0] * w[1] - d[1] * w[0]) / den
        if s > 0 and 0.0 <= u <= 1.0 and s > best_s:
            best, best_s = c + s * d, s
    return best if best is not None else c


def level_set(scene, mold) -> dict:
    """The scene's measuring levels on its mold: {"source": "chart" | "scan", "levels": [{name,
    z_m, height_m (above the floor; a scan's lowest point), girth_m, loop_m, how ("chart",
    "found", "given"), center (x, y), sides {side: [x, y, z] on the body}}]} sorted by height,
    "anterior", "medial" (x, y). Raises LevelError when the scene asks for levels it cannot
    place."""
    spec = getattr(scene, "levels", None)
    leg = getattr(getattr(scene, "mold", None), "leg", None)
    given = dict(spec.heights) if spec is not None else {}
    out = []
    if leg is not None:

        if spec is not None and (spec.center or spec.anterior or spec.medial or spec.find):
            raise LevelError("levels: center, anterior, medial and find come from the leg's chart; "
                             "leave them out (heights may add levels)")
        prm = mold.params
        a, m = _unit(leg.anterior), _unit(leg.medial)
        cen = np.asarray(leg.center, float)
        rows = [(k, leg.floor + lv.height_cm / 100.0, "chart") for k, lv in leg.levels.items() if k not in given]
        rows += [(k, float(h), "given") for k, h in given.items()]
        for name, z, how in rows:
            sides = {}
            for side, d in zip(SIDES, (a, -a, m, -m)):
                t = math.atan2(d[1], d[0])
                r = leg_radius(prm, z, t)[0]
                sides[side] = [float(cen[0] + r * d[0]), float(cen[1] + r * d[1]), float(z)]
            g = leg_girth(prm, z)
            out.append({"name": name, "z_m": float(z), "height_m": float(z - leg.floor), "girth_m": g,
                        "loop_m": leg_loop_length(prm, z),
                        "how": how, "center": cen.tolist(), "sides": sides})
        out.sort(key=lambda r: r["z_m"])
        return {"source": "chart", "levels": out, "anterior": a.tolist(), "medial": m.tolist()}
    if spec is None:
        return {"source": None, "levels": []}
    if mold is None or spec.center is None:
        raise LevelError("levels.center: give a point (x, y) inside the leg's section at the ankle "
                         "(the levels of a scan are found round it)")
    V, F = mold.surface_mesh()
    prof = scan_girths(V, F, spec.center)
    floor = float(np.asarray(V)[:, 2].min())
    a = _unit(spec.anterior if spec.anterior is not None else (0.0, -1.0))
    m = _unit(spec.medial) if spec.medial is not None else np.array([-math.copysign(1.0, spec.center[0]), 0.0])
    want = list(spec.find) if spec.find is not None else ["B", "C", "D"]
    idx = find_levels(prof["z"], prof["girth"], want)
    missing = [k for k in want if k not in idx and k not in given]
    if missing:
        raise LevelError(f"levels.find: {', '.join(missing)} not found on the leg's girths (between "
                         f"{prof['z'][0]:.3f} and {prof['z'][-1]:.3f} m); give their heights in levels.heights")
    rows = [(k, int(i), "found") for k, i in idx.items() if k not in given]
    for k, h in given.items():
        i = int(np.argmin(np.abs(prof["z"] - h)))
        if abs(prof["z"][i] - h) > SCAN_STEP:
            raise LevelError(f"levels.heights.{k}: {h} m is off the leg (its slices run from "
                             f"{prof['z'][0]:.3f} to {prof['z'][-1]:.3f} m)")
        rows.append((k, i, "given"))
    for name, i, how in rows:
        z = float(prof["z"][i])
        loop = prof["loops"][i]
        c = prof["centroid"][i]
        sides = {side: [*map(float, _ray_exit(loop, c, d)), z] for side, d in zip(SIDES, (a, -a, m, -m))}
        out.append({"name": name, "z_m": z, "height_m": z - floor, "girth_m": float(prof["girth"][i]),
                    "loop_m": float(prof["loop"][i]), "how": how, "center": c.tolist(), "sides": sides})
    out.sort(key=lambda r: r["z_m"])
    return {"source": "scan", "levels": out, "anterior": a.tolist(), "medial": m.tolist()}


def wants_levels(scene) -> bool:
    """Whether a scene's result reads levels: it has ``levels`` or a limb from a size chart."""
    return getattr(scene, "levels", None) is not None or getattr(getattr(scene, "mold", None), "leg", None) is not None


# ------------------------------------------------------------------------------------------
# readings
# ------------------------------------------------------------------------------------------


def _course_strain(model, positions, strain_warp, z: float) -> float | None:
    topo = model.topology
    X = np.asarray(positions, float)
    W = np.asarray(topo.warp)
    F = np.asarray(topo.weft)
    if not len(W) or not len(F):
        return None
    row = max(float(np.median(np.abs(X[F[:, 0], 2] - X[F[:, 1], 2]))), 1e-9)
    zm = 0.5 * (X[W[:, 0], 2] + X[W[:, 1], 2])
    # hat weights over a row's spacing: between two rows of springs, their strains linearly
    # interpolated to the level's height
    w = np.clip(1.0 - np.abs(zm - z) / row, 0.0, None)
    if not w.sum() > 0:
        return None
    return float((w * np.asarray(strain_warp)).sum() / w.sum())


def sensor_radius(scene) -> float:
    """The radius [m] of the levels' side sensors (``levels.radius``; 1 cm without)."""
    spec = getattr(scene, "levels", None)
    return spec.radius if spec is not None else 0.01


def read_level(model, positions, in_contact, pressure, lv: dict, radius: float, strain_warp=None,
               sides: bool = True) -> dict:
    """One level's reading (``lv``: a row of :func:`level_set`): {level, z_m, height_m, girth_m,
    loop_m, how, course_strain, reduction_pct, mean_mmhg, sides {side: mmHg}}. ``sides`` False
    leaves the four sensor discs out (``sides`` {}) and ``strain_warp`` None the course strain
    (None): what a fit needs of a level is its girth mean alone (:meth:`.readings.Readings.read`),
    read here by the same code as the full reading."""
    z = lv["z_m"]
    prof = read_profile(model, positions, in_contact, pressure,
                        Profile.model_validate({"name": lv["name"], "axis": "z", "from": z, "to": z, "step": 1.0}))
    # the girth mean (the profile's reported statistic, what a tape and sensor read round the
    # limb), not the contact mean, which leaves out fabric lying on a flat of the body
    mean = reported_mmhg(prof["slices"][0])
    read = {}
    for side, pt in (lv["sides"].items() if sides else ()):
        r = read_probe(model, positions, in_contact, pressure,
                       Probe(name=f"{lv['name']} {side}", point=tuple(pt), radius=radius))
        read[side] = r["pressure_mmhg"]
    e = _course_strain(model, positions, strain_warp, z) if strain_warp is not None else None
    return {"level": lv["name"], "z_m": z, "height_m": lv["height_m"], "girth_m": lv["girth_m"],
            "loop_m": lv["loop_m"], "how": lv["how"], "course_strain": e,
            "reduction_pct": None if e is None else 100.0 * e / (1.0 + e), "mean_mmhg": mean, "sides": read}


def read_levels(scene, model, positions, in_contact, pressure, strain_warp=None, lset=None) -> dict:
    """Per level: {level, z_m, height_m, girth_m, loop_m, how, course_strain, reduction_pct,
    mean_mmhg, sides {side: mmHg}, percent_of_b, required_percent, gradient_ok} and the
    gradient's verdict (module docstring). ``strain_warp`` (warp springs,) the course springs'
    strains (None: no strain, no reduction)."""

    lset = lset if lset is not None else level_set(scene, model.mold)
    spec = getattr(scene, "levels", None)
    radius = sensor_radius(scene)
    required = dict(spec.gradient) if spec is not None else {}
    rows = [read_level(model, positions, in_contact, pressure, lv, radius, strain_warp) for lv in lset["levels"]]
    b = next((r for r in rows if r["level"] == "B"), None)
    verdicts = []
    for r in rows:
        pb = None
        if b is not None and b["mean_mmhg"] and r["mean_mmhg"] is not None:
            pb = 100.0 * r["mean_mmhg"] / b["mean_mmhg"]
        r["percent_of_b"] = pb
        req = required.get(r["level"])
        r["required_percent"] = list(req) if req is not None else None
        r["gradient_ok"] = None if req is None or pb is None else bool(req[0] <= pb <= req[1])
        if r["gradient_ok"] is not None:
            verdicts.append(r["gradient_ok"])
    unknown = sorted(set(required) - {r["level"] for r in rows})
    unread = [r["level"] for r in rows if r["level"] in required and r["percent_of_b"] is None]
    note = ""
    if unknown:
        note = f"levels.gradient names levels the body does not have: {', '.join(unknown)}"
    elif required and b is None:
        note = "no level B: the gradient (per cent of B) cannot be read"
    elif unread:
        note = f"no pressure read at {', '.join(unread)} (no contact there): the gradient is not checked there"
    ok = (all(verdicts) if verdicts else None) if not unknown else False
    out = {"source": lset["source"], "levels": rows, "gradient_ok": ok, "note": note, "sensor_radius_m": radius}
    if b is not None and b["mean_mmhg"] is not None:
        # the class of B's girth mean under every known standard (and the scene's own)

        cl = getattr(scene, "classes", None)
        out["b_classes"] = classify_all(b["mean_mmhg"], cl.standards if cl else None, cl.extra if cl else None)
    return out


def level_point(lset: dict, level: str, side: str):
    """The body's surface point [m] of a level's side (a probe named by level and side), or a
    LevelError naming the levels there are."""
    for lv in lset["levels"]:
        if lv["name"] == level:
            return tuple(lv["sides"][side])
    names = ", ".join(lv["name"] for lv in lset["levels"]) or "none"
    raise LevelError(f"probe level '{level}': no such level (levels: {names})")


def levels_csv(readings: dict) -> str:
    """levels.csv: one row per level (see :data:`LEVELS_COLUMNS`)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(LEVELS_COLUMNS)
    f = lambda v, fmt: "" if v is None else format(v, fmt)  # noqa: E731
    for r in readings["levels"]:
        req = r["required_percent"]
        w.writerow([r["level"], f(r["height_m"] * 100, ".2f"), f(r["z_m"], ".5f"), f(r["girth_m"] * 100, ".2f"),
                    f(r["loop_m"] * 100, ".2f"), r["how"], f(r["course_strain"], ".4f"), f(r["reduction_pct"], ".2f"),
                    f(r["mean_mmhg"], ".3f"), *(f(r["sides"].get(s), ".3f") for s in SIDES),
                    f(r["percent_of_b"], ".1f"), "" if req is None else f"{req[0]:g}-{req[1]:g}",
                    "" if r["gradient_ok"] is None else int(r["gradient_ok"])])
    return buf.getvalue()


def levels_lines(lv: dict) -> list[str]:
    """The levels' readings as ``run`` prints them (one line per level, then the gradient and
    B's classes)."""
    if lv.get("error"):
        return [f"  levels: {lv['error']}"]
    f = lambda v: "     -" if v is None else f"{v:6.1f}"  # noqa: E731
    out = ["  levels (girth mean; anterior / posterior / medial / lateral sensors, mmHg):"]
    for r in lv["levels"]:
        sides = " / ".join(f(r["sides"].get(s)).strip() for s in SIDES)
        pct = "" if r["percent_of_b"] is None else f"  {r['percent_of_b']:.0f} % of B"
        req = r["required_percent"]
        if req is not None:
            ok = {True: "ok", False: "outside", None: "not read"}[r["gradient_ok"]]
            pct += f" (asked {req[0]:g}-{req[1]:g} %: {ok})"
        out.append(f"    {r['level']:<3} {r['height_m'] * 100:6.2f} cm  girth {r['girth_m'] * 100:6.2f} cm  "
                   f"mean {f(r['mean_mmhg'])}  sides {sides}{pct}")
    if lv.get("b_classes"):
        out.append("    B's girth mean: " + "; ".join(f"{c['standard']}: {c['class']}" for c in lv["b_classes"]))
    if lv.get("note"):
        out.append(f"    ({lv['note']})")
    return out


LEVELS_COLUMNS = ["level", "height_cm", "z_m", "girth_cm", "loop_cm", "how", "course_strain", "reduction_pct",
                  "mean_mmHg", "anterior_mmHg", "posterior_mmHg", "medial_mmHg", "lateral_mmHg", "percent_of_B",
                  "required_percent_of_B", "gradient_ok"]
