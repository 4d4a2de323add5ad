"""The browser app (viser): the sheet relaxing live on its mold, a convergence plot, controls and
editors for every part of the scene, downloads of the scene and the results.

Threads and ownership (DESIGN.md, viser's own examples):

- the **solver thread** belongs to :class:`clothsim.simulation.Simulation`; between batches it calls
  :meth:`ViewerApp._on_progress`, which only appends (iteration, residual) to the live history and,
  at most once per frame period, copies the positions (a consistent frame: the solver is between
  batches);
- **GUI callbacks** (viser's thread pool, possibly several at once from several tabs) only read
  the widget's value and *post* a task under a lock; they never touch the simulation or the scene;
- one **update loop** thread runs the posted tasks in order (validation, ``set_solver``,
  ``replace_scene``, start/pause/step/reset), then pushes the newest frame: it owns every scene
  node, creates them once per model and updates them in place (``glb_data`` for the coloured
  sheet, ``points`` for the constrained nodes). Its rate is bounded (``max_rate_hz``, default 25)
  and adapts so that its own work stays below a few percent of the wall time: the solver's numba
  kernels hold the GIL, so any Python the viewer runs is time the solver loses.

Every edit is validated before anything changes (an invalid value leaves the scene as it was and
shows a red message next to the widget). Solver settings (C, e, max iterations, method) apply to
the running relaxation; model edits (constraints, materials, fabric, mold, initial lift) are
collected in a *draft* scene and applied with **Apply** (keeping the current shape as a warm
start) or **Reset** (from the initial deformation).

Safety: binds 127.0.0.1 unless ``--host`` says otherwise; uploads larger than the limit are
refused when the browser announces them (before they are buffered) and checked again on arrival;
uploads are parsed in memory; an accepted mold upload is stored in a private temporary folder
(mode 0700) under a name chosen here, never the browser's.
"""

from __future__ import annotations

import copy
import html
import math
import re
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import viser
from viser import _messages as viser_messages

from .config import NODE_SETS, SOLVER_METHODS, Scene, SceneError, load_scene, scene_from_dict
from .material import MaterialError, check_table, parse_table_csv
from .mold import MoldError, load_mold, load_mold_bytes
from .presets import PRESETS
from .grid import FAMILY_SEAM
from .results import grid_faces, sheet_health
from .simulation import Simulation
from .viewer_fields import FIELDS, node_field
from .viewer_glb import GlbMeshWriter, colorbar_image, colormap, grid_normals

ROOT = Path(__file__).resolve().parent.parent
MOLD_DIR = ROOT / "static" / "molds"
MOLD_EXTS = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf", ".txt", ".pts", ".tri", ".vtk", ".wrl", ".vrml")
AXES_CHOICES = ("xyz", "xy", "xz", "yz", "x", "y", "z")
RANGE_NODES = "(index ranges)"
NEW_CONSTRAINT = "+ new constraint"
PLOT_POINTS = 1500
STATE_TEXT = {"idle": "ready", "max_iterations": "stopped (max iterations)", "time_limit": "stopped (time limit)"}


@dataclass
class Frame:
    """One consistent copy of the sheet for display."""

    positions: np.ndarray
    in_contact: np.ndarray
    iteration: int
    model: object


def _fmt(x: float, digits: int = 3) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e4:
        return f"{x:.{digits}g}"
    return f"{x:.{digits - 1}e}"


def parse_table_text(text: str) -> tuple[list[float], list[float]]:
    """A material table typed as one ``strain, value`` pair per line (comma, semicolon or spaces
    between; ``#`` starts a comment). Raises MaterialError naming the line."""
    strain: list[float] = []
    value: list[float] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        toks = [t for t in re.split(r"[,;\s]+", line) if t]
        if len(toks) != 2:
            raise MaterialError(f"line {n}: expected two numbers 'strain, value' (got '{raw.strip()}')")
        try:
            a, b = float(toks[0]), float(toks[1])
        except ValueError:
            raise MaterialError(f"line {n}: not a number in '{raw.strip()}'") from None
        strain.append(a)
        value.append(b)
    return strain, value


def table_text(strain, value) -> str:
    return "\n".join(f"{float(s):g}, {float(v):g}" for s, v in zip(strain, value))


