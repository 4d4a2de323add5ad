"""The browser app (viser): the server, and the one update loop that owns the scene.

Threads and ownership (the pattern of viser's own examples):

- the **solver thread** belongs to :class:`clothsim.simulation.Simulation`; between batches it calls
  :meth:`ViewerApp.on_progress`, which only appends (iteration, residual) to the live history and,
  at most once per frame period, copies the positions (a consistent frame: the solver is between
  batches);
- **GUI callbacks** (viser's thread pool, possibly several at once from several tabs) only read
  the widget's value and *post* a task under a lock; they never touch the simulation or the scene;
- one **update loop** thread runs the posted tasks in order (the draft's typed edits,
  ``set_solver``, ``replace_scene``, start/pause/step/reset), then pushes the newest frame through
  :class:`~clothsim.viewer.render.SceneRenderer`, which creates scene nodes once per model and
  updates them in place. Its rate is bounded (``max_rate_hz``, default 25) and adapts so that its
  own work stays below a few percent of the wall time: the solver's numba kernels hold the GIL,
  so any Python the viewer runs is time the solver loses. After each push it re-frames the tabs'
  cameras when the sheet grew well beyond their view, and lets the probes panel read a recorded
  click (a ray) and, on still frames, the probes;
- the **report** download is built on a thread of its own from a Result snapshot the loop took
  (it renders figures for seconds) and only sends the file.

Every edit is validated before anything changes (an invalid value leaves the scene as it was and
shows a red message next to the widget). Solver settings (C, e, max iterations, method) apply to
the running relaxation; model edits (constraints, materials, fabric, mold, initial lift) are
collected in the :class:`~clothsim.viewer.draft.SceneDraft` and applied with **Apply** (keeping
the current shape as a warm start) or **Reset** (from the initial deformation).

Safety (:mod:`clothsim.viewer.guard`): binds 127.0.0.1 unless ``--host`` says otherwise; the
websocket accepts only the viewer's own page as Origin (and, off loopback, only with the token of
:attr:`ViewerApp.url`); every GUI value is checked before viser stores or broadcasts it; uploads
are limited by the bytes actually received, per upload and for all tabs together, and
abandoned ones are dropped (closed tab, or no data for a minute); uploads are parsed in memory; an accepted mold upload
is stored in a private temporary folder (mode 0700) under a name chosen here, never the browser's.
A refused value is shown as an error and its widget shows the last valid value again.
"""

from __future__ import annotations

import html
import math
import re
import shutil
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import viser

from ..config import Scene, SceneError
from ..material import MaterialError
from ..mold import MoldError
from .. import kernels_cached, simulation
from ..simulation import Simulation
from .draft import SceneDraft
from .fields import node_field
from .guard import GuiValueGuard, HandshakeCheck, UploadGuard, guarded_server, is_loopback, new_token
from .panels.constraints import ConstraintsPanel
from .panels.fabric import FabricPanel
from .panels.files import FilesPanel
from .panels.garment import GarmentPanel
from .panels.levels import LevelsPanel
from .panels.material import MaterialPanel
from .panels.probes import ProbesPanel
from .panels.run import RunPanel
from .panels.solver import SolverPanel
from .panels.stages import StagesPanel
from .panels.view import ViewPanel
from .plot import PLOT_POINTS, ResidualPlot
from .render import Frame, SceneRenderer, camera_box, frame_camera, needs_reframe


STARTUP_NOTE = "Starting up"
# how long start/pause/step/reset/apply(wait=True) wait for the update loop to run the request
CONTROL_WAIT_S = 600.0


