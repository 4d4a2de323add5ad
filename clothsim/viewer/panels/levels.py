"""The measuring levels in the viewer (a scene with ``levels:`` or a leg from a size chart):

- **rings**: each level (B, C, D, ...) drawn round the body at its height as a closed line just
  outside the body, labelled with its girth (``B 22.4 cm``) and, once read, its girth mean
  (``B 22.4 cm · 27.1 mmHg``);
- **profile plot** (under the convergence plot): the girth-mean pressure [mmHg] against the
  height above the floor [cm], the levels marked as points, and the band of the class B's girth
  mean falls in (the scene's first standard; RAL-GZ 387 by default); a table per level below it.

Both are computed off the update loop: the rings once per model (placing the levels on a scan
slices it, seconds), the readings on each new still frame (paused, stopped, converged), each on
a thread of its own; the loop only draws what a finished job handed over
(:mod:`clothsim.viewer.levelview` computes, without viser).
"""

from __future__ import annotations

import math
import threading

import numpy as np

from ...compression.levels import level_set, wants_levels
from ..levelview import class_band, level_rings, levels_table, profile_series, read_view, ring_label
from . import Panel

RING_COLOR = (240, 140, 0)
PROFILE_PADDING = (14, 12, 0, 0)


class LevelsPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self._lock = threading.Lock()
        self.rings: list[dict] = []  # level_rings() of the model shown
        self.view: dict | None = None  # read_view() of the frame read last
        self.band: dict | None = None
        self.read_at = -1  # the iteration the readings are of
        self.error = ""
        self._model = None  # the model the rings are of
        self._lset: dict | None = None
        self._geo_job: threading.Thread | None = None
        self._geo_done: tuple | None = None  # (model, lset, rings) or (model, None, message)
        self._job: threading.Thread | None = None
        self._done: tuple | None = None  # (key, iteration, view)
        self._key: tuple | None = None
        self._nodes: list = []
        self._shown = True

    # ------------------------------------------------------------------ widgets
    def build(self, gui) -> None:
        """The profile plot, the table and the rings' checkbox (placed under the convergence plot)."""
        g, app = self.gui, self.app
        on = self.active()
        zero = np.zeros(2)  # no reading yet (uPlot's scales want numbers)
        g["profile_plot"] = gui.add_uplot(
            data=(np.array([0.0, 1.0]), zero, zero, zero, zero),
            series=({"label": "height [cm]"},
                    {"label": "girth mean [mmHg]", "stroke": "#1c7ed6", "width": 1.5},
                    {"label": "levels", "stroke": "rgba(0,0,0,0)", "width": 1.0,  # points only
                     "points": {"show": True, "size": 9, "fill": "#e8590c", "stroke": "#e8590c"}},
                    {"label": "class min", "stroke": "#2f9e44", "width": 1.0, "dash": (6.0, 4.0)},
                    {"label": "class max", "stroke": "#2f9e44", "width": 1.0, "dash": (6.0, 4.0)}),
            bands=({"series": (4, 3), "fill": "rgba(47,158,68,0.12)"},),
            scales={"x": {"time": False}},
            axes=({"label": "height above the floor [cm]"}, {"label": "mmHg", "size": 48}),
            title="Pressure profile (girth mean)", aspect=1.8, padding=PROFILE_PADDING, visible=on)
        g["levels_table"] = gui.add_markdown(self.table(), visible=on)
        g["show_levels"] = gui.add_checkbox("Show measuring levels", True, visible=on)
        g["show_levels"].on_update(lambda _e: app.view_changed())

    def active(self) -> bool:
        """Whether the applied scene has measuring levels."""
        return wants_levels(self.app.sim.scene)

    def table(self) -> str:
        if self.error:
            return f"Levels: {self.error}"
        if self.view is None:
            return "The levels are read when the sheet is still (pause, or wait for convergence)."
        return levels_table(self.view, self.band)

    def busy(self) -> bool:
        return self._geo_job is not None or self._job is not None

    # ------------------------------------------------------------------ the update loop
    def update(self, frame, still: bool) -> None:
        """Called by the update loop with the shown frame: start the model's rings, then on a
        new still frame the readings; draw what a finished job handed over."""
        if frame is None or not self.active():
            return
        model = frame.model
        scene = self.app.sim.scene
        if self._model is not model and self._geo_job is None:
            self._model = model
            self._lset = None
            self._geo_job = threading.Thread(target=self._geometry, args=(scene, model), daemon=True,
                                             name="clothsim-levels-rings")
            self._geo_job.start()
        with self._lock:
            geo, self._geo_done = self._geo_done, None
            done, self._done = self._done, None
        if geo is not None and geo[0] is model:
            if geo[1] is None:
                self.error = geo[2]
                self.gui["levels_table"].content = self.table()
            else:
                self._lset, self.rings = geo[1], geo[2]
                self._draw_rings()
        key = (id(model), frame.iteration, id(frame.positions))
        if still and self._lset is not None and self._key != key and self._job is None:
            self._key = key
            self._job = threading.Thread(target=self._read, daemon=True, name="clothsim-levels-read",
                                         args=(scene, model, frame.positions.copy(), frame.in_contact.copy(),
                                               self._lset, frame.iteration, key))
            self._job.start()
        if done is not None and done[0] == self._key:
            self.view = done[2]
            b = next((r for r in self.view["levels"]["levels"] if r["level"] == "B"), None)
            self.band = class_band(None if b is None else b["mean_mmhg"], scene)
            self._show_profile()
            self._draw_rings()
            self.read_at = done[1]  # last: once set, the plot, table and labels show it
        show = bool(self.gui["show_levels"].value)
        if show != self._shown:
            self._shown = show
            for h in self._nodes:
                h.visible = show

    def _geometry(self, scene, model) -> None:
        """(its own thread) The levels on the model's body and their rings."""
        try:
            lset = level_set(scene, model.mold)
            out = (model, lset, level_rings(scene, model.mold, lset))
        except Exception as exc:  # noqa: BLE001 - shown in the table
            out = (model, None, f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc))
        with self._lock:
            self._geo_done = out
        self._geo_job = None
        self.app.post(lambda: None)  # wake the update loop

    def _read(self, scene, model, positions, in_contact, lset, iteration, key) -> None:
        """(its own thread) The levels' readings and the profile of a copy of a still frame."""
        try:
            view = read_view(scene, model, positions, in_contact, lset)
            with self._lock:
                self._done = (key, iteration, view)
        except Exception as exc:  # noqa: BLE001 - shown as the levels' error
            msg = f"levels: {type(exc).__name__}: {exc}"
            self.app.post(lambda: (_ for _ in ()).throw(ValueError(msg)), "run")
        finally:
            self._job = None
            self.app.post(lambda: None)

    def _reading(self, name: str) -> dict | None:
        if self.view is None:
            return None
        return next((r for r in self.view["levels"]["levels"] if r["level"] == name), None)

    def _draw_rings(self) -> None:
        scene = self.app.server.scene
        for h in self._nodes:
            h.remove()
        self._nodes = []
        for k, ring in enumerate(self.rings):
            self._nodes.append(scene.add_line_segments(
                f"/levels/{k}/ring", ring["segments"].astype(np.float32), colors=RING_COLOR, thickness=3.0,
                thickness_units="screen", visible=self._shown))
            self._nodes.append(scene.add_label(
                f"/levels/{k}/label", ring_label(ring, self._reading(ring["name"])),
                position=tuple(float(x) for x in ring["label"]), anchor="center-left", visible=self._shown))

    def _show_profile(self) -> None:
        x, y, m, lo, hi = profile_series(self.view, self.band)
        if len(x) < 2:  # uPlot needs two points: a lone slice drawn flat over a millimetre
            x = np.array([x[0] - 0.05, x[0]]) if len(x) else np.array([0.0, 1.0])
            y, m, lo, hi = (np.resize(a, 2) if len(a) else np.full(2, math.nan) for a in (y, m, lo, hi))
        # the y range is set here: uPlot's own range starts from the first value of each series,
        # and the levels' series is NaN between the levels
        v = np.concatenate([y, m, lo, hi])
        v = v[np.isfinite(v)]
        a, b = (float(v.min()), float(v.max())) if len(v) else (0.0, 1.0)
        pad = 0.1 * (b - a) if b > a else 1.0
        plot = self.gui["profile_plot"]
        plot.scales = {"x": {"time": False}, "y": {"range": (max(0.0, a - pad), b + pad)}}
        plot.data = (x, y, m, lo, hi)
        self.gui["levels_table"].content = self.table()

    def reset(self) -> None:
        """A new model: forget the readings and the rings (the loop starts the new ones)."""
        on = self.active()
        for k in ("profile_plot", "levels_table", "show_levels"):
            self.gui[k].visible = on
        self.view = None
        self.band = None
        self.error = ""
        self.read_at = -1
        self._key = None
        self._model = None  # the rings again (a new model, or the same one reset)
        self._lset = None
        self.rings = []
        for h in self._nodes:
            h.remove()
        self._nodes = []
        self.gui["levels_table"].content = self.table()
