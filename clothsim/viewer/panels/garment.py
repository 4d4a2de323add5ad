"""The Garment section of the Fabric & mold tab: the scene's pattern panels, the placement of the
selected one (a rigid translate [m] and rotate [deg], or, for a panel rolled round an axis, the
wrap's radius [m] and axis) and a DXF/SVG pattern upload whose pieces can be added as panels or
replace the scene's panels. Every edit is a typed operation of
:class:`~clothsim.viewer.draft.SceneDraft`, validated with the whole scene and applied with
*Apply*; a refused one shows on the section's red line and its widget shows the last valid value
again. A pattern file is small (at most ``PATTERN_UPLOAD_MAX_BYTES``) and is read in a worker
thread (:class:`PatternJob`), never on the update loop: a hostile file (a curve a light-year long,
nested ``<use>``) is refused by the reader's bounds (clothsim.patternlimits) within seconds while
every tab keeps its updates."""

from __future__ import annotations

import html
import threading
import time

import numpy as np
import viser

from ..draft import ABS_LENGTH_MAX, PATTERN_UPLOAD_MAX_BYTES, PATTERN_UPLOAD_MAX_PIECES, ROTATE_MAX
from . import Panel

NO_PANEL = "(no pattern panels)"
NO_PATTERN = "(upload a pattern)"


class PatternJob:
    """One uploaded pattern read in a worker thread; when it is done it posts ``finish(job)`` to
    the update loop (``pieces`` holds the result, or ``error`` the exception) and sets ``done``."""

    def __init__(self, slot, data: bytes, parse, post):
        self.slot, self.pieces, self.error = slot, None, None
        self.t0 = time.perf_counter()
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(data, parse, post), name="clothsim-pattern-upload",
                                       daemon=True)

    def _run(self, data: bytes, parse, post) -> None:
        try:
            self.pieces = parse(self.slot, data)
        except Exception as exc:  # noqa: BLE001 - reported on the pattern group's error line
            self.error = exc
        finally:
            post(self)
            self.done.set()