def _startup_html(elapsed: float, cached: bool) -> str:
    """The note a background start shows until the model and kernels are ready; cached: numba's
    cache holds this version's kernels (``clothsim.kernels_cached``), so they are loaded, not
    compiled."""
    what = ("loading the solver's compiled kernels from numba's cache (a few seconds)" if cached else
            "compiling the solver's kernels (the first start after an install or an update: a minute "
            "or two on two cores; numba caches them, so later starts take a few seconds)")
    return (f'<div style="padding:0.5em 0"><b>{STARTUP_NOTE}...</b> {elapsed:.0f} s<br>'
            f'<span style="font-size:0.85em">Building the scene and {what}. '
            f'The relaxation starts when they are ready.</span></div>')


def warm_kernels(sim: Simulation) -> None:
    """Compile (or load from numba's cache) every kernel the relaxation and the display will
    call, so that a run started afterwards draws its first frame at once."""
    simulation.warm_up(sim.model, sim.state, sim.settings)
    sim.current_residual()
    for key in ("strain_warp", "pressure"):
        try:
            node_field(sim.model, sim.state.positions, sim.state.in_contact, key)
        except Exception:  # noqa: BLE001 - best effort: the display compiles the rest on first use
            pass


class _Quiet(threading.local):
    """Per-thread depth of :meth:`ViewerApp.quiet` blocks."""

    depth = 0


