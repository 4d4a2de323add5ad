"""The Files tab: download the edited scene (YAML) and the results (npz, ply, csv)."""

from __future__ import annotations

import viser

from . import Panel

EXPORTS = (("npz", "Export result (.npz)"), ("ply", "Export sheet (.ply)"), ("csv", "Export history (.csv)"))


class FilesPanel(Panel):
    def build(self, gui) -> None:
        app, g = self.app, self.gui
        g["save_yaml"] = gui.add_button("Save scene (YAML)", icon=viser.Icon.DOWNLOAD)
        g["save_yaml"].on_click(lambda e: self.download(e, "yaml"))
        for kind, label in EXPORTS:
            g[f"export_{kind}"] = gui.add_button(label, icon=viser.Icon.DOWNLOAD)
            g[f"export_{kind}"].on_click(lambda e, k=kind: self.download(e, k))
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
