"""Sizing a garment: the scene field ``garment`` (panel scale, reduction, measuring levels and
grading), applied to the cut outlines before their lattices are built.

A garment's **circumference at a height** of its pattern is the sum of its panels' widths along
the grain (the course, round the limb) on that line: panels sewn side by side round the limb,
without seam allowances in the outlines (the ``fabric`` sheet sewn into a tube: its width).
Heights ``v`` on the pattern are measured across the grain from each panel's lowest point (the
hem).

A **measuring level** (``garment.levels``) names a height on the body (``height`` [m] along
``garment.axis``), the pattern height it falls on (``at`` [m]; default ``height - garment.hem``)
and the body's girth there (``girth`` [m]; omitted: measured on the mold, see :func:`body_girth`).
A level given by its ``name`` alone is one of the scene's measuring levels (a chart leg's
``mold: {leg: {levels: ...}}``, or ``levels:`` found on a scan; :mod:`clothsim.compression.levels`):
its height and girth are that level's (:func:`resolve_levels`), so the garment is sized against
the very girths the pressure is read at.

The outline is changed in three steps, each a width factor per level (linear in the pattern
height between levels, constant beyond the first and the last) and a map of heights:

1. **grading** (``garment.grading``): a size ``d`` steps from the base size adds ``d x
   girth_cm`` to the circumference at each ruled level (shared between the panels in proportion
   to their widths there) and ``d x length_cm`` to the height of that level above the hem (the
   heights between levels follow linearly; above the last level they shift by its increment);
2. **scale** (``garment.scale``): every width times ``width``, every height times ``length``;
3. **reduction** (``garment.reduction`` [%], or a level's own): the circumference at the level
   becomes ``girth x (1 - reduction / 100)`` -- the way compression stockings are specified. It
   replaces steps 1 and 2's width at that level (so it is refused together with a width scale).

Each outline vertex moves across the grain about the middle of its row (``u' = mid + f(v) (u -
mid)``) and along it by the height map; no vertex is added (seams name vertices by index), so a
circumference is exact at a level that lies at vertex heights of the panels' sides (or on a
straight-sided panel) and linear in between otherwise: :func:`sizing_table` reports the achieved
values. A lattice given by ``spacing`` keeps its node count: the spacing scales with the
outline's extent (so ``fit`` can vary these fields from warm starts).

The girth on the body is :func:`body_girth`: analytic on a cylinder or sphere, the chart leg's
tape girth (:func:`clothsim.mold.leg.leg_girth`) on a leg from a size chart, a plane section of
a mesh measured as the levels module measures a scan (:func:`clothsim.compression.levels.hull_girth`:
its convex hull, a tape measure's length) otherwise.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import shapely
import trimesh

from .compression.levels import LevelError, hull_girth, level_set
from .errors import SceneError
from .mold import load_mold
from .mold.leg import leg_girth
from .sizingspec import AXES, GarmentSpec, SizingError


def _frame(grain) -> np.ndarray:
    g = np.asarray(grain, float)
    g = g / np.linalg.norm(g)
    return np.stack([g, [-g[1], g[0]]], 1)  # plane -> (u, v): p @ F


def row_interval(uv: np.ndarray, v: float) -> tuple[float, float, float]:
    """(width, u_lo, u_hi) of the polygon ``uv`` (K, 2) on the line at height v: the length of
    the line inside it (a non-convex row may be several pieces) and the extent; (0, nan, nan)
    outside."""
    poly = shapely.Polygon(uv)
    u0, u1 = float(uv[:, 0].min()) - 1.0, float(uv[:, 0].max()) + 1.0
    cut = poly.intersection(shapely.LineString([(u0, v), (u1, v)]))
    if cut.is_empty or cut.length == 0:
        return 0.0, math.nan, math.nan
    b = cut.bounds
    return float(cut.length), float(b[0]), float(b[2])


def level_heights(spec: GarmentSpec) -> list[float]:
    """The pattern height [m] above the hem of each level (design pattern)."""
    return [lv.at if lv.at is not None else lv.height - spec.hem for lv in spec.levels]


def circumference(outlines_uv: list[np.ndarray], v: float) -> float:
    """The garment's circumference [m] at pattern height ``v`` above the hem: the sum of the
    panels' widths there (each panel's v from its own lowest point)."""
    return sum(row_interval(p, float(p[:, 1].min()) + v)[0] for p in outlines_uv)


def _interp(x: float, xs, ys) -> float:
    return float(np.interp(x, xs, ys)) if len(xs) else 1.0


def size_outlines(spec: GarmentSpec, outlines: list, grains: list, girths: list[float | None]):
    """The sized outlines (each (K, 2) [m] in its panel's plane, same vertices) of the design
    ``outlines`` with their ``grains``; ``girths`` [m] per level (None where not needed: no
    reduction there). Raises SizingError naming the field."""
    frames = [_frame(g) for g in grains]
    uvs = [np.asarray(p, float) @ F for p, F in zip(outlines, frames)]
    if spec.is_identity():
        return [np.asarray(p, float) for p in outlines]
    vs = level_heights(spec)
    design = []
    for n, v in enumerate(vs):
        c = circumference(uvs, v)
        if not c > 0:
            span = max(float(np.ptp(p[:, 1])) for p in uvs)
            raise SizingError(f"garment.levels.{n}: at {v:.4g} m above the hem the pattern has no width "
                              f"(its panels span 0 to {span:.4g} m)")
        design.append(c)
    # step 1: grading
    f = np.ones(len(vs))
    dv = np.zeros(len(vs))
    if spec.grading is not None:
        d = spec.grading.steps()
        for n, lv in enumerate(spec.levels):
            rule = spec.grading.rules.get(lv.name)
            if rule is not None:
                f[n] = (design[n] + d * rule.girth_cm / 100.0) / design[n]
                dv[n] = d * rule.length_cm / 100.0
                if not f[n] > 0:
                    raise SizingError(f"garment.grading.rules.{lv.name}: size {spec.grading.size} leaves no "
                                      f"circumference at level {lv.name} ({design[n] * 100:.4g} cm "
                                      f"{d:+d} x {rule.girth_cm:g} cm)")
    # step 2: scale
    f = f * spec.scale.width
    # step 3: reduction
    for n, lv in enumerate(spec.levels):
        r = lv.reduction if lv.reduction is not None else spec.reduction
        if r is not None:
            f[n] = girths[n] * (1.0 - r / 100.0) / design[n]
    order = np.argsort(vs)
    vk, fk, dk = np.asarray(vs)[order], f[order], dv[order]
    # the height map: 0 -> 0, each level v -> v + dv, beyond the last shifted by its dv
    above = vk > 0
    if np.any(dk[~above] != 0):
        raise SizingError("garment.grading.rules: a level at or below the hem cannot take a length increment")
    knots = np.concatenate([[0.0], vk[above]])
    moved = np.concatenate([[0.0], (vk + dk)[above]])
    if np.any(np.diff(knots) <= 0) or np.any(np.diff(moved) <= 0):
        raise SizingError("garment.grading.rules: the graded heights of the levels are not increasing "
                          f"(levels at {', '.join(f'{x:.4g}' for x in vk + dk)} m above the hem)")

    def vmap(v):
        if len(knots) == 1:
            return v
        if v >= knots[-1]:
            return v + (moved[-1] - knots[-1])
        return float(np.interp(v, knots, moved))

    out = []
    for p, uv, F in zip(outlines, uvs, frames):
        v0 = float(uv[:, 1].min())
        new = np.empty_like(uv)
        for k, (u, v) in enumerate(uv):
            _, lo, hi = row_interval(uv, v)
            mid = 0.5 * (lo + hi) if math.isfinite(lo) else 0.5 * (uv[:, 0].min() + uv[:, 0].max())
            fv = _interp(v - v0, vk, fk)
            new[k, 0] = mid + fv * (u - mid)
            new[k, 1] = v0 + spec.scale.length * vmap(v - v0)
        out.append(new @ F.T)  # back to the panel's plane (F is orthonormal)
    return out


def sized_spacing(spacing, design, sized, grain):
    """A panel's lattice ``spacing`` scaled with its outline's extent along and across the grain
    (the node count stays the design's)."""
    if spacing is None:
        return None
    F = _frame(grain)
    e0 = np.ptp(np.asarray(design, float) @ F, axis=0)
    e1 = np.ptp(np.asarray(sized, float) @ F, axis=0)
    dx, dy = (spacing, spacing) if np.isscalar(spacing) else spacing
    return (float(dx * e1[0] / e0[0]), float(dy * e1[1] / e0[1]))


# ---------------------------------------------------------------------------------------------
# the body's girth


def body_girth(scene, n: int, mold=None) -> float:
    """The body's girth [m] at ``garment.levels[n]``: the level's ``girth``, else measured on the
    scene's mold at the level's ``height`` along ``garment.axis``: 2 pi r on a cylinder along
    that axis, the circle's on a sphere, the convex hull of a mesh's plane section (the loop
    nearest ``garment.center``; a tape measure bridges the hollows) otherwise.

    A level named by its name alone takes the scene's measuring level's girth
    (:func:`resolve_levels`). The one function every girth comes from."""
    spec = scene.garment
    lv = spec.levels[n]
    where = f"garment.levels.{n}"
    if lv.girth is not None:
        return float(lv.girth)
    if lv.height is None and lv.at is None:
        return float(_measured(scene, mold, n)["girth_m"])
    if lv.height is None:
        raise SizingError(f"{where}.girth: give it, or the level's height on the body to measure it at")
    if scene.mold is None:
        raise SizingError(f"{where}.girth: give it (the scene has no mold to measure it on)")
    ax = np.zeros(3)
    ax[AXES[spec.axis]] = 1.0
    kind = getattr(scene.mold, "kind", "mesh")
    if kind == "leg":
        if spec.axis != "z":
            raise SizingError(f"{where}.girth: a leg from a size chart stands along z: garment.axis must be z")
        if mold is None:
            mold = load_mold(scene.mold, scene.base_dir)
        return leg_girth(mold.params, float(lv.height))
    if kind == "cylinder":
        c = scene.mold.cylinder
        a = np.asarray(c.axis, float) / np.linalg.norm(c.axis)
        if abs(abs(a @ ax) - 1.0) > 1e-9:
            raise SizingError(f"{where}.girth: the cylinder's axis is not along garment.axis {spec.axis}: give it")
        if abs(lv.height - float(np.asarray(c.center) @ ax)) > c.length / 2:
            raise SizingError(f"{where}.height: {lv.height:g} m is beyond the cylinder's length")
        return 2.0 * math.pi * c.radius
    if kind == "sphere":
        s = scene.mold.sphere
        h = lv.height - float(np.asarray(s.center) @ ax)
        if abs(h) >= s.radius:
            raise SizingError(f"{where}.height: {lv.height:g} m does not cut the sphere")
        return 2.0 * math.pi * math.sqrt(s.radius ** 2 - h ** 2)
    if kind in ("plane", "box"):
        raise SizingError(f"{where}.girth: give it (a {kind} mold has no limb to measure)")
    return mesh_girth(_mold_mesh(scene, mold), ax, lv.height, spec.center, where)


def _mold_mesh(scene, mold):
    if mold is None:

        mold = load_mold(scene.mold, scene.base_dir)
    return np.asarray(mold.vertices, float), np.asarray(mold.faces, np.int64)


def mesh_girth(mesh, axis: np.ndarray, height: float, center, where: str = "girth") -> float:
    """The convex-hull perimeter [m] of the section of a triangle mesh ``(vertices, faces)`` by
    the plane ``x . axis = height``: of its loop nearest ``center`` (a point [m]; None: the
    longest loop)."""

    verts, faces = mesh
    tm = trimesh.Trimesh(verts, faces, process=False)
    origin = axis * height
    sec = tm.section(plane_origin=origin, plane_normal=axis)
    if sec is None:
        raise SizingError(f"{where}: the plane at {height:g} m does not cut the mold")
    # the section's points in the plane's two in-plane axes
    e1 = np.eye(3)[(int(np.argmax(axis)) + 1) % 3]
    e2 = np.cross(axis, e1)
    loops = []
    for d in sec.discrete:
        pts = np.asarray(d, float)
        if len(pts) >= 3:
            loops.append(np.stack([pts @ e1, pts @ e2], 1))
    if not loops:
        raise SizingError(f"{where}: the plane at {height:g} m cuts no closed loop of the mold")
    if center is not None:
        c = np.asarray(center, float)
        c2 = shapely.Point(c @ e1, c @ e2)
        loop = min(loops, key=lambda p: shapely.Polygon(p).buffer(0).distance(c2))
    else:
        loop = max(loops, key=lambda p: shapely.LineString(p).length)
    return hull_girth(loop)


# ---------------------------------------------------------------------------------------------
# levels named after the scene's measuring levels


def _measured(scene, mold, n: int) -> dict:
    """The scene's measuring level (:func:`clothsim.compression.levels.level_set`) that
    ``garment.levels[n]`` names; SizingError naming the field when there is none."""
    name = scene.garment.levels[n].name
    where = f"garment.levels.{n}"
    if getattr(scene, "levels", None) is None and getattr(getattr(scene, "mold", None), "leg", None) is None:
        raise SizingError(f"{where}: give height or at (the scene has no measuring levels named '{name}': "
                          f"no leg from a size chart, no levels:)")
    if scene.garment.axis != "z":
        raise SizingError(f"{where}: the scene's measuring levels stand along z: garment.axis must be z")
    if mold is None:
        mold = load_mold(scene.mold, scene.base_dir)
    try:
        lset = level_set(scene, mold)
    except LevelError as exc:
        raise SizingError(f"{where}: {exc}") from None
    for lvl in lset["levels"]:
        if lvl["name"] == name:
            return lvl
    names = ", ".join(lvl["name"] for lvl in lset["levels"]) or "none"
    raise SizingError(f"{where}.name: '{name}' is not one of the scene's measuring levels ({names}); "
                      f"give height or at")


def resolve_levels(scene, mold=None) -> GarmentSpec:
    """``scene.garment`` with each level named by its name alone given the height and girth of
    the scene's measuring level of that name (the others as given)."""
    spec = scene.garment
    if spec is None or all(lv.height is not None or lv.at is not None for lv in spec.levels):
        return spec
    levels = []
    for n, lv in enumerate(spec.levels):
        if lv.height is None and lv.at is None:
            m = _measured(scene, mold, n)
            lv = lv.model_copy(update={"height": float(m["z_m"]),
                                       "girth": float(m["girth_m"]) if lv.girth is None else lv.girth})
        levels.append(lv)
    return spec.model_copy(update={"levels": levels})


def _resolved_scene(scene, mold):
    spec = resolve_levels(scene, mold)
    if spec is scene.garment:
        return scene
    return _View(scene, spec)


class _View:
    """A scene seen with another ``garment`` (every other field the scene's)."""

    def __init__(self, scene, garment):
        self._scene, self.garment = scene, garment

    def __getattr__(self, key):
        return getattr(self._scene, key)


# ---------------------------------------------------------------------------------------------
# what compile and fit call


def girths(scene, mold=None, needed_only: bool = True) -> list[float | None]:
    """The body's girth at each level [m] (None where no reduction needs it, if ``needed_only``)."""
    spec = scene.garment
    out = []
    for n, lv in enumerate(spec.levels):
        need = lv.reduction is not None or spec.reduction is not None or not needed_only
        out.append(body_girth(scene, n, mold) if need else None)
    return out


def sized(scene, outlines: list, grains: list, mold=None) -> tuple[list, list, list]:
    """(design outlines, sized outlines, grains) of the scene, given its design ``outlines`` and
    ``grains`` (clothsim.compile.design_outlines; sized = design when the scene has no
    ``garment``). SceneError (located) on a garment that cannot be sized."""

    spec = getattr(scene, "garment", None)
    if spec is None or spec.is_identity():
        return outlines, outlines, grains
    try:
        if mold is None and getattr(scene, "mold", None) is not None and not all(
                lv.height is not None or lv.at is not None for lv in spec.levels):
            mold = load_mold(scene.mold, scene.base_dir)
        scene = _resolved_scene(scene, mold)
        spec = scene.garment
        new = size_outlines(spec, outlines, grains, girths(scene, mold))
        if not scene.panels:
            new[0] = new[0] - new[0].min(axis=0)
            w = np.ptp(new[0], axis=0)
            if not np.allclose(new[0], [[0, 0], [w[0], 0], [w[0], w[1]], [0, w[1]]], atol=1e-12 * max(w)):
                raise SizingError("garment.levels: the fabric sheet is a rectangle (one width) but the levels "
                                  "ask for different widths: give one level, or cut the garment as panels")
    except SizingError as exc:
        raise SceneError(scene.locate(str(exc))) from None
    return outlines, new, grains


def sizing_table(scene, outlines: list, grains: list, mold=None) -> list[dict]:
    """Per level: name, height [m] (on the body; None if not given), at [m] (pattern height of the
    design), girth_m (the body's), design_m and garment_m (the relaxed circumference of the
    design and of the sized pattern), reduction_pct (100 (1 - garment / girth)) and
    target_reduction_pct (None where none was asked)."""
    spec = getattr(scene, "garment", None)
    if spec is None or not spec.levels:
        return []
    design, new, grains = sized(scene, outlines, grains, mold)
    try:
        scene = _resolved_scene(scene, mold)
    except SizingError as exc:
        raise SceneError(scene.locate(str(exc))) from None
    spec = scene.garment
    uv0 = [p @ _frame(g) for p, g in zip(design, grains)]
    uv1 = [p @ _frame(g) for p, g in zip(new, grains)]
    rows = []
    for n, (lv, v) in enumerate(zip(spec.levels, level_heights(spec))):
        # the level's line moves with the pattern: find its sized height as the map of the design's
        # (the same vertices: interpolate each panel's height map at v)
        try:
            g = body_girth(scene, n, mold)
        except SizingError:
            g = None  # no girth given and none measurable: the table says so
        c0 = circumference(uv0, v)
        c1 = sum(row_interval(b, float(b[:, 1].min()) + _mapped(a, b, v))[0] for a, b in zip(uv0, uv1))
        r = lv.reduction if lv.reduction is not None else spec.reduction
        rows.append({"name": lv.name, "height": lv.height, "at": v, "girth_m": g, "design_m": c0,
                     "garment_m": c1, "reduction_pct": None if g is None else 100.0 * (1.0 - c1 / g),
                     "target_reduction_pct": r})
    return rows


def _mapped(a: np.ndarray, b: np.ndarray, v: float) -> float:
    """The sized height above the hem of design height ``v``: the vertices' height map (design
    ``a`` -> sized ``b``) interpolated at v."""
    va = a[:, 1] - a[:, 1].min()
    vb = b[:, 1] - b[:, 1].min()
    order = np.argsort(va, kind="stable")
    return float(np.interp(v, va[order], vb[order]))


def table_lines(rows: list[dict]) -> list[str]:
    """Printable lines of :func:`sizing_table`."""
    out = []
    for r in rows:
        g = "girth not known" if r["girth_m"] is None else f"girth {r['girth_m'] * 100:.2f} cm"
        red = "" if r["reduction_pct"] is None else f", reduction {r['reduction_pct']:.2f} %"
        where = f" (at {r['height']:.4g} m on the body)" if r["height"] is not None else ""
        out.append(f"  level {r['name']}{where}: {g}, garment {r['garment_m'] * 100:.2f} cm relaxed "
                   f"(design {r['design_m'] * 100:.2f} cm){red}")
    return out


def default_for(path: str, scene, outlines: list, grains: list) -> Any:
    """The start value a fit takes for an omitted ``garment.reduction``: the design pattern's own
    reduction at the first level (None when it has no level); ``outlines`` and ``grains``: the
    design's (clothsim.compile.design_outlines)."""
    if path != "garment.reduction" or scene.garment is None or not scene.garment.levels:
        return None
    try:
        scene = _resolved_scene(scene, None)
    except SizingError as exc:
        raise SceneError(scene.locate(str(exc))) from None
    uvs = [p @ _frame(g) for p, g in zip(outlines, grains)]
    c = circumference(uvs, level_heights(scene.garment)[0])
    return round(100.0 * (1.0 - c / body_girth(scene, 0)), 6)
