"""The Probes tab and the click readout.

- **Probes**: each of the scene's probes is drawn on the mold as its sensor disc's outline with a
  label (``ankle 21.3 mmHg``); the tab lists them with the contact fraction and the classes.
  Readings are taken on still frames (paused, stopped, converged), on a thread of their own:
  reading a probe queries the mold at thousands of points (about 0.3 s a probe on the class II
  sleeve), which neither the solver nor the display loop should wait for.
- **Readout**: a click on the sheet shows the nearest node's contact pressure [mmHg], warp and
  weft strain and tension [N/m] under the colour legend, and marks the node.

The click callback (viser's thread pool) only records the ray; the update loop finds the node
(:func:`clothsim.viewer.pick.ray_hit`) and reads it (:meth:`ProbesPanel.update`).
"""

from __future__ import annotations

import html
import threading

import numpy as np

from ..pick import PROBE_MMHG, node_readout, probe_label, probe_readings, readout_text, ray_hit, ring
from . import Panel

PROBE_COLOR = (20, 110, 220)
PICK_COLOR = (255, 0, 200)


class ProbesPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self._lock = threading.Lock()
        self._ray: tuple | None = None  # the newest click's (origin, direction), not yet read
        self.readings: list[dict] = []
        self.read_at = -1  # the iteration the readings are of
        self.readout: dict | None = None  # the picked node's values
        self.picked: int | None = None
        self._key: tuple | None = None
        self._pick_key: tuple | None = None
        self._nodes: list = []  # probe scene nodes
        self._pick_node = None
        self._shown = True
        self.clicks = 0  # clicks received from the tabs
        self.last_ray: tuple | None = None
        self._job: threading.Thread | None = None  # the probe reading under way
        self._done: tuple | None = None  # (key, iteration, readings) of a finished reading
        self.misses = 0  # clicks whose ray missed the sheet

    # ------------------------------------------------------------------ widgets
    def build_readout(self, gui) -> None:
        """The readout line (under the colour legend)."""
        self.gui["readout"] = gui.add_markdown(readout_text(None))

    def build(self, gui) -> None:
        g, app = self.gui, self.app
        g["show_probes"] = gui.add_checkbox("Show probes", True)
        g["show_probes"].on_update(lambda _e: app.view_changed())
        g["probes_table"] = gui.add_markdown(self.table())
        app.err("probes")

    def on_scene_click(self, event) -> None:
        """viser's click callback (thread pool): record the ray only."""
        with self._lock:
            self._ray = (tuple(event.ray_origin), tuple(event.ray_direction))
            self.last_ray = self._ray
            self.clicks += 1
        self.app.post(lambda: None)  # wake the update loop

    def pick_ray(self, origin, direction) -> None:
        """Record a click's ray as the browser would (tests); the update loop reads it."""
        with self._lock:
            self._ray = (tuple(origin), tuple(direction))
        self.app.post(lambda: None)

    # ------------------------------------------------------------------ the update loop
    def update(self, frame, still: bool) -> None:
        """Called by the update loop with the shown frame: read a pending click, and on a new
        still frame the probes and the picked node."""
        if frame is None:
            return
        model = frame.model
        with self._lock:
            ray, self._ray = self._ray, None
        if ray is not None:
            hit = ray_hit(frame.positions, model.topology.faces, *ray)
            if hit is not None:
                self.picked = hit[0]
                self._pick_key = None
            else:
                self.misses += 1
        if self.picked is not None and self.picked >= model.node_count:
            self.picked = None
        key = (id(model), frame.iteration, id(frame.positions))
        if self.picked is not None and (self._pick_key != key or ray is not None):
            self.readout = {**node_readout(model, frame.positions, frame.in_contact, self.picked),
                            "iteration": frame.iteration}
            self._pick_key = key
            self._show_pick(frame.positions[self.picked], model)
            self.gui["readout"].content = readout_text(self.readout) + \
                ("" if still else "  \n<small>(running: values of the frame shown)</small>")
        show = bool(self.gui["show_probes"].value)
        if still and self._key != key and self._job is None and self.app.sim.scene.probes:
            self._key = key
            self._job = threading.Thread(target=self._read, name="clothsim-probes", daemon=True,
                                         args=(self.app.sim.scene, model, frame.positions.copy(),
                                               frame.in_contact.copy(), frame.iteration, key))
            self._job.start()
        with self._lock:
            done, self._done = self._done, None
        if done is not None and done[0] == self._key:  # a reading of the frame shown
            self.readings = done[2]
            self._draw_probes()
            self.gui["probes_table"].content = self.table()
            self.read_at = done[1]  # last: once it is set, the rings, labels and table show it
        if show != self._shown:
            self._shown = show
            for h in self._nodes:
                h.visible = show

    def _read(self, scene, model, positions, in_contact, iteration, key) -> None:
        """(its own thread) Read the probes on a copy of a still frame; the loop draws them."""
        try:
            readings = probe_readings(scene, model, positions, in_contact)
            with self._lock:
                self._done = (key, iteration, readings)
        except Exception as exc:
            msg = f"probes: {type(exc).__name__}: {exc}"
            self.app.post(lambda: (_ for _ in ()).throw(ValueError(msg)), "probes")
        finally:
            self._job = None
            self.app.post(lambda: None)  # wake the update loop

    def _show_pick(self, p, model) -> None:
        scene = self.app.server.scene
        dx = min(model.spacing) if model.spacing and min(model.spacing) > 0 else 0.005
        if self._pick_node is None:
            self._pick_node = scene.add_icosphere("/pick", radius=0.35 * dx, color=PICK_COLOR,
                                                  position=tuple(float(x) for x in p))
        else:
            self._pick_node.position = tuple(float(x) for x in p)

    def _draw_probes(self) -> None:
        scene = self.app.server.scene
        for h in self._nodes:
            h.remove()
        self._nodes = []
        for k, r in enumerate(self.readings):
            c = np.asarray(r["center"] if r.get("center") is not None else r["point"], float)
            n = np.asarray(r["normal"], float)
            lift = 0.15 * r["radius_m"]  # just off the mold, so that the ring is not hidden in it
            self._nodes.append(scene.add_line_segments(
                f"/probes/{k}/disc", ring(c + lift * n, n, r["radius_m"]), colors=PROBE_COLOR, thickness=3.0,
                thickness_units="screen", visible=self._shown))
            self._nodes.append(scene.add_label(
                f"/probes/{k}/label", probe_label(r), position=tuple(float(x) for x in c + (lift + r["radius_m"]) * n),
                anchor="bottom-center", visible=self._shown))

    def table(self) -> str:
        scene = self.app.sim.scene
        if not scene.probes:
            return ("No probes in this scene. Add `probes: [{name, point: [x, y, z], radius}]` to the scene "
                    "file (see docs/guide/compression.md).")
        if not self.readings:
            return "Probes are read when the sheet is still (pause, or wait for convergence)."
        # three narrow columns (issue 28, item 18: five, the classes' long names among them,
        # crowded the panel); the classes of the classified probe on a line of their own
        rows = [f"| probe | {PROBE_MMHG.unit} | covered |", "|:---|---:|---:|"]
        for r in self.readings:
            rows.append(f"| {html.escape(r['name'])} | {r['pressure_mmhg']:.1f} | {r['contact_fraction']:.0%} |")
        lines = []
        for r in self.readings:
            if r.get("classes"):
                cls = " · ".join(f"{html.escape(k)} **{html.escape(str(v))}**" for k, v in r["classes"].items())
                lines.append(f"Class at *{html.escape(r['name'])}*: {cls}")
        lines += [f"*{html.escape(r['name'])}*: {html.escape(r['note'])}" for r in self.readings if r.get("note")]
        return "\n".join(rows) + ("\n\n" + "  \n".join(lines) if lines else "")

    def reset(self) -> None:
        """A new model: forget the picked node and the readings."""
        self.picked = None
        self.readout = None
        self._key = None
        self.readings = []
        self.read_at = -1
        for h in self._nodes:
            h.remove()
        self._nodes = []
        if self._pick_node is not None:
            self._pick_node.remove()
            self._pick_node = None
        self.gui["readout"].content = readout_text(None)
        self.gui["probes_table"].content = self.table()