def _thin(x: np.ndarray, y: np.ndarray, n: int = PLOT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """At most about n points, evenly spread, the first and last kept."""
    if len(x) <= n:
        return x, y
    idx = np.unique(np.concatenate([np.linspace(0, len(x) - 1, n).astype(np.int64), [len(x) - 1]]))
    return x[idx], y[idx]


def _decades(lo: float, hi: float) -> tuple[float, ...]:
    a = math.floor(math.log10(lo))
    b = math.ceil(math.log10(hi))
    if b <= a:
        b = a + 1
    step = max(1, math.ceil((b - a) / 8))
    return tuple(10.0 ** k for k in range(a, b + 1, step))


class ViewerApp:
    """The viser app around one :class:`Simulation`. Several browser tabs share it.

    The public methods (start, pause, step, reset, apply, post, wait_idle, close) are what the
    buttons do; tests drive the app through them and through the GUI handles in ``self.gui``."""

    def __init__(self, scene: Scene, *, host: str = "127.0.0.1", port: int = 8080,
                 upload_limit_mb: float = 200.0, max_rate_hz: float = 25.0, duty: float = 0.02,
                 verbose: bool = False):
        self.upload_limit = int(upload_limit_mb * 1024 * 1024)
        self.min_period = 1.0 / max_rate_hz
        self.duty = duty
        self.verbose = verbose
        self._source = scene.source
        self._label = str(scene.source) if scene.source is not None else "<scene>"
        self._lock = threading.Lock()
        self._tasks: list[tuple[Callable[[], None], str | None]] = []
        self._tl = threading.local()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._frame: Frame | None = None
        self._last_frame: Frame | None = None
        self._last_capture = 0.0
        self._live_it: list[int] = []
        self._live_res: list[float] = []
        self._upload_n = 0
        self._tmpdir = Path(tempfile.mkdtemp(prefix="clothsim-uploads-"))  # mkdtemp: mode 0700
        self.frames_pushed = 0
        self.pushed_iteration = -1
        self.pushed_positions: np.ndarray | None = None
        self.loop_work_s = 0.0
        self.errors: dict[str, str] = {}

        self.sim = Simulation(scene, on_progress=self._on_progress)
        self.draft: dict = scene.to_dict()
        self.pending: set[str] = set()
        self._mold_preview = None  # a validated Mold of the draft, shown until applied

        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.host = host
        self.port = self.server.get_port()
        self.server.gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        self.server.scene.set_up_direction("+z")
        self.server.on_client_connect(self._on_connect)
        self.server._websock_server.register_handler(  # refuse oversize uploads before buffering
            viser_messages.FileTransferStartUpload, self._on_upload_start)

        self._scene_model = None
        self._field_key = "strain_warp"
        self._range = (0.0, 1.0)
        self._status_text = ""
        self._legend_text = ""
        self._plot_key = None
        self._plot_axes_key = None
        self._plot_last = 0.0
        self._hist_version = -1
        self._hist = (np.zeros(0), np.zeros(0))
        self._view_dirty = True
        self._mold_dirty = True
        self.h_cloth = None
        self.h_fixed = None
        self.h_seams = None
        self._seam_ab = np.zeros((0, 2), np.int64)
        self.h_mold = None
        self._glb: GlbMeshWriter | None = None
        self.gui: dict[str, object] = {}
        self._build_gui()
        self._sync_widgets_from_draft()
        self._thread = threading.Thread(target=self._loop, name="clothsim-viewer", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ public controls
    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "", "::") else self.host
        return f"http://{host}:{self.port}"

    def post(self, fn: Callable[[], None], group: str | None = None) -> None:
        """Queue fn for the update loop (the only thread that changes the simulation or scene).
        An exception it raises becomes the error line of ``group``."""
        with self._lock:
            self._tasks.append((fn, group))
            self._idle.clear()
        self._wake.set()

    def start(self, wait: bool = False) -> None:
        """Start (or resume) the relaxation; ``wait``: return once the loop has run the request."""
        self.post(self._do_start, "run")
        if wait:
            self.wait_idle()

    def pause(self, wait: bool = False) -> None:
        self.post(self.sim.pause, "run")
        if wait:
            self.wait_idle()

    def step(self, wait: bool = False) -> None:
        self.post(self._do_step, "run")
        if wait:
            self.wait_idle()

    def reset(self, wait: bool = False) -> None:
        """Back to the initial deformation, with the edited scene if there are unapplied edits."""
        self.post(self._do_reset, "run")
        if wait:
            self.wait_idle()

    def apply(self, wait: bool = False) -> None:
        """Rebuild the model from the edited scene, keeping the current shape as a warm start."""
        self.post(lambda: self._do_apply(reset=False), "run")
        if wait:
            self.wait_idle()

    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Block until every posted task has run and a frame has been pushed after them."""
        return self._idle.wait(timeout)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        self.sim.close()
        self._thread.join(timeout=10)
        try:
            self.server.stop()
        finally:
            shutil.rmtree(self._tmpdir, ignore_errors=True)

    # ------------------------------------------------------------------ solver thread hook
    def _on_progress(self, sim: Simulation) -> None:
        """Called by the solver thread between batches: cheap bookkeeping only."""
        it = sim.state.iteration
        r = sim.residual
        now = time.perf_counter()
        with self._lock:
            if math.isfinite(r) and r > 0 and (not self._live_it or it > self._live_it[-1]):
                self._live_it.append(it)
                self._live_res.append(r)
                if len(self._live_it) > 4 * PLOT_POINTS:
                    self._live_it = self._live_it[::2] + ([it] if len(self._live_it) % 2 == 0 else [])
                    self._live_res = self._live_res[::2] + ([r] if len(self._live_res) % 2 == 0 else [])
            due = now - self._last_capture >= self.min_period
            if due:
                self._last_capture = now
        if due:
            frame = Frame(sim.state.positions.copy(), sim.state.in_contact.copy(), it, sim.model)
            with self._lock:
                self._frame = frame

    # ------------------------------------------------------------------ update loop
    def _loop(self) -> None:
        while not self._stop.is_set():
            t0 = time.perf_counter()
            c0 = time.thread_time()  # CPU time: waiting for the GIL is not our work
            with self._lock:
                tasks, self._tasks = self._tasks, []
            for fn, group in tasks:
                self._run_task(fn, group)
            try:
                self._push()
            except Exception as exc:  # never let the display kill the loop
                if self.verbose:
                    print(f"viewer: display update failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            work = time.perf_counter() - t0
            cpu = time.thread_time() - c0
            self.loop_work_s += cpu
            with self._lock:
                if not self._tasks:
                    self._idle.set()
            # while the solver runs, keep the loop's own share of the time below `duty` (a smoothed
            # estimate, so that one slow frame, e.g. loading a kernel, does not stall the display)
            self._work_avg = 0.8 * getattr(self, "_work_avg", cpu) + 0.2 * cpu
            period = self.min_period
            if self.sim.status == "running":
                period = min(max(self.min_period, self._work_avg / self.duty), 1.0)
            self._wake.wait(timeout=max(0.002, period - work))
            self._wake.clear()

    def _run_task(self, fn, group) -> None:
        try:
            fn()
            if group is not None:
                self._set_error(group, "")
        except Exception as exc:  # validation errors are the expected case
            msg = str(exc) if isinstance(exc, (SceneError, MoldError, MaterialError, ValueError)) \
                else f"{type(exc).__name__}: {exc}"
            self._set_error(group or "run", self._clean(msg))

    def _clean(self, msg: str) -> str:
        msg = msg.replace(f"{self._label}: ", "").replace("<scene>: ", "")
        # pydantic ValidationError text from set_solver: keep the useful lines
        if "validation error" in msg:
            lines = [ln.strip() for ln in msg.splitlines()[1:] if ln.strip() and not ln.strip().startswith("For further")]
            msg = " ".join(lines)
            msg = re.sub(r"\s*\[type=.*?\]", "", msg)
        return msg

    def _set_error(self, group: str, msg: str) -> None:
        h = self.gui.get(f"err_{group}")
        if self.errors.get(group, "") == msg:
            return
        self.errors[group] = msg
        if h is not None:
            h.content = (f'<div style="color:#c92a2a;font-size:0.85em;white-space:pre-wrap">&#9888; '
                         f'{html.escape(msg)}</div>') if msg else ""
            h.visible = bool(msg)

    # ------------------------------------------------------------------ tasks
    def _do_start(self) -> None:
        if self.pending:  # Start with unapplied edits: apply them first (warm start)
            self._do_apply(reset=False)
        self._begin_segment()
        self.sim.start()

    def _do_step(self) -> None:
        if self.pending:
            self._do_apply(reset=False)
        self._begin_segment()
        self.sim.step()

    def _begin_segment(self) -> None:
        """A new run segment: its live points start afresh (earlier ones are in the history)."""
        with self._lock:
            self._live_it = []
            self._live_res = []

    def _do_reset(self) -> None:
        if self.pending:
            self._do_apply(reset=True)
        else:
            self.sim.reset()
            self._after_model_change()

    def _do_apply(self, reset: bool) -> None:
        scene = self._validate(self.draft)
        self.sim.replace_scene(scene, warm_start=not reset)
        self.pending.clear()
        self._mold_preview = None
        self._after_model_change()

    def _after_model_change(self) -> None:
        with self._lock:
            self._live_it = []
            self._live_res = []
            self._frame = None
        self._hist_version = -1
        self._mold_dirty = True
        self.draft = self.sim.scene.to_dict()
        self._refresh_pending()

    def _validate(self, data: dict) -> Scene:
        return scene_from_dict(copy.deepcopy(data), source=self._source)

    def _edit_draft(self, group: str, mutate: Callable[[dict], None]) -> Scene:
        """Apply mutate to a copy of the draft; keep it only if the whole scene validates."""
        new = copy.deepcopy(self.draft)
        mutate(new)
        scene = self._validate(new)
        self.draft = new
        self.pending.add(group)
        self._refresh_pending()
        return scene

    def _refresh_pending(self) -> None:
        h = self.gui.get("pending")
        if h is None:
            return
        if self.pending:
            h.content = (f"**Unapplied edits:** {', '.join(sorted(self.pending))}. *Apply* keeps the current "
                         f"shape as a warm start; *Reset* restarts from the initial deformation.")
        else:
            h.content = "No unapplied edits."
        self.gui["apply"].disabled = not self.pending

    # ------------------------------------------------------------------ GUI building
    def _quiet(self):
        """Context in which widget assignments made here do not count as user edits."""
        app = self

        class _Q:
            def __enter__(self):
                app._tl.quiet = getattr(app._tl, "quiet", 0) + 1

            def __exit__(self, *a):
                app._tl.quiet -= 1

        return _Q()

    def _on(self, handle, fn: Callable, group: str | None):
        """Register fn(value) as a user edit of handle, run by the update loop."""

        def cb(event) -> None:
            if getattr(self._tl, "quiet", 0):
                return
            value = handle.value
            self.post(lambda: fn(value), group)

        handle.on_update(cb)
        return handle

    def _err(self, group: str, order: float | None = None):
        h = self.server.gui.add_html("", visible=False, order=order)
        self.gui[f"err_{group}"] = h
        self.errors[group] = ""
        return h

    def _build_gui(self) -> None:
        gui = self.server.gui
        g = self.gui
        g["title"] = gui.add_markdown(f"**clothsim** · {html.escape(self.sim.scene.name)}")
        g["status"] = gui.add_markdown("starting ...")
        g["run"] = gui.add_button_group("Run", ("Start", "Pause", "Step", "Reset"))

        def on_run(event) -> None:
            v = event.target.value
            {"Start": self.start, "Pause": self.pause, "Step": self.step, "Reset": self.reset}[v]()

        g["run"].on_click(on_run)
        g["apply"] = gui.add_button("Apply edits", disabled=True, hint="rebuild the model from the edited scene, "
                                                                        "keeping the current shape")
        g["apply"].on_click(lambda _e: self.apply())
        g["pending"] = gui.add_markdown("No unapplied edits.")
        self._err("run")
        r0 = 1.0
        e = self.sim.settings.e
        g["plot"] = gui.add_uplot(
            data=(np.array([0.0, 1.0]), np.array([r0, r0]), np.array([e, e])),
            series=({"label": "iteration"},
                    {"label": "||V||inf [N]", "stroke": "#1c7ed6", "width": 1.5},
                    {"label": "target e", "stroke": "#e03131", "width": 1.0, "dash": (6.0, 4.0)}),
            scales={"x": {"time": False}, "y": {"distr": 3, "log": 10}},
            title="Convergence", aspect=1.8)
        g["legend_img"] = gui.add_image(colorbar_image(256, 12), format="png")
        g["legend"] = gui.add_markdown("")

        tabs = gui.add_tab_group()
        with tabs.add_tab("View"):
            g["field"] = gui.add_dropdown("Colour by", tuple(FIELDS), initial_value="warp strain")
            g["field"].on_update(lambda _e: self._view_changed())
            g["auto_range"] = gui.add_checkbox("Auto range", True)
            g["range_min"] = gui.add_number("Range min", 0.0)
            g["range_max"] = gui.add_number("Range max", 1.0)
            for k in ("auto_range", "range_min", "range_max"):
                g[k].on_update(lambda _e: self._view_changed())
            g["sheet_opacity"] = gui.add_slider("Sheet opacity", min=0.2, max=1.0, step=0.05, initial_value=1.0)
            g["sheet_opacity"].on_update(lambda _e: self._view_changed())
            g["show_fixed"] = gui.add_checkbox("Show constrained nodes", True)
            g["show_mold"] = gui.add_checkbox("Show mold", True)
            g["mold_opacity"] = gui.add_slider("Mold opacity", min=0.1, max=1.0, step=0.05, initial_value=0.6)
            for k in ("show_fixed", "show_mold", "mold_opacity"):
                g[k].on_update(lambda _e: self._view_changed(mold=True))

        with tabs.add_tab("Solver"):
            s = self.sim.settings
            g["method"] = self._on(gui.add_dropdown("Method", SOLVER_METHODS, initial_value=s.method),
                                   lambda v: self._set_solver(method=v), "solver")
            g["C"] = self._on(gui.add_number("C (step divisor)", float(s.C), step=0.1),
                              lambda v: self._set_solver(C=float(v)), "solver")
            g["e"] = self._on(gui.add_text("e (limit on ||V||inf) [N]", f"{s.e:g}"),
                              lambda v: self._set_solver(e=self._float(v, "e")), "solver")
            g["max_iterations"] = self._on(gui.add_number("Max iterations", int(s.max_iterations), step=1),
                                           lambda v: self._set_solver(max_iterations=self._int(v, "max iterations")),
                                           "solver")
            gui.add_markdown("C, e and max iterations reach a running relaxation at once; the method "
                             "applies from the next Start.")
            self._err("solver")

        with tabs.add_tab("Constraints"):
            g["c_list"] = gui.add_markdown("")
            g["c_select"] = gui.add_dropdown("Constraint", (NEW_CONSTRAINT,))
            g["c_select"].on_update(lambda _e: None if getattr(self._tl, "quiet", 0) else
                                    self.post(self._load_constraint_fields, "constraints"))
            g["c_nodes"] = gui.add_dropdown("Nodes", NODE_SETS + (RANGE_NODES,), initial_value="perimeter")
            g["c_axes"] = gui.add_dropdown("Axes", AXES_CHOICES, initial_value="xyz")
            g["c_stretch"] = gui.add_vector2("Stretch (sx, sy)", (1.0, 1.0), step=0.01)
            g["c_disp"] = gui.add_vector3("Displacement [m]", (0.0, 0.0, 0.0), step=0.001)
            g["c_save"] = gui.add_button("Save constraint")
            g["c_save"].on_click(lambda _e: self.post(self._save_constraint, "constraints"))
            g["c_delete"] = gui.add_button("Delete constraint", color="red")
            g["c_delete"].on_click(lambda _e: self.post(self._delete_constraint, "constraints"))
            self._err("constraints")

        with tabs.add_tab("Material"):
            g["preset"] = self._on(gui.add_dropdown("Preset", ("(custom)",) + tuple(PRESETS)),
                                   self._set_preset, "material")
            g["preset_info"] = gui.add_markdown("")
            g["thickness"] = self._on(gui.add_number("Thickness [mm] (for Pa)", 0.0, min=0.0, step=0.05),
                                      lambda v: self._set_materials(), "material")
            for d in ("warp", "weft"):
                g[f"{d}_unit"] = self._on(
                    gui.add_dropdown(f"{d.capitalize()} unit", ("N/m (tension)", "Pa (stress)")),
                    lambda v: self._set_materials(), "material")
                g[f"{d}_text"] = self._on(gui.add_text(f"{d.capitalize()} table", "", multiline=True,
                                                       hint="one 'strain, value' pair per line"),
                                          lambda v: self._set_materials(), "material")
                up = gui.add_upload_button(f"Upload {d} CSV", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                           hint="header: strain,tension (N/m) or strain,stress (Pa)")
                up.on_upload(self._upload_cb(up, lambda name, data, d=d: self._csv_uploaded(d, name, data),
                                             "material"))
                g[f"{d}_csv"] = up
            self._err("material")
            g["curves"] = gui.add_uplot(
                data=(np.array([0.0, 1.0]), np.array([0.0, 1.0]), np.array([0.0, 1.0])),
                series=({"label": "strain"}, {"label": "warp [N/m]", "stroke": "#1c7ed6", "width": 1.5},
                        {"label": "weft [N/m]", "stroke": "#f08c00", "width": 1.5}),
                title="Tension per width [N/m] vs strain", aspect=1.8)

        with tabs.add_tab("Fabric & mold"):
            g["size"] = self._on(gui.add_vector2("Size [m] (warp, weft)", (0.1, 0.1), step=0.005, min=(1e-6, 1e-6)),
                                 self._set_size, "fabric")
            g["nx"] = self._on(gui.add_number("Warp divisions", 10, step=1),
                               lambda v: self._set_divisions(), "fabric")
            g["ny"] = self._on(gui.add_number("Weft divisions", 10, step=1),
                               lambda v: self._set_divisions(), "fabric")
            g["lift"] = self._on(gui.add_number("Initial lift [m]", 0.0, step=0.001),
                                 lambda v: self._edit_draft("fabric", lambda d: d.setdefault("initial", {})
                                                            .__setitem__("lift", float(v))), "fabric")
            self._err("fabric")
            g["mold"] = self._on(gui.add_dropdown("Mold", ("none",)), lambda v: self._set_mold(), "mold")
            g["mold_scale"] = self._on(gui.add_number("Mold scale (mesh files)", 1.0, step=0.001),
                                       lambda v: self._set_mold(), "mold")
            g["mold_offset"] = self._on(gui.add_vector3("Mold offset [m]", (0.0, 0.0, 0.0), step=0.001),
                                        lambda v: self._set_mold(), "mold")
            up = gui.add_upload_button("Upload mold", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                       hint="STL, OBJ, PLY, OFF, GLB, the paper's .txt, .vtk, .wrl")
            up.on_upload(self._upload_cb(up, self._mold_uploaded, "mold"))
            g["mold_upload"] = up
            g["mold_info"] = gui.add_markdown("")
            self._err("mold")

        with tabs.add_tab("Files"):
            g["save_yaml"] = gui.add_button("Save scene (YAML)", icon=viser.Icon.DOWNLOAD)
            g["save_yaml"].on_click(lambda e: self._download(e, "yaml"))
            for kind, label in (("npz", "Export result (.npz)"), ("ply", "Export sheet (.ply)"),
                                ("csv", "Export history (.csv)")):
                g[f"export_{kind}"] = gui.add_button(label, icon=viser.Icon.DOWNLOAD)
                g[f"export_{kind}"].on_click(lambda e, k=kind: self._download(e, k))
            gui.add_markdown(f"Uploads larger than {self.upload_limit / 2**20:.0f} MB are refused.")
            self._err("files")

    # ------------------------------------------------------------------ widget <-> draft
    def _sync_widgets_from_draft(self) -> None:
        """Show the draft's values in every editor (not counted as edits)."""
        g = self.gui
        d = self.draft
        fab = d["fabric"]
        with self._quiet():
            s = d.get("solver", {})
            g["method"].value = s.get("method", "auto")
            g["C"].value = float(s.get("C", 2.0))
            g["e"].value = f"{float(s.get('e', 1e-6)):g}"
            g["max_iterations"].value = int(s.get("max_iterations", 200000))
            g["size"].value = tuple(float(x) for x in fab["size"])
            g["nx"].value = int(fab["divisions"][0])
            g["ny"].value = int(fab["divisions"][1])
            g["lift"].value = float(d.get("initial", {}).get("lift", 0.0))
            g["thickness"].value = float(fab.get("thickness") or 0.0) * 1000.0
            presets = {fab[k].get("preset") for k in ("warp", "weft")}
            g["preset"].value = presets.pop() if len(presets) == 1 and None not in presets else "(custom)"
            for k in ("warp", "weft"):
                strain, value, unit = self._material_values(k)
                g[f"{k}_unit"].value = "Pa (stress)" if unit == "stress" else "N/m (tension)"
                g[f"{k}_text"].value = table_text(strain, value)
            self._refresh_constraints()
            self._refresh_mold_options()
        self._refresh_curves()
        self._refresh_preset_info()

    def _material_values(self, key: str):
        """(strain, value, 'stress'|'tension') of the draft's warp or weft spec, presets and CSV
        files resolved."""
        spec = self.draft["fabric"][key]
        if spec.get("preset"):
            p = PRESETS[spec["preset"]]
            return list(p.strain), list(getattr(p, key)), "tension"
        if spec.get("csv"):
            scene = self._validate(self.draft)
            text = scene.resolve(spec["csv"]).read_text(encoding="utf-8-sig")
            s, v, kind = parse_table_csv(text, spec["csv"])
            return s.tolist(), v.tolist(), kind
        kind = "stress" if spec.get("stress") is not None else "tension"
        return list(spec["strain"]), list(spec[kind]), kind

    @staticmethod
    def _float(v, name: str) -> float:
        try:
            x = float(str(v).strip())
        except ValueError:
            raise ValueError(f"{name}: not a number ('{v}')") from None
        return x

    @staticmethod
    def _int(v, name: str) -> int:
        x = float(v)
        if not math.isfinite(x) or x != int(x):
            raise ValueError(f"{name}: must be a whole number (got {v})")
        return int(x)

    def _set_solver(self, **kw) -> None:
        from pydantic import ValidationError

        try:
            self.sim.set_solver(**kw)  # validates before recording the edit
        except ValidationError as exc:
            msgs = []
            for err in exc.errors():
                msg = err["msg"].removeprefix("Value error, ")
                msgs.append(f"{'.'.join(str(p) for p in err['loc'])}: {msg}")
            raise SceneError("; ".join(msgs)) from None
        self.draft.setdefault("solver", {}).update(kw)

    def _set_size(self, v) -> None:
        self._edit_draft("fabric", lambda d: d["fabric"].__setitem__("size", [float(v[0]), float(v[1])]))

    def _set_divisions(self) -> None:
        nx = self._int(self.gui["nx"].value, "warp divisions")
        ny = self._int(self.gui["ny"].value, "weft divisions")
        self._edit_draft("fabric", lambda d: d["fabric"].__setitem__("divisions", [nx, ny]))

    # materials ---------------------------------------------------------------
    def _set_materials(self) -> None:
        g = self.gui
        specs = {}
        for k in ("warp", "weft"):
            try:
                strain, value = parse_table_text(g[f"{k}_text"].value)
                kind = "stress" if g[f"{k}_unit"].value.startswith("Pa") else "tension"
                check_table(strain, value, kind)
            except MaterialError as exc:
                raise MaterialError(f"{k}: {exc}") from None
            specs[k] = {"strain": strain, kind: value}
        t = float(g["thickness"].value)
        if not math.isfinite(t) or t < 0:
            raise MaterialError(f"thickness: must be positive (got {t})")

        def mutate(d):
            d["fabric"]["warp"] = specs["warp"]
            d["fabric"]["weft"] = specs["weft"]
            if t > 0:
                d["fabric"]["thickness"] = t / 1000.0
            else:
                d["fabric"].pop("thickness", None)

        self._edit_draft("material", mutate)
        with self._quiet():
            g["preset"].value = "(custom)"
        self._refresh_curves()
        self._refresh_preset_info()

    def _set_preset(self, name: str) -> None:
        if name == "(custom)":
            return
        self._edit_draft("material", lambda d: (d["fabric"].__setitem__("warp", {"preset": name}),
                                                d["fabric"].__setitem__("weft", {"preset": name})))
        with self._quiet():
            p = PRESETS[name]
            for k in ("warp", "weft"):
                self.gui[f"{k}_unit"].value = "N/m (tension)"
                self.gui[f"{k}_text"].value = table_text(p.strain, getattr(p, k))
        self._refresh_curves()
        self._refresh_preset_info()

    def _refresh_preset_info(self) -> None:
        name = self.gui["preset"].value
        self.gui["preset_info"].content = (f"*{html.escape(PRESETS[name].description)}* "
                                           f"(see clothsim/presets.py for sources)"
                                           if name in PRESETS else "")

    def _csv_uploaded(self, key: str, name: str, data: bytes) -> None:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise MaterialError(f"{name}: not a UTF-8 text file") from None
        strain, value, kind = parse_table_csv(text, name)
        with self._quiet():
            self.gui[f"{key}_unit"].value = "Pa (stress)" if kind == "stress" else "N/m (tension)"
            self.gui[f"{key}_text"].value = table_text(strain, value)
        self._set_materials()

    def _refresh_curves(self) -> None:
        try:
            scene = self._validate(self.draft)
            warp, weft = scene.tables()
        except Exception:
            return
        smax = max(float(warp.strain[-1]), float(weft.strain[-1]))
        x = np.unique(np.concatenate([warp.strain, weft.strain, [smax]]))

        self.gui["curves"].data = (x, warp.evaluate(x), weft.evaluate(x))

    # constraints ------------------------------------------------------------
    @staticmethod
    def _describe(c: dict) -> str:
        nodes = c["nodes"] if isinstance(c["nodes"], str) else f"i {c['nodes'].get('i', 'all')}, j {c['nodes'].get('j', 'all')}"
        out = f"{nodes} · axes {c.get('axes', 'xyz')}"
        if c.get("stretch") is not None:
            out += f" · stretch {c['stretch']}"
        if c.get("displacement") is not None:
            out += f" · displacement {list(c['displacement'])} m"
        return out

    def _refresh_constraints(self, select: int | None = None) -> None:
        cons = self.draft.get("constraints", [])
        g = self.gui
        if cons:
            lines = [f"{n + 1}. {html.escape(self._describe(c))}" for n, c in enumerate(cons)]
            g["c_list"].content = "\n".join(lines)
        else:
            g["c_list"].content = "*No constraints: the sheet is held by nothing but the mold.*"
        opts = tuple(f"{n + 1}: {self._describe(c)}" for n, c in enumerate(cons)) + (NEW_CONSTRAINT,)
        with self._quiet():
            g["c_select"].options = opts
            g["c_select"].value = opts[select] if select is not None and select < len(opts) else opts[0]
        self._load_constraint_fields()

    def _selected_constraint(self) -> int | None:
        v = self.gui["c_select"].value
        if v == NEW_CONSTRAINT:
            return None
        return int(v.split(":", 1)[0]) - 1

    def _load_constraint_fields(self) -> None:
        k = self._selected_constraint()
        g = self.gui
        cons = self.draft.get("constraints", [])
        c = cons[k] if k is not None and k < len(cons) else {"nodes": "perimeter", "axes": "xyz"}
        with self._quiet():
            g["c_nodes"].value = c["nodes"] if isinstance(c["nodes"], str) else RANGE_NODES
            g["c_axes"].value = c.get("axes", "xyz") if c.get("axes", "xyz") in AXES_CHOICES else "xyz"
            st = c.get("stretch")
            g["c_stretch"].value = (1.0, 1.0) if st is None else (
                (float(st), float(st)) if isinstance(st, (int, float)) else (float(st[0]), float(st[1])))
            g["c_disp"].value = tuple(float(x) for x in (c.get("displacement") or (0.0, 0.0, 0.0)))

    def _save_constraint(self) -> None:
        g = self.gui
        k = self._selected_constraint()
        cons = self.draft.get("constraints", [])
        nodes = g["c_nodes"].value
        if nodes == RANGE_NODES:
            if k is None or isinstance(cons[k]["nodes"], str):
                raise SceneError("nodes: index ranges are edited in the scene YAML; pick a named set here")
            nodes = cons[k]["nodes"]
        c: dict = {"nodes": nodes, "axes": g["c_axes"].value}
        sx, sy = (float(x) for x in g["c_stretch"].value)
        if (sx, sy) != (1.0, 1.0):
            c["stretch"] = sx if sx == sy else [sx, sy]
        disp = [float(x) for x in g["c_disp"].value]
        if any(disp):
            c["displacement"] = disp

        def mutate(d):
            lst = d.setdefault("constraints", [])
            if k is None:
                lst.append(c)
            else:
                lst[k] = c

        self._edit_draft("constraints", mutate)
        self._refresh_constraints(select=len(cons) if k is None else k)

    def _delete_constraint(self) -> None:
        k = self._selected_constraint()
        if k is None:
            raise SceneError("pick a constraint to delete")
        self._edit_draft("constraints", lambda d: d["constraints"].pop(k))
        self._refresh_constraints(select=max(0, k - 1))

    # mold -------------------------------------------------------------------
    def _mold_options(self) -> dict[str, dict | None]:
        """Label -> mold spec (None = no mold). Primitives are placed under the sheet's centre."""
        fab = self.draft["fabric"]
        ox, oy, oz = (list(fab.get("origin", (0.0, 0.0, 0.0))) + [0.0, 0.0, 0.0])[:3]
        lx, ly = fab["size"]
        cx, cy = ox + lx / 2, oy + ly / 2
        L = min(lx, ly)
        opts: dict[str, dict | None] = {}
        if getattr(self, "_scene_mold_spec", None) is None:
            self._scene_mold_spec = copy.deepcopy(self.draft.get("mold"))
        if self._scene_mold_spec is not None:
            opts["scene's mold"] = self._scene_mold_spec
        opts["none"] = None
        if MOLD_DIR.is_dir():
            for p in sorted(MOLD_DIR.iterdir()):
                if p.suffix.lower() in MOLD_EXTS:
                    opts[f"file: {p.name}"] = {"path": str(p)}
        opts["sphere"] = {"sphere": {"center": [cx, cy, oz - 0.2 * L], "radius": 0.4 * L}}
        opts["box"] = {"box": {"min": [cx - 0.25 * L, cy - 0.25 * L, oz - 0.5 * L],
                               "max": [cx + 0.25 * L, cy + 0.25 * L, oz + 0.15 * L]}}
        opts["cylinder"] = {"cylinder": {"center": [cx, cy, oz - 0.15 * L], "axis": [0.0, 1.0, 0.0],
                                         "radius": 0.3 * L, "length": 1.5 * ly}}
        for label, spec in getattr(self, "_uploads", {}).items():
            opts[label] = spec
        return opts

    def _refresh_mold_options(self, select: str | None = None) -> None:
        opts = self._mold_options()
        labels = tuple(opts)
        g = self.gui
        with self._quiet():
            g["mold"].options = labels
            if select is None:
                select = "scene's mold" if "scene's mold" in opts else "none"
            g["mold"].value = select
        self._refresh_mold_info()

    def _refresh_mold_info(self) -> None:
        spec = self.draft.get("mold")
        self.gui["mold_info"].content = (f"Current: `{html.escape(str(spec))}`" if spec is not None
                                         else "Current: no mold")

    def _mold_spec(self) -> dict | None:
        g = self.gui
        label = g["mold"].value
        opts = self._mold_options()
        if label not in opts:
            raise MoldError(f"unknown mold choice {label!r}")
        spec = copy.deepcopy(opts[label])
        if spec is None:
            return None
        scale = float(g["mold_scale"].value)
        off = [float(x) for x in g["mold_offset"].value]
        if "path" in spec:
            base = float(spec.get("scale", 1.0)) if label == "scene's mold" else 1.0
            if not (math.isfinite(scale) and scale > 0):
                raise MoldError(f"scale: must be positive (got {scale})")
            spec["scale"] = base * scale
            if any(off) or "translate" in spec:
                t0 = spec.get("translate", [0.0, 0.0, 0.0])
                spec["translate"] = [a + b for a, b in zip(t0, off)]
            if spec["scale"] == 1.0:
                spec.pop("scale")
        elif any(off):
            kind, prm = next(iter(spec.items()))
            for key in ("center", "point", "min", "max"):
                if key in prm:
                    prm[key] = [a + b for a, b in zip(prm[key], off)]
        return spec

    def _set_mold(self) -> None:
        spec = self._mold_spec()
        scene = self._validate({**self.draft, "mold": spec})  # field-level check first
        mold = load_mold(spec, scene.base_dir) if spec is not None else None  # parse: errors shown here
        self._edit_draft("mold", lambda d: d.__setitem__("mold", spec) if spec is not None else d.pop("mold", None))
        self._mold_preview = mold if mold is not None else "none"
        self._mold_dirty = True
        self._refresh_mold_info()

    def _mold_uploaded(self, name: str, data: bytes) -> None:
        scale = float(self.gui["mold_scale"].value)
        off = [float(x) for x in self.gui["mold_offset"].value]
        # parse in memory first: an unknown or broken file is refused before anything is written
        load_mold_bytes(data, name, scale=scale, translate=off)
        self._upload_n += 1
        ext = Path(name).suffix.lower()
        stored = self._tmpdir / f"mold_upload_{self._upload_n}{ext if ext in MOLD_EXTS else ''}"
        stored.write_bytes(data)
        label = f"upload: {Path(name).name[:60]}"
        if not hasattr(self, "_uploads"):
            self._uploads = {}
        self._uploads[label] = {"path": str(stored)}
        self._refresh_mold_options(select=label)
        self._set_mold()

    # uploads ----------------------------------------------------------------
    def _on_upload_start(self, client_id, message) -> None:
        """Runs on viser's event loop when a browser announces an upload: refuse it at once if it
        is too large (the transfer state is dropped, so its parts are ignored)."""
        if message.size_bytes <= self.upload_limit:
            return
        self.server.gui._current_file_upload_states.pop(message.transfer_uuid, None)
        msg = (f"{message.filename}: {message.size_bytes / 2**20:.1f} MB is over the upload limit of "
               f"{self.upload_limit / 2**20:.0f} MB (--upload-limit-mb)")
        group = "mold" if message.source_component_uuid == self.gui["mold_upload"]._impl.uuid else "material"
        self.post(lambda: (_ for _ in ()).throw(ValueError(msg)), group)
        client = self.server.get_clients().get(client_id)
        if client is not None:
            client.add_notification("Upload refused", msg, color="red", auto_close_seconds=10.0)

    def _upload_cb(self, handle, fn: Callable[[str, bytes], None], group: str):
        def cb(_event) -> None:
            f = handle.value
            name, data = f.name, f.content
            if len(data) > self.upload_limit:
                msg = f"{name}: over the upload limit of {self.upload_limit / 2**20:.0f} MB"
                self.post(lambda: (_ for _ in ()).throw(ValueError(msg)), group)
                return
            self.post(lambda: fn(name, data), group)

        return cb

    # downloads --------------------------------------------------------------
    def _download(self, event, kind: str) -> None:
        """Send a file to the tab that asked (built by the update loop, which owns the draft)."""
        client = event.client
        if client is not None:
            self.post(lambda: self._send_file(client, kind), "files")

    def _send_file(self, client, kind: str) -> None:
        try:
            if kind == "yaml":
                name, data = f"{self.sim.scene.name}.yaml", self.scene_yaml().encode()
            else:
                result = self.sim.result()
                if kind == "npz":
                    name, data = "result.npz", result.npz_bytes()
                elif kind == "ply":
                    fld = "pressure" if self._field_key == "pressure" else "strain"
                    name, data = "sheet.ply", result.colored_mesh(fld).export(file_type="ply")
                else:
                    name, data = "history.csv", result.history_csv().encode()
            client.send_file_download(name, data, save_immediately=True)
        except Exception as exc:
            raise ValueError(f"{kind}: {type(exc).__name__}: {exc}") from None

    def scene_yaml(self) -> str:
        """The edited scene (the draft) as YAML, with file paths made absolute so it loads from
        wherever it is saved."""
        scene = self._validate(self.draft).resolved()
        head = f"# saved by the clothsim viewer on {time.strftime('%Y-%m-%d %H:%M')}\n"
        if scene.mold is not None and str(self._tmpdir) in str(getattr(scene.mold, "path", "")):
            head += "# the mold was uploaded: its temporary copy disappears when the viewer stops\n"
        if self.pending:
            head += f"# includes edits not yet applied in the viewer: {', '.join(sorted(self.pending))}\n"
        return head + scene.to_yaml()

    # ------------------------------------------------------------------ view
    def _view_changed(self, mold: bool = False) -> None:
        if getattr(self._tl, "quiet", 0):
            return
        self._view_dirty = True
        self._mold_dirty = self._mold_dirty or mold
        self._wake.set()

    def _on_connect(self, client) -> None:
        model = self.sim.model
        p = model.rest_positions
        lo, hi = p.min(axis=0), p.max(axis=0)
        if model.mold is not None:
            try:
                mb = np.asarray(model.mold.bounds, float)
                if mb.shape == (2, 3) and np.isfinite(mb).all() and np.ptp(mb, axis=0).max() < 10 * max(np.ptp(p, axis=0).max(), 1e-9):
                    lo, hi = np.minimum(lo, mb[0]), np.maximum(hi, mb[1])
            except Exception:
                pass
        c = 0.5 * (lo + hi)
        r = max(float(np.linalg.norm(hi - lo)) * 0.5, 1e-3)
        d = np.array([0.45, -1.0, 0.8])
        client.camera.up_direction = (0.0, 0.0, 1.0)
        client.camera.position = tuple(c + 1.6 * r * d / np.linalg.norm(d))
        client.camera.look_at = tuple(c)
        client.camera.near = r * 0.01
        client.camera.far = r * 100.0

    def _rebuild_nodes(self, model) -> None:
        """Scene nodes for a (new) model: created once per model, then updated in place."""
        nx1, ny1 = model.grid_shape
        faces = grid_faces(nx1, ny1)
        self._glb = GlbMeshWriter(faces)
        pos = model.rest_positions
        vals = np.zeros(model.node_count)
        glb = self._glb.build(pos, colormap(vals, 0, 1), grid_normals(pos, nx1, ny1))
        self.h_cloth = self.server.scene.add_glb("/sheet", glb)
        fixed = model.fixed_axes.any(axis=1)
        self._fixed_idx = np.nonzero(fixed)[0]
        dx, dy = model.spacing if model.spacing and min(model.spacing) > 0 else (0.01, 0.01)
        size = float(max(0.3 * min(dx, dy), 0.002 * np.ptp(pos, axis=0).max()))
        if self.h_fixed is not None:
            self.h_fixed.remove()
            self.h_fixed = None
        if len(self._fixed_idx):
            self.h_fixed = self.server.scene.add_point_cloud(
                "/constrained", pos[self._fixed_idx].astype(np.float32), colors=(230, 40, 40),
                point_size=size, point_shape="circle", precision="float32",
                visible=bool(self.gui["show_fixed"].value))
        # seams: one thread per sewn node pair (it shrinks to nothing as the seam closes)
        if self.h_seams is not None:
            self.h_seams.remove()
            self.h_seams = None
        self._seam_ab = model.spring_nodes[model.spring_family == FAMILY_SEAM]
        if len(self._seam_ab):
            self.h_seams = self.server.scene.add_line_segments(
                "/seams", self._seam_points(pos), colors=(255, 140, 0), thickness=2.0,
                thickness_units="screen")
        self._scene_model = model
        self._mold_dirty = True

    def _seam_points(self, pos: np.ndarray) -> np.ndarray:
        """(P, 2, 3) float32 end points of the seam threads."""
        return np.stack([pos[self._seam_ab[:, 0]], pos[self._seam_ab[:, 1]]], axis=1).astype(np.float32)

    def _update_mold_node(self) -> None:
        g = self.gui
        mold = self._mold_preview if self._mold_preview is not None else self.sim.model.mold
        pending = self._mold_preview is not None
        if mold == "none":
            mold = None
        if mold is None:
            if self.h_mold is not None:
                self.h_mold.remove()
                self.h_mold = None
            self._shown_mold = None
        else:
            if getattr(self, "_shown_mold", None) is not mold or self.h_mold is None:
                ext = float(np.ptp(self.sim.model.rest_positions, axis=0).max()) * 2.0
                V, F = mold.surface_mesh(resolution=64, extent=max(ext, 1e-3))
                V = self._inset(np.asarray(V, np.float64), np.asarray(F, np.int64))
                self.h_mold = self.server.scene.add_mesh_simple(
                    "/mold", np.asarray(V, np.float32), np.asarray(F, np.uint32), color=(150, 150, 160),
                    side="double", opacity=1.0)
                self._shown_mold = mold
            op = float(g["mold_opacity"].value)
            self.h_mold.opacity = None if op >= 0.999 else op
            self.h_mold.color = (235, 140, 50) if pending else (150, 150, 160)
            self.h_mold.visible = bool(g["show_mold"].value)
        self._mold_dirty = False

    def _inset(self, V: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Display only: move the mold's surface inwards by a quarter of the grid spacing, so that
        the sheet's flat triangles spanning nodes in contact (chords of a curved mold) do not
        show the mold poking through them."""
        try:
            import trimesh

            dx, dy = self.sim.model.spacing
            d = 0.25 * min(dx, dy)
            if not (d > 0) or len(F) == 0:
                return V
            n = trimesh.Trimesh(V, F, process=False).vertex_normals
            return V - d * np.asarray(n)
        except Exception:
            return V

    def _current_range(self, values: np.ndarray) -> tuple[float, float]:
        g = self.gui
        if not g["auto_range"].value:
            lo, hi = float(g["range_min"].value), float(g["range_max"].value)
            if math.isfinite(lo) and math.isfinite(hi) and hi > lo:
                return lo, hi
        finite = values[np.isfinite(values)]
        if self._field_key == "contact":
            return 0.0, 1.0
        if not len(finite):
            return 0.0, 1.0
        lo, hi = float(finite.min()), float(finite.max())
        if self._field_key == "pressure":
            lo = 0.0
        if hi <= lo:
            hi = lo + (1.0 if lo == 0 else abs(lo) * 1e-3)
        return lo, hi

    def _push_frame(self, f: Frame) -> None:
        model = f.model
        nx1, ny1 = model.grid_shape
        self._field_key = FIELDS[self.gui["field"].value][1]
        vals = node_field(model, f.positions, f.in_contact, self._field_key)
        lo, hi = self._current_range(vals)
        self._range = (lo, hi)
        glb = self._glb.build(f.positions, colormap(vals, lo, hi), grid_normals(f.positions, nx1, ny1),
                              opacity=float(self.gui["sheet_opacity"].value))
        self.h_cloth.glb_data = glb
        if self.h_fixed is not None:
            self.h_fixed.points = f.positions[self._fixed_idx].astype(np.float32)
            self.h_fixed.visible = bool(self.gui["show_fixed"].value)
        if self.h_seams is not None:
            self.h_seams.points = self._seam_points(f.positions)
        label = self.gui["field"].value
        unit = FIELDS[label][0]
        if self._field_key == "contact":
            legend = "**in contact**: dark = free, yellow = touching the mold"
        else:
            tiny = 1e-9 * max(abs(lo), abs(hi))
            lo_s, hi_s = _fmt(0.0 if abs(lo) < tiny else lo), _fmt(0.0 if abs(hi) < tiny else hi)
            legend = f"**{label}**{f' [{unit}]' if unit else ''}: {lo_s} (dark) … {hi_s} (yellow)"
        if legend != self._legend_text:
            self._legend_text = legend
            self.gui["legend"].content = legend
        self.pushed_positions = f.positions
        self.pushed_iteration = f.iteration
        self.frames_pushed += 1
        self._last_frame = f

    def _push(self) -> None:
        sim = self.sim
        model = sim.model
        if model is not self._scene_model:
            self._rebuild_nodes(model)
            self._last_frame = None
        if self._mold_dirty:
            self._update_mold_node()
        with self._lock:
            frame, self._frame = self._frame, None
        if frame is not None and frame.model is not model:
            frame = None
        running = sim.status == "running"
        if not running:  # the state is still: show it exactly (once per change)
            key = (sim.version, sim.state.iteration, id(model))
            if key != getattr(self, "_still_key", None) or self._last_frame is None:
                snap = sim.snapshot()
                if sim.model is model:
                    frame = Frame(snap.positions, snap.in_contact, snap.iteration, model)
                    self._still_key = key
        if frame is None and self._view_dirty and self._last_frame is not None:
            frame = self._last_frame
        self._view_dirty = False
        if frame is not None:
            self._push_frame(frame)
        self._push_status(running)
        self._push_plot(running)

    def _push_status(self, running: bool) -> None:
        sim = self.sim
        status = sim.status
        r = sim.residual
        if not math.isfinite(r):
            r = self._initial_residual()
        it = sim.state.iteration
        contact = int(np.count_nonzero(self._last_frame.in_contact)) if self._last_frame is not None else 0
        ips = sim.ips if running else 0.0
        text = (f"**{STATE_TEXT.get(status, status)}** · iteration {it} · residual {_fmt(r, 3)} N "
                f"(e = {_fmt(sim.settings.e, 2)} N) · {contact} contact nodes · {ips:,.0f} it/s · {sim.method}")
        if sim.message and status not in ("running", "idle", "paused"):
            text += f"  \n<small>{html.escape(sim.message)}</small>"
        if not running and self._last_frame is not None:
            text += "  \n" + self._health_text(self._last_frame)
        if text != self._status_text:
            self._status_text = text
            self.gui["status"].content = text

    def _health_text(self, f: Frame) -> str:
        """Slack springs, undetermined nodes and the sheet's narrowest weft extent: a band that
        gathers into a rope or a region held by nothing is shown, not hidden."""
        key = (id(f.model), f.iteration, id(f.positions))
        if getattr(self, "_health_key", None) != key:
            h = sheet_health(f.model, f.positions, f.in_contact)
            warn = h["min_weft_extent_ratio"] < 0.5 or h["undetermined_nodes"] > 0
            txt = (f"{h['slack_springs']} of {h['spring_count']} springs slack · "
                   f"{h['undetermined_nodes']} undetermined nodes · narrowest weft extent "
                   f"{h['min_weft_extent_ratio']:.0%} of the rest width")
            if h["min_weft_extent_ratio"] < 0.5:
                txt += " (the sheet gathers: nothing holds its width)"
            self._health = f"<small>{'⚠ ' if warn else ''}{txt}</small>"
            self._health_key = key
        return self._health

    def _initial_residual(self) -> float:
        key = (id(self.sim.model), self.sim.state.iteration, self.sim.version)
        if getattr(self, "_r0_key", None) != key:
            from .solvers.common import residual

            with self.sim._lock:
                self._r0 = float(residual(self.sim.model, self.sim.state)[0])
            self._r0_key = key
        return self._r0

    def _push_plot(self, running: bool) -> None:
        now = time.perf_counter()
        if running and now - self._plot_last < max(0.25, 8 * self.min_period):
            return
        sim = self.sim
        if sim.version != self._hist_version:
            snap = sim.snapshot()
            self._hist = (snap.history_iteration.astype(np.float64), snap.history_residual.astype(np.float64))
            self._hist_version = sim.version
        hx, hy = self._hist
        with self._lock:
            lx = np.asarray(self._live_it, np.float64)
            ly = np.asarray(self._live_res, np.float64)
        if len(hx) and len(lx):
            keep = lx > hx[-1]
            lx, ly = lx[keep], ly[keep]
        x = np.concatenate([hx, lx])
        y = np.concatenate([hy, ly])
        ok = np.isfinite(y) & (y > 0)
        x, y = x[ok], y[ok]
        if len(x) == 0:
            r0 = self._initial_residual()
            x, y = np.array([0.0, 1.0]), np.array([r0, r0])
        elif len(x) == 1:
            x, y = np.array([x[0] - 1, x[0]]), np.array([y[0], y[0]])
        x, y = _thin(x, y)
        e = float(sim.settings.e)
        key = (len(x), float(x[-1]), float(y[-1]), float(y.min()), e)
        if key == self._plot_key:
            return
        self._plot_key = key
        self._plot_last = now
        lo = min(float(y.min()), e) * 0.8
        hi = max(float(y.max()), e) * 1.25
        splits = _decades(lo, hi)
        plot = self.gui["plot"]
        if splits != self._plot_axes_key:
            self._plot_axes_key = splits
            plot.axes = ({"label": "iteration"},
                         {"splits": splits, "values": tuple(f"1e{round(math.log10(s))}" for s in splits),
                          "size": 48})
            plot.scales = {"x": {"time": False}, "y": {"distr": 3, "log": 10, "range": (splits[0], splits[-1])}}
        plot.data = (x, y, np.full_like(y, e))


# ---------------------------------------------------------------------- command line


def _is_loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


def main(args) -> int:
    """``clothsim view [scene] [--host H] [--port P] [--upload-limit-mb M] [--no-browser]``."""
    try:
        scene = load_scene(args.scene)
    except (SceneError, MoldError, MaterialError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    host = args.host
    if not _is_loopback(host):
        print(f"warning: binding {host}: anyone who can reach this machine on that network can view and "
              f"drive the simulation, upload files and download results", file=sys.stderr)
    try:
        app = ViewerApp(scene, host=host, port=args.port, upload_limit_mb=args.upload_limit_mb, verbose=True)
    except (SceneError, MoldError, MaterialError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if app.port != args.port:
        print(f"note: port {args.port} is busy; using {app.port}", file=sys.stderr)
    print(f"clothsim viewer: {app.url}  (scene {args.scene}; Ctrl+C stops)", flush=True)
    if not getattr(args, "no_browser", False):
        try:
            import webbrowser

            webbrowser.open(app.url)
        except Exception:
            pass
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("\nstopping", file=sys.stderr)
    finally:
        app.close()
    return 0
