"""The Files tab: download the edited scene (YAML, or a zip with the files it references), the
results (npz, ply, csv) and the HTML report; open another scene: one of the bundled scenes
(``configs/``, picked from a list) or an upload (.yaml or .zip)."""

from __future__ import annotations

import html
import sys
import tempfile
import threading

import viser

from ...compression.report import build_report
from ..draft import SceneDraft, open_scene_upload
from ..scenes import bundled_scenes, open_bundled
from . import Panel

PICK = "(pick a scene)"
EXPORTS = (("npz", "Export result (.npz)"), ("ply", "Export sheet (.ply)"), ("csv", "Export history (.csv)"))


class FilesPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self.opened = 0  # scenes opened from uploads
        self.report_threads: list[threading.Thread] = []

    def build(self, gui) -> None:
        app, g = self.app, self.gui
        g["save_yaml"] = gui.add_button("Save scene (YAML)", icon=viser.Icon.DOWNLOAD)
        g["save_yaml"].on_click(lambda e: self.download(e, "yaml"))
        g["save_zip"] = gui.add_button("Save scene + files (.zip)", icon=viser.Icon.DOWNLOAD,
                                       hint="scene.yaml with the mold and tables it uses: reruns anywhere")
        g["save_zip"].on_click(lambda e: self.download(e, "zip"))
        for kind, label in EXPORTS:
            g[f"export_{kind}"] = gui.add_button(label, icon=viser.Icon.DOWNLOAD)
            g[f"export_{kind}"].on_click(lambda e, k=kind: self.download(e, k))
        g["export_html"] = gui.add_button("Report (.html)", icon=viser.Icon.DOWNLOAD,
                                          hint="the same self-contained report as 'app.py report'")
        g["export_html"].on_click(lambda e: self.download(e, "html"))
        scenes = tuple(bundled_scenes())
        g["bundled"] = gui.add_dropdown("Bundled scene", (PICK,) + scenes, initial_value=PICK,
                                        hint="the scenes in configs/ (sweeps excepted)")
        g["open_bundled"] = gui.add_button("Open bundled scene", icon=viser.Icon.FOLDER_OPEN,
                                           hint="replaces the current scene (checked first)")
        g["open_bundled"].on_click(lambda _e: app.post(lambda: self.open_bundled(g["bundled"].value), "files"))
        up = gui.add_upload_button("Open scene (.yaml / .zip)", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                   hint="replaces the current scene (checked first; an invalid one changes nothing)")
        up.on_upload(app.upload_callback(up, self.open_scene, "files"))
        g["scene_upload"] = up
        gui.add_markdown(f"Uploads larger than {app.upload_limit / 2**20:.0f} MB are refused.")
        app.err("files")

    def download(self, event, kind: str) -> None:
        """Send a file to the tab that asked (built by the update loop, which owns the draft)."""
        client = event.client
        if client is not None:
            self.app.post(lambda: self.send(client, kind), "files")

    def send(self, client, kind: str) -> None:
        app = self.app
        try:
            if kind == "yaml":
                name, data = f"{app.sim.scene.name}.yaml", app.scene_draft.scene_yaml().encode()
            elif kind == "zip":
                name, data = f"{app.sim.scene.name}.zip", app.scene_draft.scene_zip()
            elif kind == "html":
                self.send_report(client, app.sim.result())
                return
            else:
                result = app.sim.result()
                if kind == "npz":
                    name, data = "result.npz", result.npz_bytes()
                elif kind == "ply":
                    fld = "pressure" if app.renderer.field_key == "pressure" else "strain"
                    name, data = "sheet.ply", result.colored_mesh(fld).export(file_type="ply")
                else:
                    name, data = "history.csv", result.history_csv().encode()
            client.send_file_download(name, data, save_immediately=True)
        except Exception as exc:
            raise ValueError(f"{kind}: {type(exc).__name__}: {exc}") from None

    def send_report(self, client, result) -> None:
        """Build the HTML report of ``result`` (a snapshot taken by the update loop) on a thread of
        its own (it renders several figures: seconds, which the display loop must not wait for)
        and send it to the tab."""
        app = self.app

        def work():
            try:
                with tempfile.TemporaryDirectory(prefix="clothsim-report-") as td:
                    result.save(td)
                    text = build_report(td)
                client.send_file_download(f"{result.scene.name}-report.html", text.encode(), save_immediately=True)
            except Exception as exc:
                msg = f"report: {type(exc).__name__}: {exc}"
                if app.verbose:
                    print(f"viewer: {msg}", file=sys.stderr)
                app.post(lambda: (_ for _ in ()).throw(ValueError(msg)), "files")

        t = threading.Thread(target=work, name="clothsim-report", daemon=True)
        self.report_threads.append(t)
        t.start()

    def open_scene(self, name: str, data: bytes) -> None:
        """(update loop) Replace the simulation's scene by an uploaded one, validated first: an
        invalid scene raises and nothing changes."""
        app = self.app
        self.opened += 1
        self.replace(open_scene_upload(name, data, app.upload_dir / f"scene_{self.opened}", app.upload_limit))

    def open_bundled(self, label: str) -> None:
        """(update loop) Replace the simulation's scene by the bundled scene ``label`` (a key of
        :func:`bundled_scenes`), validated first."""
        scenes = bundled_scenes()
        if label not in scenes:
            raise ValueError("pick a bundled scene from the list first")
        self.replace(open_bundled(scenes[label]))

    def replace(self, scene) -> None:
        """(update loop) Make ``scene`` (validated, its files read) the simulation's scene."""
        app = self.app
        app.sim.replace_scene(scene, warm_start=False)
        count = app.scene_draft.upload_count
        app.scene_draft = SceneDraft(scene, upload_dir=app.upload_dir)
        app.scene_draft.upload_count = count  # later uploads never overwrite earlier ones
        app.panels["fabric"].mold_preview = None
        app._label = str(scene.source)
        app._after_model_change()
        app.sync_widgets()
        app._mark_valid()
        self.gui["title"].content = f"**clothsim** · {html.escape(scene.name)}"
        app.view_changed(mold=True)
