"""The Fabric & mold tab: sheet size and divisions, initial lift; the mold (the scene's, a bundled
file, a primitive or an upload) with a scale and an offset.

An uploaded mold is parsed once, in a worker thread (:class:`MoldUploadJob`), never on the update
loop: every tab keeps its updates while a large mesh is read and its search tree built. The panel
shows the parse's stage and progress and a **Cancel upload** button; the update loop polls the job
(:meth:`FabricPanel.poll_upload`) and, when it is done, stores the file and makes it the draft's
mold (the parsed mold is handed to the mold cache, so the stored file is not parsed again)."""

from __future__ import annotations

import html
import threading
import time
from pathlib import Path

import viser

from ...mold import load_mold, mold_cached, mold_scale_warning
from ..draft import ABS_LENGTH_MAX, DIVISIONS_MAX, MOLD_SCALE_MAX, MOLD_UPLOAD_MAX_TRIANGLES, SCENE_MOLD
from . import Panel


class UploadCancelled(Exception):
    """Raised inside a parse when its upload was cancelled."""


class MoldUploadJob:
    """One uploaded mold parsed in a worker thread. ``fraction`` (0..1) and ``stage`` tell how
    far it is; :meth:`cancel` makes the parse stop at its next progress report (between stages
    and every few thousand search-tree nodes: within about a second); when ``done`` is set,
    ``mold`` holds the result, or ``error`` the exception, or ``cancelled`` is true."""

    def __init__(self, name: str, data: bytes, scale, offset, parse, *, size: int | None = None,
                 spec: dict | None = None, restore: dict | None = None):
        self.name, self.data, self.scale, self.offset = name, data, scale, tuple(offset)
        self.size = len(data) if size is None else size  # [bytes]
        # a mold file being loaded for a mold edit (not an upload): its spec, and the edit's
        # widgets' last valid values (shown again if the load fails or is cancelled)
        self.spec = spec
        self.restore = restore or {}
        self.fraction = 0.0
        self.stage = "starting"
        self.t0 = time.perf_counter()
        self.mold = None
        self.error: Exception | None = None
        self.done = threading.Event()
        self._cancel = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(parse,), name="clothsim-mold-upload", daemon=True)

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def cancel(self) -> None:
        self._cancel.set()

    def _progress(self, fraction: float, stage: str) -> None:
        if self._cancel.is_set():
            raise UploadCancelled
        self.fraction = float(fraction)
        self.stage = stage

    def _run(self, parse) -> None:
        try:
            self.mold = parse(self.name, self.data, self.scale, self.offset, progress=self._progress)
            if self._cancel.is_set():
                self.mold = None
        except UploadCancelled:
            pass
        except Exception as exc:  # noqa: BLE001 - reported on the panel's error line
            self.error = exc
        finally:
            if self.mold is None:
                self.data = b""  # free the upload at once
            self.done.set()


class FabricPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self.mold_preview = None  # a validated Mold of the draft, shown until applied ("none": no mold)
        self.mold_warnings: list[str] = []  # "mold: ..." warnings (units, reach) of the last preview or apply
        self.job: MoldUploadJob | None = None  # the upload (or mold file) being parsed
        self._job_shown = 0.0

    def build(self, gui) -> None:
        app, g = self.app, self.gui
        big = ABS_LENGTH_MAX
        g["size"] = app.on(gui.add_vector2("Size [m] (warp, weft)", (0.1, 0.1), step=0.005, min=(1e-6, 1e-6),
                                           max=(big, big)),
                           self.set_size, "fabric")
        g["nx"] = app.on(gui.add_number("Warp divisions", 10, step=1, min=1, max=DIVISIONS_MAX),
                         lambda v: self.set_divisions(), "fabric")
        g["ny"] = app.on(gui.add_number("Weft divisions", 10, step=1, min=1, max=DIVISIONS_MAX),
                         lambda v: self.set_divisions(), "fabric")
        g["panels"] = gui.add_markdown("", visible=False)
        g["lift"] = app.on(gui.add_number("Initial lift [m]", 0.0, step=0.001, min=-big, max=big),
                           self.set_lift, "fabric")
        app.err("fabric")
        g["mold"] = app.on(gui.add_dropdown("Mold", ("none",)), lambda v: self.set_mold(), "mold")
        g["mold_scale"] = app.on(gui.add_number("Mold scale (mesh files)", 1.0, step=0.001, min=0.0,
                                                max=MOLD_SCALE_MAX),
                                 lambda v: self.set_mold(), "mold")
        g["mold_offset"] = app.on(gui.add_vector3("Mold offset [m]", (0.0, 0.0, 0.0), step=0.001,
                                                  min=(-big,) * 3, max=(big,) * 3),
                                  lambda v: self.set_mold(), "mold")
        g["mold_up"] = app.on(gui.add_dropdown("Mold up axis (mesh files)", ("z", "y"), initial_value="z",
                                               hint="y: a Y-up file (most scans) is turned to clothsim's Z-up"),
                              lambda v: self.set_mold(), "mold")
        g["mold_surface"] = app.on(gui.add_dropdown("Mold surface (mesh files)", ("auto", "faceted", "smooth"),
                                                    initial_value="auto",
                                                    hint="smooth: contact on a smooth surface blended from the "
                                                         "triangles (scans); faceted: on the triangles (CAD molds); "
                                                         "auto: smooth if over 10 % of the edges bend by 10-45 "
                                                         "degrees (a scan), else faceted"),
                                   lambda v: self.set_mold(), "mold")
        g["mold_smoothing"] = app.on(gui.add_number("Mold smoothing [m] (smooth; 0: default)", 0.0, step=0.0005,
                                                    min=0.0, max=big,
                                                    hint="the smooth surface's blending radius; 0: the mesh's "
                                                         "median edge length"),
                                     lambda v: self.set_mold(), "mold")
        up = gui.add_upload_button("Upload mold", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                   hint=f"STL, OBJ, PLY, OFF, GLB, the paper's .txt, .vtk, .wrl; at most "
                                        f"{MOLD_UPLOAD_MAX_TRIANGLES:,} triangles and "
                                        f"{app.upload_limit / 2**20:.0f} MB")
        up.on_upload(app.upload_callback(up, self.mold_uploaded, "mold"))
        g["mold_upload"] = up
        g["mold_progress_text"] = gui.add_html("", visible=False)
        g["mold_progress"] = gui.add_progress_bar(0.0, visible=False, animated=True)
        g["mold_cancel"] = gui.add_button("Cancel upload", icon=viser.Icon.X, color="red", visible=False)
        g["mold_cancel"].on_click(lambda _e: self.cancel_upload())
        g["mold_info"] = gui.add_markdown("")
        app.err("mold")

    def sync(self) -> None:
        g = self.gui
        data = self.app.scene_draft.data
        self.sync_panels()
        g["lift"].value = float(self.app.scene_draft.data.get("initial", {}).get("lift", 0.0))
        with self.app.quiet():
            g["mold_up"].value = (data.get("mold") or {}).get("up") or "z"
            g["mold_surface"].value = (data.get("mold") or {}).get("surface") or "auto"
            g["mold_smoothing"].value = float((data.get("mold") or {}).get("smoothing") or 0.0)
        self.refresh_mold_options()

    def sync_panels(self) -> None:
        """The sheet's size and divisions (a ``fabric:`` rectangle) or the panels table."""
        g = self.gui
        fab = self.app.scene_draft.data["fabric"]
        rect = "size" in fab and "divisions" in fab
        for k in ("size", "nx", "ny"):
            g[k].visible = rect
        g["panels"].visible = not rect
        if rect:
            g["size"].value = tuple(float(x) for x in fab["size"])
            g["nx"].value = int(fab["divisions"][0])
            g["ny"].value = int(fab["divisions"][1])
        else:
            g["panels"].content = self.panels_table()
        self.app._mark_valid("fabric")

    def panels_table(self) -> str:
        """A markdown table of the scene's pattern panels (name, nodes, outline area, lattice)."""
        model = self.app.sim.model
        topo = model.topology
        rows = ["| panel | nodes | area [cm²] | lattice |", "|---|---|---|---|"]
        for p, name in enumerate(topo.names):
            sel = topo.node_panel == p
            nx1, ny1 = topo.panel_shape(p)
            rows.append(f"| {name} | {int(sel.sum())} | {model.node_area[sel].sum() * 1e4:.2f} | "
                        f"{nx1 - 1} x {ny1 - 1} |")
        return ("**Pattern panels** (placements and pattern uploads below; outlines and lattices in the "
                "scene file)\n\n" + "\n".join(rows))

    # fabric ------------------------------------------------------------------
    def set_size(self, v) -> None:
        self.app.scene_draft.set_size(v[0], v[1])
        self.app.draft_changed()

    def set_divisions(self) -> None:
        self.app.scene_draft.set_divisions(self.gui["nx"].value, self.gui["ny"].value)
        self.app.draft_changed()

    def set_lift(self, v) -> None:
        self.app.scene_draft.set_lift(v)
        self.app.draft_changed()

    # mold --------------------------------------------------------------------
    def refresh_mold_options(self, select: str | None = None) -> None:
        opts = self.app.scene_draft.mold_options()
        with self.app.quiet():
            self.gui["mold"].options = tuple(opts)
            if select is None:
                select = SCENE_MOLD if SCENE_MOLD in opts else "none"
            self.gui["mold"].value = select
        self.refresh_mold_info()

    def refresh_mold_info(self) -> None:
        spec = self.app.scene_draft.data.get("mold")
        # inside a markdown code span nothing is interpreted (an HTML escape would show as
        # "&#x27;"): only a backtick could end the span early
        self.gui["mold_info"].content = (f"Current: `{str(spec).replace('`', chr(39))}`" if spec is not None
                                         else "Current: no mold") + "".join(
            f"\n\n**warning**: `{w.replace('`', chr(39))}`" for w in self.mold_warnings)

    def set_mold(self) -> None:
        """A mold edit (choice, scale, offset). A mesh file not yet in the mold cache (a bundled
        file chosen, an upload rescaled) is parsed in a worker thread like an upload, so the edit
        does not stall the loop; the draft changes when it is done."""
        app, g = self.app, self.gui
        draft = app.scene_draft
        spec = draft.mold_spec(g["mold"].value, g["mold_scale"].value, g["mold_offset"].value,
                               g["mold_up"].value, g["mold_surface"].value, g["mold_smoothing"].value)
        if spec is not None:
            base = draft.validate({**draft.data, "mold": spec}).base_dir  # field-level check first
            if not mold_cached(spec, base):
                if self.job is not None and not self.job.done.is_set():
                    self.job.cancel()
                restore = {k: app._valid[id(g[k])] for k in ("mold", "mold_scale", "mold_offset", "mold_up",
                                                                    "mold_surface", "mold_smoothing")
                           if id(g[k]) in app._valid}
                path = Path(spec["path"])
                try:
                    size = (path if path.is_absolute() or base is None else Path(base) / path).stat().st_size
                except OSError:
                    size = 0
                job = MoldUploadJob(path.name, b"", g["mold_scale"].value, g["mold_offset"].value,
                                    lambda *_a, progress: load_mold(spec, base, progress=progress),
                                    size=size, spec=spec, restore=restore)
                self.job = job
                self._job_shown = 0.0
                self._show_progress(job)
                job.thread.start()
                return
        self._mold_set(spec)

    def _mold_set(self, spec) -> None:
        mold = self.app.scene_draft.set_mold(spec)
        self.mold_preview = mold if mold is not None else "none"
        self.mold_warnings = []
        if mold is not None:  # units at once; the reach is checked when the edit is applied

            msg = mold_scale_warning(mold, self.app.sim.model.placement.size)
            self.mold_warnings = [f"mold: {msg}"] if msg else []
        self.app.draft_changed(mold=True)
        self.refresh_mold_info()

    def mold_uploaded(self, name: str, data: bytes) -> None:
        """An upload arrived (on the update loop): parse it in a worker thread (an upload still
        being parsed is cancelled); :meth:`poll_upload` takes it from there."""
        if self.job is not None and not self.job.done.is_set():
            self.job.cancel()
        g = self.gui
        job = MoldUploadJob(name, data, g["mold_scale"].value, g["mold_offset"].value,
                            self.app.scene_draft.parse_upload)
        self.job = job
        self._job_shown = 0.0
        self._show_progress(job)
        job.thread.start()

    def cancel_upload(self) -> None:
        """The Cancel button (any thread): the parse stops at its next progress report."""
        job = self.job
        if job is not None:
            job.cancel()
        self.app._wake.set()

    def busy(self) -> bool:
        """An upload or a mold file is being parsed, or its result not yet applied."""
        return self.job is not None

    def poll_upload(self) -> None:
        """On the update loop: show the parse's progress; when it is done, store the upload and
        make it the draft's mold, or show why not (raises: the error line of the mold group)."""
        job = self.job
        if job is None:
            return
        if not job.done.is_set():
            now = time.perf_counter()
            if now - self._job_shown >= 0.25:
                self._job_shown = now
                self._show_progress(job)
            return
        # the job stays this panel's until its result is applied (``busy`` is True until then)
        try:
            self._apply_job(job)
        finally:
            if self.job is job:  # (an upload's set_mold may have started the next job)
                self.job = None

    def _apply_job(self, job: MoldUploadJob) -> None:
        """A finished parse (on the update loop): the draft's new mold, or why not (raises)."""
        self._hide_progress()
        name = job.name[:60]
        if (job.cancelled or job.error is not None) and job.restore:
            app = self.app
            for k, v in job.restore.items():  # the edit did not happen: show the mold in use again
                app._valid[id(self.gui[k])] = v
                app._restore(self.gui[k])
        if job.cancelled:
            raise ValueError(f"{name}: {'loading' if job.spec is not None else 'upload'} cancelled; "
                             f"the mold is unchanged")
        if job.error is not None:
            raise job.error
        if job.spec is not None:  # a mold edit: the file is in the mold cache now
            self._mold_set(job.spec)
            self.app._mark_valid("mold")
            return
        label = self.app.scene_draft.store_upload(job.name, job.data, job.mold, job.scale, job.offset)
        job.data = b""
        self.refresh_mold_options(select=label)
        self.set_mold()
        self.app._mark_valid("mold")  # the mold widgets show the mold in use

    def _show_progress(self, job: MoldUploadJob) -> None:
        g = self.gui
        pct = 100.0 * min(max(job.fraction, 0.0), 1.0)
        what = "cancelling" if job.cancelled else job.stage
        g["mold_progress_text"].content = (
            f'<div style="font-size:0.85em">{"Loading" if job.spec is not None else "Parsing"} '
            f'<b>{html.escape(job.name[:60])}</b> '
            f'({job.size / 2**20:.1f} MB): {html.escape(what)}... {pct:.0f} % '
            f'({time.perf_counter() - job.t0:.0f} s)</div>')
        g["mold_progress"].value = pct
        for k in ("mold_progress_text", "mold_progress", "mold_cancel"):
            g[k].visible = True

    def _hide_progress(self) -> None:
        for k in ("mold_progress_text", "mold_progress", "mold_cancel"):
            self.gui[k].visible = False