class ViewerApp:
    """The viser app around one :class:`Simulation`. Several browser tabs share it.

    The public methods (start, pause, step, reset, apply, post, wait_idle, close) are what the
    buttons do; tests drive the app through them, through the GUI handles in ``self.gui`` and
    through the panels in ``self.panels``.

    ``token``: the secret the websocket requires (None: a new one when ``host`` is not a loopback
    address, none on loopback; "" : none). ``port`` 0 picks a free port; a busy one is skipped."""

    def __init__(self, scene: Scene, *, host: str = "127.0.0.1", port: int = 8080,
                 upload_limit_mb: float = 200.0, max_rate_hz: float = 25.0, duty: float = 0.02,
                 verbose: bool = False, token: str | None = None, background: bool = False,
                 autostart: bool = False, warm: Callable[[Simulation], None] | None = None,
                 upload_idle_s: float = 60.0):
        """``background``: serve the page at once, with a "compiling kernels" note, and in a
        start-up thread build the model and the panels (the scene is drawn), then compile (or
        load from numba's cache) the solver's kernels with ``warm(sim)`` (default
        :func:`warm_kernels`); ``ready`` is set when done (``startup_error`` holds the message if
        the scene could not be built). Otherwise the model and panels are built here, before the
        constructor returns, and nothing is warmed. ``autostart``: start the relaxation once
        ready. ``upload_limit_mb`` bounds one upload and, for the whole server, the uploads in
        flight from every tab together; an upload with no data for ``upload_idle_s`` seconds is
        dropped."""
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ValueError(f"port must be a whole number from 0 to 65535 (got {port})")
        if not (math.isfinite(upload_limit_mb) and upload_limit_mb >= 0):
            raise ValueError(f"upload limit must be a finite number of MB >= 0 (got {upload_limit_mb})")
        self._t_created = time.perf_counter()
        self.token = (None if is_loopback(host) else new_token()) if token is None else (token or None)
        self.upload_limit = int(upload_limit_mb * 1024 * 1024)
        self.min_period = 1.0 / max_rate_hz
        self.duty = duty
        self.verbose = verbose
        self._label = str(scene.source) if scene.source is not None else "<scene>"
        self._lock = threading.Lock()
        self._tasks: list[tuple[Callable[[], None], str | None]] = []
        self._quiet = _Quiet()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._frame: Frame | None = None  # the newest frame from the solver thread
        self._last_frame: Frame | None = None  # the frame shown last
        self._last_capture = 0.0
        self._live_it: list[int] = []
        self._live_res: list[float] = []
        self._still_key: tuple | None = None
        self._r0_key: tuple | None = None
        self._r0 = math.nan
        self._hist_version = -1
        self._hist = (np.zeros(0), np.zeros(0))
        self._view_dirty = True
        self._mold_dirty = True
        self._framed_model = None
        self._work_avg: float | None = None
        self.upload_dir = Path(tempfile.mkdtemp(prefix="clothsim-uploads-"))  # mkdtemp: mode 0700
        self.frames_pushed = 0
        self.pushed_iteration = -1
        self.shown = None  # (status, version) of the solver the display last showed
        self.pushed_positions: np.ndarray | None = None
        self.loop_work_s = 0.0
        self.errors: dict[str, str] = {}
        self._valid: dict[int, object] = {}  # id(handle) -> its last valid value
        self._edit_group: dict[int, str | None] = {}  # id(handle) -> edit group
        self._edit_handles: list = []
        self.ready = threading.Event()  # the model, kernels and panels are built (or failed)
        self.startup_error: str | None = None
        self.startup_s: float | None = None  # [s] from construction to ready
        self.gui: dict[str, object] = {}
        self.panels: dict[str, object] = {}
        self._thread: threading.Thread | None = None

        self.handshake = HandshakeCheck(loopback=is_loopback(host), token=self.token)
        self.server = guarded_server(host, port, self.handshake)
        self.host = host
        self.port = self.server.get_port()
        self.server.gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        self.server.scene.set_up_direction("+z")
        self.framed_box: tuple | None = None  # the box every tab's camera was last pointed at
        self.reframes = 0
        self.upload_guard = UploadGuard(self.server, self.upload_limit, self._upload_refused,
                                        idle_timeout=upload_idle_s)

        if background:
            self._kernels_cached = kernels_cached()
            self._startup_note = self.server.gui.add_html(_startup_html(0.0, self._kernels_cached))
            threading.Thread(target=self._start_up, args=(scene, warm or warm_kernels, autostart),
                             name="clothsim-startup", daemon=True).start()
        else:
            self._startup_note = None
            self._build(scene, warm)
            self.startup_s = time.perf_counter() - self._t_created
            self.ready.set()
            if autostart:
                self.start()

    def _build(self, scene: Scene, warm: Callable[[Simulation], None] | None) -> None:
        """The model (mold), ``warm(sim)`` if given, the panels, the value guard and the update
        loop."""
        self.sim = Simulation(scene, on_progress=self.on_progress)
        if warm is not None:
            warm(self.sim)
        if self._stop.is_set():
            return
        self.scene_draft = SceneDraft(scene, upload_dir=self.upload_dir)
        self.server.on_client_connect(self._frame_new_client)  # registered once the model exists
        self.renderer = SceneRenderer(self.server.scene)
        self.panels.update({"run": RunPanel(self), "view": ViewPanel(self), "solver": SolverPanel(self),
                            "constraints": ConstraintsPanel(self), "material": MaterialPanel(self),
                            "fabric": FabricPanel(self), "files": FilesPanel(self),
                            "probes": ProbesPanel(self), "garment": GarmentPanel(self),
                            "stages": StagesPanel(self), "levels": LevelsPanel(self)})
        self.plot = self._build_gui()
        self.server.scene.on_click()(self.panels["probes"].on_scene_click)  # records the ray only
        self.sync_widgets()
        self._mark_valid()
        self.value_guard = GuiValueGuard(self.server, self._input_handles(), self._value_refused)
        self._thread = threading.Thread(target=self._loop, name="clothsim-viewer", daemon=True)
        self._thread.start()

    def _start_up(self, scene: Scene, warm: Callable[[Simulation], None], autostart: bool) -> None:
        """The start-up thread of a background start, while the page shows a note (its elapsed
        time ticking): build the model and the panels (the scene is drawn once they are), warm
        the kernels, then remove the note and, if asked, start the run."""
        ticking = threading.Event()

        def tick() -> None:
            while not ticking.wait(1.0):
                note = self._startup_note
                if note is not None:
                    note.content = _startup_html(time.perf_counter() - self._t_created, self._kernels_cached)

        threading.Thread(target=tick, name="clothsim-startup-note", daemon=True).start()
        try:
            self._build(scene, None)  # the scene is drawn as soon as its model is built
            if not self._stop.is_set():
                warm(self.sim)  # then the solver's kernels: the note stays until they are ready
        except Exception as exc:  # noqa: BLE001 - shown on the page and by `view` (exit 2)
            known = (SceneError, MoldError, MaterialError, ValueError)
            self.startup_error = str(exc) if isinstance(exc, known) else f"{type(exc).__name__}: {exc}"
            ticking.set()
            self._startup_note.content = (f'<div style="color:#c92a2a">&#9888; The scene could not be built: '
                                          f'{html.escape(self.startup_error)}</div>')
            self.ready.set()
            return
        ticking.set()
        if self._stop.is_set():
            return
        for client in list(self.server.get_clients().values()):  # tabs opened while compiling
            try:
                self._frame_new_client(client)
            except Exception:  # noqa: BLE001 - a tab that just closed
                pass
        self._startup_note.remove()
        self._startup_note = None
        self.startup_s = time.perf_counter() - self._t_created
        if autostart:
            self.start()
        self.ready.set()

    # ------------------------------------------------------------------ public controls
    @property
    def url(self) -> str:
        """The address to open (with the token, when one is required)."""
        host = "127.0.0.1" if self.host in ("0.0.0.0", "", "::") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.port}" + (f"/?token={self.token}" if self.token else "")

    @property
    def draft(self) -> dict:
        """The edited scene as a dict (read it; edit through the panels or ``scene_draft``)."""
        return self.scene_draft.data

    @property
    def pending(self) -> set[str]:
        """Edit groups waiting for Apply."""
        return self.scene_draft.pending

    def post(self, fn: Callable[[], None], group: str | None = None) -> None:
        """Queue fn for the update loop (the only thread that changes the simulation or scene).
        An exception it raises becomes the error line of ``group``."""
        with self._lock:
            self._tasks.append((fn, group))
            self._idle.clear()
        self._wake.set()

    def start(self, wait: bool = False) -> None:
        """Start (or resume) the relaxation; ``wait``: return once the loop has run the request."""
        self._control(self._do_start, wait)

    def pause(self, wait: bool = False) -> None:
        self._control(self.sim.pause, wait)

    def step(self, wait: bool = False) -> None:
        self._control(self._do_step, wait)

    def run_stage(self, wait: bool = False) -> None:
        """Run until the current stage of a staged scene ends, then pause."""
        self._control(self._do_stage, wait)

    def reset(self, wait: bool = False) -> None:
        """Back to the initial deformation, with the edited scene if there are unapplied edits."""
        self._control(self._do_reset, wait)

    def apply(self, wait: bool = False) -> None:
        """Rebuild the model from the edited scene, keeping the current shape as a warm start; a
        running relaxation goes on with the new model."""
        self._control(lambda: self._do_apply(reset=False), wait)

    def scene_yaml(self) -> str:
        """The edited scene as YAML (what *Save scene* downloads)."""
        return self.scene_draft.scene_yaml()

    def _control(self, fn: Callable[[], None], wait: bool) -> None:
        self.post(fn, "run")
        # the loop may be compiling kernels (a cold numba cache: about a minute) before it gets
        # to the request: wait for it rather than return as if it had run
        if wait and not self.wait_idle(CONTROL_WAIT_S):
            raise TimeoutError(f"the viewer's update loop did not run the request within {CONTROL_WAIT_S:.0f} s")

    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Block until every posted task has run and a frame has been pushed after them."""
        return self._idle.wait(timeout)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        fabric = self.panels.get("fabric")
        if fabric is not None and fabric.job is not None:
            fabric.job.cancel()
        sim = getattr(self, "sim", None)
        if sim is not None:
            sim.close()
        if self._thread is not None:
            self._thread.join(timeout=10)
        try:
            self.server.stop()
        finally:
            shutil.rmtree(self.upload_dir, ignore_errors=True)

    # ------------------------------------------------------------------ for the panels
    def quiet(self):
        """Context in which widget assignments made here do not count as user edits."""
        app = self

        class _Q:
            def __enter__(self):
                app._quiet.depth += 1

            def __exit__(self, *a):
                app._quiet.depth -= 1

        return _Q()

    def is_quiet(self) -> bool:
        return self._quiet.depth > 0

    def on(self, handle, fn: Callable, group: str | None, restore: bool = True):
        """Register fn(value) as a user edit of handle, run by the update loop. If fn refuses
        the value (raises), the widget shows its last valid value again, unless ``restore`` is
        False (a text the user is typing: it stays, with its error next to it)."""

        def cb(_event) -> None:
            if self.is_quiet():
                return
            value = handle.value
            self.post(lambda: self._edit(handle, fn, value, restore), group)

        handle.on_update(cb)
        self._edit_group[id(handle)] = group
        self._edit_handles.append(handle)
        return handle

    def _edit(self, handle, fn: Callable, value, restore: bool = True) -> None:
        try:
            fn(value)
        except Exception:
            if restore:
                self._restore(handle)
            raise
        self._mark_valid(self._edit_group[id(handle)])

    def _mark_valid(self, group: str | None = "*") -> None:
        """The edit widgets of ``group`` (all: "*") show valid values now."""
        for h in self._edit_handles:
            if group == "*" or self._edit_group[id(h)] == group:
                self._valid[id(h)] = h.value

    def _restore(self, handle, resend: bool = False) -> None:
        """Show the widget's last valid value again (in every tab); ``resend``: also when the
        server still holds it (the refused value never reached the server, only the tab)."""
        if id(handle) not in self._valid:
            return
        valid = self._valid[id(handle)]
        with self.quiet():
            if resend and handle.value == valid:
                handle.value = _other(handle, valid)
            handle.value = valid

    def _input_handles(self) -> dict:
        inputs = (viser.GuiNumberHandle, viser.GuiSliderHandle, viser.GuiVector2Handle, viser.GuiVector3Handle,
                  viser.GuiTextHandle, viser.GuiDropdownHandle, viser.GuiCheckboxHandle)
        return {h._impl.uuid: h for h in self.gui.values() if isinstance(h, inputs)}

    def _value_refused(self, handle, why: str) -> None:
        """From viser's event loop: a tab sent a value the guard refused."""
        label = str(handle.label)[:60]

        def task():
            self._restore(handle, resend=True)
            raise ValueError(f"{label}: {why}")

        self.post(task, self._edit_group.get(id(handle)) or "run")

    def err(self, group: str) -> None:
        """The (hidden until needed) error line of an edit group, placed where it is called."""
        self.gui[f"err_{group}"] = self.server.gui.add_html("", visible=False)
        self.errors[group] = ""

    def draft_changed(self, mold: bool = False) -> None:
        """A draft edit was accepted: show the unapplied edits (and the draft's mold)."""
        self.panels["run"].sync()
        if mold:
            self._mold_dirty = True

    def view_changed(self, mold: bool = False) -> None:
        if self.is_quiet():
            return
        self._view_dirty = True
        self._mold_dirty = self._mold_dirty or mold
        self._wake.set()

    def initial_residual(self) -> float:
        """||V||inf [N] of the current state when no run has reported one (cached per state)."""
        key = (id(self.sim.model), self.sim.state.iteration, self.sim.version)
        if self._r0_key != key:
            self._r0 = self.sim.current_residual()
            self._r0_key = key
        return self._r0

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> ResidualPlot:
        """Every panel's widgets, in page order; returns the residual plot."""
        gui = self.server.gui
        p = self.panels
        p["run"].build(gui)
        plot = ResidualPlot(gui, self.sim.settings.e, self.min_period)
        plot.atomic = self.server.atomic
        self.gui["plot"] = plot.handle
        p["levels"].build(gui)  # the pressure profile beside (under) the convergence plot
        p["view"].build_legend(gui)
        p["probes"].build_readout(gui)
        tabs = gui.add_tab_group()
        for key, title in (("view", "View"), ("stages", "Stages"), ("solver", "Solver"),
                           ("constraints", "Constraints"), ("material", "Material"), ("fabric", "Fabric & mold"),
                           ("probes", "Probes"), ("files", "Files")):
            with tabs.add_tab(title):
                p[key].build(gui)
                if key == "fabric":  # the Garment section: panels, placements, pattern uploads
                    p["garment"].build(gui)
        return plot

    def sync_widgets(self) -> None:
        """Show the draft's values in every editor (not counted as edits)."""
        with self.quiet():
            for key in ("solver", "fabric", "material", "constraints", "garment", "run", "stages"):
                self.panels[key].sync()
        for group in ("warp_table", "weft_table"):  # the tables show the draft's again
            self._set_error(group, "")
        self.panels["material"].refresh()

    # ------------------------------------------------------------------ solver thread hook
    def on_progress(self, sim: Simulation) -> None:
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
        if sim.status != "running":  # the run ended: show the still state now, not after the
            self._wake.set()         # loop's running period (up to 1 s)

    # ------------------------------------------------------------------ update loop
    def _loop(self) -> None:
        while not self._stop.is_set():
            t0 = time.perf_counter()
            c0 = time.thread_time()  # CPU time: waiting for the GIL is not our work
            with self._lock:
                tasks, self._tasks = self._tasks, []
            for fn, group in tasks:
                self._run_task(fn, group)
            self._poll_upload()
            try:
                self._push()
            except Exception as exc:  # never let the display kill the loop
                if self.verbose:
                    print(f"viewer: display update failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            work = time.perf_counter() - t0
            cpu = time.thread_time() - c0
            self.loop_work_s += cpu
            with self._lock:
                if not self._tasks and not self.panels["fabric"].busy() and not self.panels["garment"].busy():
                    self._idle.set()
            # while the solver runs, keep the loop's own share of the time below `duty` (a smoothed
            # estimate, so that one slow frame, e.g. loading a kernel, does not stall the display)
            self._work_avg = cpu if self._work_avg is None else 0.8 * self._work_avg + 0.2 * cpu
            period = self.min_period
            if self.sim.status == "running":
                period = min(max(self.min_period, self._work_avg / self.duty), 1.0)
            self._wake.wait(timeout=max(0.002, period - work))
            self._wake.clear()

    def _poll_upload(self) -> None:
        """The mold upload being parsed off the loop: its progress, or its result once done."""
        fabric = self.panels["fabric"]
        job = fabric.job
        if job is None:
            return
        if job.done.is_set():
            self._run_task(fabric.poll_upload, "mold")
        else:
            try:
                fabric.poll_upload()
            except Exception:  # noqa: BLE001 - progress display only
                pass

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
        # never show the private upload folder: an uploaded scene's files by their names in it
        up = re.escape(str(self.upload_dir))
        msg = re.sub(up + r"/scene_\d+/", "", msg)
        msg = re.sub(up + r"/?", "(upload)/", msg)
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
            self._do_apply(reset=False, resume=False)
        self._begin_segment()
        self.sim.start()

    def _do_stage(self) -> None:
        if self.pending:
            self._do_apply(reset=False, resume=False)
        self._begin_segment()
        self.sim.run_stage()

    def _do_step(self) -> None:
        if self.pending:
            self._do_apply(reset=False, resume=False)
        self._begin_segment()
        self.sim.step()

    def _begin_segment(self) -> None:
        """A new run segment: its live points start afresh (earlier ones are in the history)."""
        with self._lock:
            self._live_it = []
            self._live_res = []

    def _do_reset(self) -> None:
        if self.pending:
            self._do_apply(reset=True, resume=False)
        else:
            self.sim.reset()
            self._after_model_change()

    def _do_apply(self, reset: bool, resume: bool | None = None) -> None:
        """Rebuild the model from the draft (warm start unless ``reset``); a relaxation that was
        running goes on from the new model (``resume``: None = if it was running)."""
        resume = self.sim.status == "running" if resume is None else resume
        scene = self.scene_draft.validate()
        with warnings.catch_warnings(record=True) as caught:  # the mold's units and reach
            warnings.simplefilter("always")
            self.sim.replace_scene(scene, warm_start=not reset)
        self.panels["fabric"].mold_warnings = [str(w.message) for w in caught if str(w.message).startswith("mold: ")]
        self.panels["fabric"].mold_preview = None
        self._after_model_change()
        self.panels["fabric"].refresh_mold_info()
        if resume:
            self._begin_segment()
            self.sim.start()

    def _after_model_change(self) -> None:
        with self._lock:
            self._live_it = []
            self._live_res = []
            self._frame = None
        self._hist_version = -1
        self._mold_dirty = True
        self.scene_draft.reset_to(self.sim.scene)
        self.panels["run"].sync()
        self.panels["probes"].reset()
        self.panels["stages"].reset()
        self.panels["levels"].reset()
        with self.quiet():  # the panel list and table of the applied model, its friction
            self.panels["fabric"].sync_panels()
            self.panels["garment"].sync()
            self.panels["stages"].sync()

    # ------------------------------------------------------------------ uploads
    def _upload_refused(self, client_id, message, filename: str, reason: str) -> None:
        """From viser's event loop: the upload guard refused a transfer (its parts are freed)."""
        msg = f"{filename[:60]}: {reason}"
        groups = {self.gui[k]._impl.uuid: g for k, g in (("mold_upload", "mold"), ("scene_upload", "files"),
                                                                  ("pattern_upload", "pattern"))
                  if k in self.gui}
        group = groups.get(getattr(message, "source_component_uuid", None), "material")
        self.post(lambda: (_ for _ in ()).throw(ValueError(msg)), group)
        client = self.server.get_clients().get(client_id)
        if client is not None:
            client.add_notification("Upload refused", msg, color="red", auto_close_seconds=10.0)

    def upload_callback(self, handle, fn: Callable[[str, bytes], None], group: str):
        """The on_upload callback of an upload button: size-check, then post fn(name, data)."""

        def cb(_event) -> None:
            f = handle.value
            name, data = f.name, f.content
            if len(data) > self.upload_limit:
                msg = f"{name[:60]}: over the upload limit of {self.upload_limit / 2**20:.0f} MB"
                self.post(lambda: (_ for _ in ()).throw(ValueError(msg)), group)
                return
            self.post(lambda: fn(name, data), group)

        return cb

    # ------------------------------------------------------------------ camera
    def _frame_new_client(self, client) -> None:
        """A new tab: its camera on the sheet as shown now."""
        f = self._last_frame
        model = self.sim.model
        # the shown frame, else the current state (the initial deformation: a wrapped sleeve is
        # not where its flat rest positions are)
        pos = f.positions if f is not None and f.model is model else self.sim.state.positions.copy()
        frame_camera(client, model, pos if len(pos) == model.node_count else None)

    def frame(self, client=None) -> None:
        """(update loop) Point the camera of ``client`` (None: every tab) at the sheet as shown."""
        f = self._last_frame
        model = f.model if f is not None else self.sim.model
        pos = f.positions if f is not None else None
        clients = [client] if client is not None else list(self.server.get_clients().values())
        for c in clients:
            frame_camera(c, model, pos)
        if client is None:
            self.framed_box = camera_box(model, pos)
            self.reframes += 1

    def _auto_frame(self, frame: Frame) -> None:
        """Re-frame every tab when the sheet grew well beyond what the cameras were pointed at
        (a stretch), or when the model changed (a new scene)."""
        box = (frame.positions.min(axis=0), frame.positions.max(axis=0))
        if self._framed_model is not frame.model:
            self._framed_model = frame.model
            self.frame()  # tabs that connected before this frame may have been framed on another state
            return
        if needs_reframe(self.framed_box, box):
            self.frame()

    # ------------------------------------------------------------------ display
    def _push(self) -> None:
        sim = self.sim
        model = sim.model
        view = self.panels["view"].settings()
        r = self.renderer
        if model is not r.model:
            r.rebuild(model, view, outlines=bool(sim.scene.panels))
            self._last_frame = None
            self._mold_dirty = True
        if self._mold_dirty:
            preview = self.panels["fabric"].mold_preview
            mold = preview if preview is not None else model.mold
            r.show_mold(None if mold == "none" else mold, preview is not None, model, view)
            self._mold_dirty = False
        with self._lock:
            frame, self._frame = self._frame, None
        if frame is not None and frame.model is not model:
            frame = None
        shown = (sim.status, sim.version)  # read before the frame: the display is at least this new
        running = shown[0] == "running"
        if not running:  # the state is still: show it exactly (once per change)
            key = (sim.version, sim.state.iteration, id(model))
            if key != self._still_key or self._last_frame is None:
                snap = sim.snapshot()
                if sim.model is model:
                    frame = Frame(snap.positions, snap.in_contact, snap.iteration, model)
                    self._still_key = key
        view_dirty = self._view_dirty
        if frame is None and self._view_dirty and self._last_frame is not None:
            frame = self._last_frame
        self._view_dirty = False
        # a finished stage's end state shown instead of the live one (the Stages tab)
        staged = self.panels["stages"].frame()
        if staged is not None:
            frame = staged if (staged is not self._last_frame or view_dirty) else None
        elif self._last_frame is not None and self._last_frame is self.panels["stages"].last_shown:
            frame = self._live_frame(sim, model)  # back to the live state
        self.panels["stages"].last_shown = staged
        if frame is not None:
            self.panels["view"].set_legend(r.push_frame(frame, view))
            self.panels["view"].set_colorbar(*r.range, r.field_key)
            self.panels["view"].show_range(*r.range)
            self.pushed_positions = frame.positions
            self.pushed_iteration = frame.iteration
            self.frames_pushed += 1
            self._last_frame = frame
            if staged is None:
                self._auto_frame(frame)
        self.panels["run"].update_status(running, self._last_frame)
        self.panels["probes"].update(self._last_frame, still=not running)
        self.panels["levels"].update(self._last_frame, still=not running)
        self._update_plot(running)
        if sim.model is model:
            self.shown = shown

    @staticmethod
    def _live_frame(sim, model) -> Frame | None:
        """The simulation's state now, as a frame of ``model`` (None if the model changed)."""
        snap = sim.snapshot()
        return Frame(snap.positions, snap.in_contact, snap.iteration, model) if sim.model is model else None

    def _update_plot(self, running: bool) -> None:
        if not self.plot.due(running):
            return
        sim = self.sim
        if sim.version != self._hist_version:
            snap = sim.snapshot()
            self._hist = (snap.history_iteration.astype(np.float64), snap.history_residual.astype(np.float64))
            self._hist_version = sim.version
        with self._lock:
            live = (np.asarray(self._live_it, np.float64), np.asarray(self._live_res, np.float64))
        self.plot.update(self._hist, live, float(sim.settings.e), self.initial_residual, running, sim.stage_marks)


def _other(handle, value):
    """A value of the widget's type different from ``value`` (to make viser send ``value`` again)."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value + 1
    if isinstance(value, tuple):
        return tuple(x + 1 for x in value)
    if isinstance(handle, viser.GuiDropdownHandle):
        return next((o for o in handle.options if o != value), value)
    return value + " "
