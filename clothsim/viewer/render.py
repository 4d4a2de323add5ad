"""Rendering: the scene nodes of the 3D view (the coloured sheet, the constrained nodes, the seam
threads, the mold) and the camera framing. Only the update loop calls into this module: nodes are
created once per model and then updated in place (``glb_data`` for the sheet, ``points`` for the
constrained nodes and seams)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model import Model, SpringFamily
from .fields import FIELDS, FRICTION_COLOURS, FRICTION_STATES, node_field
from .glb import GlbMeshWriter, colormap, srgb_to_linear, vertex_normals

MOLD_GREY = (150, 150, 160)
MOLD_PENDING = (235, 140, 50)  # a mold shown before it is applied
#: the pattern panels' outlines (magenta: a colour the sheet's colour map, the seams' orange and
#: the constrained nodes' red never take)
OUTLINE_COLOUR = (220, 0, 220)
#: the sheet is slightly see-through by default, so that a mold under it shows (issue 15, item 24:
#: the default scene's mold was hidden under the opaque sheet)
DEFAULT_SHEET_OPACITY = 0.8


@dataclass
class Frame:
    """One consistent copy of the sheet for display: positions [m] (N, 3), in_contact (N,) bool,
    the iteration it was taken at and the model it belongs to."""

    positions: np.ndarray
    in_contact: np.ndarray
    iteration: int
    model: Model


@dataclass(frozen=True)
class ViewSettings:
    """What the View panel asks for: the field label (a key of FIELDS), the colour range (auto,
    or [lo, hi] in the field's unit), the sheet's opacity and which helpers are shown."""

    field: str = "warp strain"
    auto_range: bool = True
    range_min: float = 0.0
    range_max: float = 1.0
    sheet_opacity: float = DEFAULT_SHEET_OPACITY
    show_fixed: bool = True
    show_mold: bool = True
    mold_opacity: float = 0.6
    show_outlines: bool = True


def fmt(x: float | None, digits: int = 3) -> str:
    """A short human number: 'n/a' for None or non-finite, plain in [1e-3, 1e4), else exponent."""
    if x is None or not math.isfinite(x):
        return "n/a"
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e4:
        return f"{x:.{digits}g}"
    return f"{x:.{digits - 1}e}"


#: Smallest spread of an auto colour range, per field: strains are dimensionless and rounding
#: noise of a flat sheet is ~1e-8, so 1e-6 is the floor; other fields use 1e-6 of their magnitude.
STRAIN_FLOOR = 1e-6
RELATIVE_FLOOR = 1e-6


def range_floor(key: str, lo: float, hi: float) -> float:
    """The smallest meaningful spread of field ``key`` around values in [lo, hi]."""
    if key in ("strain_warp", "strain_weft"):
        return STRAIN_FLOOR
    return RELATIVE_FLOOR * max(abs(lo), abs(hi))


def field_range(values: np.ndarray, key: str, view: ViewSettings) -> tuple[float, float]:
    """The colour range (lo, hi) of a field's values under the view's settings. An auto range
    narrower than the field's floor (:func:`range_floor`) is widened to the floor around its
    middle, so that rounding noise shows as one colour, not as hotspots."""
    if not view.auto_range:
        lo, hi = float(view.range_min), float(view.range_max)
        if math.isfinite(lo) and math.isfinite(hi) and hi > lo:
            return lo, hi
    finite = values[np.isfinite(values)]
    if key == "contact":
        return 0.0, 1.0
    if key == "friction":
        return 0.0, float(len(FRICTION_STATES) - 1)
    if not len(finite):
        return 0.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    if key == "pressure":
        lo = 0.0
    floor = range_floor(key, lo, hi)
    if hi - lo <= floor:
        mid = 0.5 * (lo + hi)
        half = 0.5 * floor if floor > 0 else (0.5 if mid == 0 else abs(mid) * 5e-4)
        lo, hi = mid - half, mid + half
        if key == "pressure" and lo < 0:
            lo, hi = 0.0, hi - lo
    return lo, hi


def is_uniform(values: np.ndarray, key: str) -> bool:
    """True if the finite values spread less than the field's floor."""
    finite = values[np.isfinite(values)]
    if not len(finite) or key in ("contact", "friction"):
        return False
    lo, hi = float(finite.min()), float(finite.max())
    return hi - lo <= range_floor(key, lo, hi)


#: the stick/slip categories' colours as linear RGB (glTF vertex colours), one row per category
FRICTION_LINEAR = srgb_to_linear(np.asarray(FRICTION_COLOURS, np.float64) / 255.0).astype(np.float32)
FRICTION_NAMES = ("blue", "amber", "green", "red")


def friction_colours(values: np.ndarray) -> np.ndarray:
    """(N,) stick/slip categories (fields.friction_state) -> (N, 3) linear RGB."""
    idx = np.clip(np.nan_to_num(values).round().astype(np.int64), 0, len(FRICTION_STATES) - 1)
    return FRICTION_LINEAR[idx]


def friction_legend(values: np.ndarray | None) -> str:
    """The stick/slip legend: each category's colour, name and node count."""
    counts = (np.bincount(np.clip(np.nan_to_num(values).round().astype(np.int64), 0, 3), minlength=4)
              if values is not None else np.zeros(4, np.int64))
    parts = [f"{c} = {name} ({int(n)})" for c, name, n in zip(FRICTION_NAMES, FRICTION_STATES, counts)]
    return "**stick / slip** (nodes, last load step): " + " · ".join(parts)


def legend_text(label: str, key: str, lo: float, hi: float, uniform: bool = False,
                value: float | None = None, values: np.ndarray | None = None) -> str:
    """The markdown under the colour bar: the range's ends and middle, or for a uniform field its
    ``value`` (default: the range's middle): "0 everywhere" for a field that is zero (rounding
    noise included: an all-zero pressure field is not "uniform (0.5)" of its widened range), else
    "uniform (3)"; the stick/slip field counts its ``values`` per category."""
    if key == "contact":
        return "**in contact**: dark = free, yellow = touching the mold"
    if key == "friction":
        return friction_legend(values)
    unit = FIELDS[label][0]
    head = f"**{label}**{f' [{unit}]' if unit else ''}"
    tiny = 1e-9 * max(abs(lo), abs(hi))

    def show(x: float) -> str:
        return fmt(0.0 if abs(x) < tiny else x)

    if uniform:
        if value is None:
            mid = 0.5 * (lo + hi)
            v = mid if abs(mid) > range_floor(key, lo, hi) else 0.0
        else:  # the field's own value; a strain within its noise floor is zero
            v = float(value)
            v = 0.0 if key in ("strain_warp", "strain_weft") and abs(v) <= STRAIN_FLOOR else v
        return f"{head}: 0 everywhere" if show(v) == "0" else f"{head}: uniform ({show(v)})"
    return f"{head}: {show(lo)} (dark) · {show(0.5 * (lo + hi))} · {show(hi)} (yellow)"


def outline_loops(topology) -> list[np.ndarray]:
    """Each pattern panel's outline as its boundary nodes in order: one int64 array of node numbers
    per panel that has an outline (a lattice built without one gets no loop), the
    panel's boundary nodes (:attr:`clothsim.topology.Topology.boundary`) sorted by where their
    lattice point (i, j) projects onto the outline polygon (lattice units, counter-clockwise).
    Drawn as a closed line through these nodes."""
    import shapely

    loops = []
    for p, outline in enumerate(topology.outlines):
        if outline is None:
            continue
        nodes = topology.panel_nodes(p)
        nodes = nodes[topology.boundary[nodes]]
        if nodes.size < 2:
            continue
        ring = shapely.LineString(np.vstack([outline, outline[:1]]).astype(float))
        t = shapely.line_locate_point(ring, shapely.points(topology.node_ij[nodes].astype(float)))
        loops.append(nodes[np.argsort(t, kind="stable")].astype(np.int64))
    return loops


def outline_segments(loops: list[np.ndarray]) -> np.ndarray:
    """(S, 2) int64 node pairs of the closed lines through ``loops`` (:func:`outline_loops`)."""
    segs = [np.stack([lp, np.roll(lp, -1)], 1) for lp in loops if len(lp) >= 2]
    return np.concatenate(segs).astype(np.int64) if segs else np.zeros((0, 2), np.int64)


def inset_surface(V: np.ndarray, F: np.ndarray, spacing) -> np.ndarray:
    """Display only: move a mold's surface inwards by a quarter of the grid spacing [m], so that
    the sheet's flat triangles spanning nodes in contact (chords of a curved mold) do not show the
    mold poking through them."""
    try:
        import trimesh

        d = 0.25 * min(spacing)
        if not (d > 0) or len(F) == 0:
            return V
        n = trimesh.Trimesh(V, F, process=False).vertex_normals
        return V - d * np.asarray(n)
    except Exception:
        return V


class SceneRenderer:
    """The 3D scene of one viser server."""

    def __init__(self, scene_api):
        self.scene = scene_api
        self.model = None  # the model the nodes were built for
        self.glb: GlbMeshWriter | None = None
        self.h_cloth = None
        self.h_fixed = None
        self.h_seams = None
        self.h_mold = None
        self.h_outlines = None
        self.outline_ab = np.zeros((0, 2), np.int64)
        self.fixed_idx = np.zeros(0, np.int64)
        self.seam_ab = np.zeros((0, 2), np.int64)
        self.shown_mold = None
        self.field_key = "strain_warp"
        self.range = (0.0, 1.0)

    def rebuild(self, model, view: ViewSettings, outlines: bool = True) -> None:
        """Scene nodes for a (new) model; ``outlines``: draw each panel's outline (the viewer
        does for scenes of pattern ``panels``, not for a plain ``fabric:`` rectangle)."""
        self.glb = GlbMeshWriter(model.topology.faces)
        pos = model.rest_positions
        vals = np.zeros(model.node_count)
        glb = self.glb.build(pos, colormap(vals, 0, 1), vertex_normals(pos, model.topology))
        self.h_cloth = self.scene.add_glb("/sheet", glb)
        fixed = model.fixed_axes.any(axis=1)
        self.fixed_idx = np.nonzero(fixed)[0]
        dx, dy = model.spacing if model.spacing and min(model.spacing) > 0 else (0.01, 0.01)
        size = float(max(0.3 * min(dx, dy), 0.002 * np.ptp(pos, axis=0).max()))
        if self.h_fixed is not None:
            self.h_fixed.remove()
            self.h_fixed = None
        if len(self.fixed_idx):
            self.h_fixed = self.scene.add_point_cloud(
                "/constrained", pos[self.fixed_idx].astype(np.float32), colors=(230, 40, 40),
                point_size=size, point_shape="circle", precision="float32", visible=view.show_fixed)
        # seams: one thread per sewn node pair, and per sewn node of a seam of unequal node counts
        # to the point of the other side it is sewn to (they shrink to nothing as the seam closes)
        if self.h_seams is not None:
            self.h_seams.remove()
            self.h_seams = None
        self.seam_ab = model.spring_nodes[model.spring_family == SpringFamily.SEAM]
        self.seam_model = model
        if len(self.seam_ab) or model.seam_count:
            self.h_seams = self.scene.add_line_segments(
                "/seams", self.seam_points(pos), colors=(255, 140, 0), thickness=2.0,
                thickness_units="screen")
        # the pattern panels' outlines: a closed line through each panel's boundary nodes
        if self.h_outlines is not None:
            self.h_outlines.remove()
            self.h_outlines = None
        self.outline_ab = outline_segments(outline_loops(model.topology)) if outlines else np.zeros((0, 2), np.int64)
        if len(self.outline_ab):
            self.h_outlines = self.scene.add_line_segments(
                "/outlines", pos[self.outline_ab].astype(np.float32), colors=OUTLINE_COLOUR, thickness=3.0,
                thickness_units="screen", visible=view.show_outlines)
        self.model = model

    def seam_points(self, pos: np.ndarray) -> np.ndarray:
        """(P, 2, 3) float32 end points of the seam threads (clothsim.model.Model.seam_points)."""
        return self.seam_model.seam_points(pos).astype(np.float32)

    def show_mold(self, mold, pending: bool, model, view: ViewSettings) -> None:
        """Show ``mold`` (None: none), orange while it is a draft not yet applied."""
        if mold is None:
            if self.h_mold is not None:
                self.h_mold.remove()
                self.h_mold = None
            self.shown_mold = None
            return
        if self.shown_mold is not mold or self.h_mold is None:
            ext = float(np.ptp(model.rest_positions, axis=0).max()) * 2.0
            V, F = mold.surface_mesh(resolution=64, extent=max(ext, 1e-3))
            V = inset_surface(np.asarray(V, np.float64), np.asarray(F, np.int64), model.spacing)
            self.h_mold = self.scene.add_mesh_simple(
                "/mold", np.asarray(V, np.float32), np.asarray(F, np.uint32), color=MOLD_GREY,
                side="double", opacity=1.0)
            self.shown_mold = mold
        op = float(view.mold_opacity)
        self.h_mold.opacity = None if op >= 0.999 else op
        self.h_mold.color = MOLD_PENDING if pending else MOLD_GREY
        self.h_mold.visible = bool(view.show_mold)

    def push_frame(self, f: Frame, view: ViewSettings) -> str:
        """Show a frame; returns the legend text for its colour range."""
        self.field_key = FIELDS[view.field][1]
        vals = node_field(f.model, f.positions, f.in_contact, self.field_key)
        lo, hi = field_range(vals, self.field_key, view)
        uniform = view.auto_range and is_uniform(vals, self.field_key)
        finite = vals[np.isfinite(vals)]
        value = float(np.median(finite)) if uniform and len(finite) else None
        self.range = (lo, hi)
        colours = friction_colours(vals) if self.field_key == "friction" else colormap(vals, lo, hi)
        glb = self.glb.build(f.positions, colours, vertex_normals(f.positions, f.model.topology),
                             opacity=float(view.sheet_opacity))
        self.h_cloth.glb_data = glb
        if self.h_fixed is not None:
            self.h_fixed.points = f.positions[self.fixed_idx].astype(np.float32)
            self.h_fixed.visible = bool(view.show_fixed)
        if self.h_seams is not None:
            self.h_seams.points = self.seam_points(f.positions)
        if self.h_outlines is not None:
            self.h_outlines.points = f.positions[self.outline_ab].astype(np.float32)
            self.h_outlines.visible = bool(view.show_outlines)
        return legend_text(view.field, self.field_key, lo, hi, uniform, value, vals)


#: the camera's view holds the framed box grown by this share of its size on every side (issue 28,
#: item 15: the garment framed with a margin)
FRAME_MARGIN = 0.1


def frame_camera(client, model, positions: np.ndarray | None = None) -> None:
    """Point a tab's camera at the sheet (its ``positions`` [m] (N, 3), default the rest
    positions) and the part of the mold near it (:func:`camera_box`), with a margin."""
    lo, hi = camera_box(model, positions)
    c = 0.5 * (lo + hi)
    r = max(float(np.linalg.norm(hi - lo)) * 0.5 * (1.0 + 2.0 * FRAME_MARGIN), 1e-3)
    d = np.array([0.45, -1.0, 0.8])
    client.camera.up_direction = (0.0, 0.0, 1.0)
    client.camera.position = tuple(c + 1.6 * r * d / np.linalg.norm(d))
    client.camera.look_at = tuple(c)
    client.camera.near = r * 0.01
    client.camera.far = r * 100.0


#: re-frame when the sheet leaves the framed box grown by this share of its diagonal (issue 15,
#: item 24: a stretched sheet ran off the screen)
REFRAME_GROWTH = 0.25


def needs_reframe(framed, box) -> bool:
    """True if ``box`` (lo (3,), hi (3,)) [m] reaches beyond ``framed`` (the box the camera was
    last pointed at; None: never framed) by more than REFRAME_GROWTH of framed's diagonal."""
    if framed is None:
        return True
    flo, fhi = (np.asarray(x, float) for x in framed)
    lo, hi = (np.asarray(x, float) for x in box)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return False
    margin = REFRAME_GROWTH * max(float(np.linalg.norm(fhi - flo)), 1e-9)
    return bool((lo < flo - margin).any() or (hi > fhi + margin).any())


#: the mold is framed only within this share of the sheet's largest extent around the sheet
#: (issue 28, item 15: a sleeve on a 1.8 m body was framed with the whole body, the garment a
#: sliver of the view)
MOLD_REACH = 0.1


def camera_box(model, positions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) [m] of what the camera frames: the sheet (``positions``, default the rest
    positions, i.e. the garment) and the part of the mold's box within MOLD_REACH of the
    sheet's largest extent around it (the sphere under a cap, the body under a band: not the
    whole body)."""
    p = model.rest_positions if positions is None else positions
    p = p[np.isfinite(p).all(axis=1)]
    if not len(p):
        p = model.rest_positions
    lo, hi = p.min(axis=0), p.max(axis=0)
    if model.mold is not None:
        try:
            mb = np.asarray(model.mold.bounds, float)
            if mb.shape == (2, 3) and np.isfinite(mb).all():
                g = MOLD_REACH * max(float(np.ptp(p, axis=0).max()), 1e-9)
                mlo, mhi = np.maximum(mb[0], lo - g), np.minimum(mb[1], hi + g)
                if (mlo <= mhi).all():
                    lo, hi = np.minimum(lo, mlo), np.maximum(hi, mhi)
        except Exception:
            pass
    return lo, hi