class GarmentPanel(Panel):
    def build(self, gui) -> None:
        app, g = self.app, self.gui
        big = ABS_LENGTH_MAX
        g["garment_head"] = gui.add_markdown("**Garment panels**")
        g["panel_pick"] = gui.add_dropdown("Panel", (NO_PANEL,), hint="the panel whose placement is edited below")
        g["panel_pick"].on_update(lambda _e: None if app.is_quiet() else app.post(self.show_placement, "panels"))
        g["pl_kind"] = gui.add_markdown("")
        g["pl_translate"] = app.on(gui.add_vector3("Panel translate [m]", (0.0, 0.0, 0.0), step=0.001,
                                                   min=(-big,) * 3, max=(big,) * 3),
                                   lambda v: self.set_transform(), "panels")
        g["pl_rotate"] = app.on(gui.add_vector3("Panel rotate [deg] (x, y, z)", (0.0, 0.0, 0.0), step=1.0,
                                                min=(-ROTATE_MAX,) * 3, max=(ROTATE_MAX,) * 3),
                                lambda v: self.set_transform(), "panels")
        g["pl_radius"] = app.on(gui.add_number("Wrap radius [m]", 0.05, step=0.001, min=0.0, max=big),
                                lambda v: self.set_wrap(), "panels")
        g["pl_axis"] = app.on(gui.add_vector3("Wrap axis", (0.0, 0.0, 1.0), step=0.1, min=(-big,) * 3,
                                              max=(big,) * 3),
                              lambda v: self.set_wrap(), "panels")
        g["reduction"] = app.on(gui.add_number("Reduction [%] (garment, at its levels)", 0.0, step=0.1, min=-50.0,
                                               max=90.0, hint="garment.reduction: the relaxed circumference at "
                                                              "each measuring level = girth x (1 - r/100)"),
                                lambda v: self.set_reduction(), "panels")
        app.err("panels")
        up = gui.add_upload_button("Upload pattern (DXF/SVG)", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                   hint=f"a DXF (DXF-AAMA or plain) or SVG pattern; at most "
                                        f"{PATTERN_UPLOAD_MAX_BYTES / 2**20:.0f} MB and "
                                        f"{PATTERN_UPLOAD_MAX_PIECES} pieces")
        up.on_upload(app.upload_callback(up, self.pattern_uploaded, "pattern"))
        g["pattern_upload"] = up
        g["pattern_info"] = gui.add_markdown("")
        g["pattern_piece"] = gui.add_dropdown("Pattern piece", (NO_PATTERN,))
        g["pattern_add"] = gui.add_button("Add piece as panel", icon=viser.Icon.PLUS,
                                          hint="a new panel of this piece, placed beside the sheet")
        g["pattern_add"].on_click(lambda _e: app.post(self.add_piece, "pattern"))
        g["pattern_replace"] = gui.add_button("Replace panels with the file's pieces", icon=viser.Icon.REPLACE,
                                              hint="every piece of the file becomes a panel; the old panels' "
                                                   "seams go")
        g["pattern_replace"].on_click(lambda _e: app.post(self.replace_panels, "pattern"))
        app.err("pattern")
        self.pattern_label: str | None = None
        self.job: PatternJob | None = None  # the upload being read

    def busy(self) -> bool:
        """A pattern upload is being read, or its result not yet shown."""
        return self.job is not None

    # ------------------------------------------------------------------ display
    def sync(self) -> None:
        """The panel list and the selected panel's placement (inside ``app.quiet()``)."""
        g = self.gui
        names = self.app.scene_draft.panel_names()
        opts = tuple(names) if names else (NO_PANEL,)
        keep = g["panel_pick"].value if g["panel_pick"].value in opts else opts[0]
        g["panel_pick"].options = opts
        g["panel_pick"].value = keep
        draft = self.app.scene_draft
        g["reduction"].visible = draft.has_levels()  # a scene with measuring levels (garment.levels)
        r = draft.reduction()
        if r is not None:
            g["reduction"].value = r
        self.show_placement()

    def selected(self) -> int | None:
        names = self.app.scene_draft.panel_names()
        v = self.gui["panel_pick"].value
        return names.index(v) if v in names else None

    def show_placement(self) -> None:
        """Show the selected panel's placement in its widgets (not an edit)."""
        g, app = self.gui, self.app
        i = self.selected()
        kind, prm = app.scene_draft.placement(i) if i is not None else (None, {})
        with app.quiet():
            for k in ("pl_translate", "pl_rotate"):
                g[k].visible = kind == "transform"
            for k in ("pl_radius", "pl_axis"):
                g[k].visible = kind == "wrap"
            if kind == "transform":
                g["pl_translate"].value = tuple(float(x) for x in prm.get("translate", (0.0, 0.0, 0.0)))
                g["pl_rotate"].value = tuple(float(x) for x in prm.get("rotate", (0.0, 0.0, 0.0)))
            elif kind == "wrap":
                g["pl_radius"].value = float(prm["radius"])
                g["pl_axis"].value = tuple(float(x) for x in prm.get("axis", (0.0, 0.0, 1.0)))
        g["pl_kind"].content = ("" if kind is None else
                                f"Placement: **{kind}**" + (" (edited in the scene file)" if kind == "wrap_hull" else ""))
        app._mark_valid("panels")

    # ------------------------------------------------------------------ edits
    def set_transform(self) -> None:
        g = self.gui
        self.app.scene_draft.set_transform(self.selected(), g["pl_translate"].value, g["pl_rotate"].value)
        self.app.draft_changed()

    def set_reduction(self) -> None:
        self.app.scene_draft.set_reduction(self.gui["reduction"].value)
        self.app.draft_changed()

    def set_wrap(self) -> None:
        g = self.gui
        self.app.scene_draft.set_wrap(self.selected(), g["pl_radius"].value, g["pl_axis"].value)
        self.app.draft_changed()

    def pattern_uploaded(self, name: str, data: bytes) -> None:
        """(update loop) Start reading the uploaded pattern in a worker thread; :meth:`pattern_read`
        lists its pieces once it is read. One upload is read at a time."""
        if self.job is not None:
            raise ValueError(f"{str(name)[:60]}: another pattern is still being read; upload "
                             f"again when it is listed")
        draft = self.app.scene_draft
        slot = draft.pattern_slot(name, data)
        self.job = PatternJob(slot, data, draft.parse_pattern,
                              lambda job: self.app.post(lambda: self.pattern_read(job), "pattern"))
        self.gui["pattern_info"].content = f"Reading **{html.escape(slot[0])}**..."
        self.job.thread.start()

    def pattern_read(self, job: PatternJob) -> None:
        """(update loop) A finished read: list the pieces, or raise why not (the red line)."""
        if self.job is job:
            self.job = None
        if job.error is not None:
            self.gui["pattern_info"].content = ""
            raise job.error
        draft = self.app.scene_draft
        label = draft.store_pattern(job.slot, job.pieces)
        self.pattern_label = label
        pieces = draft.patterns[label][1]
        rows = ["| piece | area [cm²] | size [cm] |", "|---|---|---|"]
        for pc in pieces:
            ext = np.ptp(pc.outline, axis=0) * 100
            rows.append(f"| {html.escape(pc.name[:40])} | {pc.area * 1e4:.2f} | {ext[0]:.1f} x {ext[1]:.1f} |")
        self.gui["pattern_info"].content = (f"**{html.escape(label)}**: {len(pieces)} piece(s)\n\n" + "\n".join(rows))
        with self.app.quiet():
            self.gui["pattern_piece"].options = tuple(pc.name for pc in pieces)
            self.gui["pattern_piece"].value = pieces[0].name

    def _shown(self) -> np.ndarray:
        """(N, 3) [m] the sheet as shown (else its current state)."""
        f = self.app._last_frame
        return f.positions if f is not None else self.app.sim.snapshot().positions

    def _beside(self) -> tuple[float, float, float]:
        """[m] where a new panel goes: 2 cm beyond the sheet's +x side, at its lowest y and z."""
        p = self._shown()
        lo, hi = p.min(axis=0), p.max(axis=0)
        return float(hi[0] + 0.02), float(lo[1]), float(lo[2])

    def _need_pattern(self) -> str:
        if self.pattern_label is None:
            raise ValueError("upload a DXF or SVG pattern first")
        return self.pattern_label

    def add_piece(self) -> None:
        label = self._need_pattern()
        self.app.scene_draft.add_pattern_piece(label, self.gui["pattern_piece"].value, self._beside())
        self.after_panels_changed()

    def replace_panels(self) -> None:
        label = self._need_pattern()
        p = self._shown()
        self.app.scene_draft.replace_panels(label, None, tuple(float(x) for x in p.min(axis=0)))
        self.after_panels_changed()

    def after_panels_changed(self) -> None:
        app = self.app
        names = app.scene_draft.panel_names()
        with app.quiet():
            self.gui["panel_pick"].options = tuple(names)
            self.gui["panel_pick"].value = names[-1]
            self.show_placement()
            app.panels["fabric"].sync_panels()  # a rectangle replaced: its size widgets go
            app.panels["constraints"].sync()  # constraints naming an old panel may have gone
        app.draft_changed()
