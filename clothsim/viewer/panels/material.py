"""The Material tab: a preset, or warp and weft tables typed (or uploaded as CSV) in tension per
width [N/m] or stress [Pa] with a thickness; the curves as a plot."""

from __future__ import annotations

import html

import numpy as np
import viser

from ...presets import PRESETS
from ..draft import THICKNESS_MM_MAX, table_text
from . import Panel

CUSTOM = "(custom)"
UNITS = ("N/m (tension)", "Pa (stress)")


def _kind(unit_label: str) -> str:
    return "stress" if unit_label.startswith("Pa") else "tension"


class MaterialPanel(Panel):
    def build(self, gui) -> None:
        app, g = self.app, self.gui
        g["preset"] = app.on(gui.add_dropdown("Preset", (CUSTOM,) + tuple(PRESETS)), self.set_preset, "material")
        g["preset_info"] = gui.add_markdown("")
        g["thickness"] = app.on(gui.add_number("Thickness [mm] (for Pa)", 0.0, min=0.0, max=THICKNESS_MM_MAX,
                                               step=0.05),
                                lambda v: self.set_tables(), "material")
        for d in ("warp", "weft"):
            g[f"{d}_unit"] = app.on(gui.add_dropdown(f"{d.capitalize()} unit", UNITS),
                                    lambda v: self.set_tables(), "material")
            # an invalid table keeps what was typed and shows its error right under it (issue 28,
            # item 18: the text was thrown away and the error shown below the fold)
            g[f"{d}_text"] = app.on(gui.add_text(f"{d.capitalize()} table", "", multiline=True,
                                                 hint="one 'strain, value' pair per line"),
                                    lambda v: self.set_tables(), f"{d}_table", restore=False)
            app.err(f"{d}_table")
            up = gui.add_upload_button(f"Upload {d} CSV", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                       hint="header: strain,tension (N/m) or strain,stress (Pa)")
            up.on_upload(app.upload_callback(up, lambda name, data, d=d: self.csv_uploaded(d, name, data),
                                             "material"))
            g[f"{d}_csv"] = up
        app.err("material")
        g["curves"] = gui.add_uplot(
            data=(np.array([0.0, 1.0]), np.array([0.0, 1.0]), np.array([0.0, 1.0])),
            series=({"label": "strain"}, {"label": "warp [N/m]", "stroke": "#1c7ed6", "width": 1.5},
                    {"label": "weft [N/m]", "stroke": "#f08c00", "width": 1.5}),
            title="Tension per width [N/m] vs strain", aspect=1.8)

    def sync(self) -> None:
        g, draft = self.gui, self.app.scene_draft
        fab = draft.data["fabric"]
        g["thickness"].value = float(fab.get("thickness") or 0.0) * 1000.0
        g["preset"].value = draft.preset() or CUSTOM
        for k in ("warp", "weft"):
            strain, value, unit = draft.material_values(k)
            g[f"{k}_unit"].value = UNITS[1] if unit == "stress" else UNITS[0]
            g[f"{k}_text"].value = table_text(strain, value)

    def refresh(self) -> None:
        """The preset's description and the curves of the draft's tables."""
        name = self.gui["preset"].value
        self.gui["preset_info"].content = (f"*{html.escape(PRESETS[name].description)}* "
                                           f"(see clothsim/presets.py for sources)" if name in PRESETS else "")
        try:
            warp, weft = self.app.scene_draft.validate().tables()
        except Exception:
            return
        smax = max(float(warp.strain[-1]), float(weft.strain[-1]))
        x = np.unique(np.concatenate([warp.strain, weft.strain, [smax]]))
        self.gui["curves"].data = (x, warp.evaluate(x), weft.evaluate(x))

    def set_tables(self) -> None:
        g = self.gui
        self.app.scene_draft.set_tables((g["warp_text"].value, _kind(g["warp_unit"].value)),
                                  (g["weft_text"].value, _kind(g["weft_unit"].value)), g["thickness"].value)
        for group in ("warp_table", "weft_table", "material"):  # both tables are valid now
            self.app._set_error(group, "")
        self.app.draft_changed()
        with self.app.quiet():
            g["preset"].value = CUSTOM
        self.refresh()

    def set_preset(self, name: str) -> None:
        if name == CUSTOM:
            return
        self.app.scene_draft.set_preset(name)
        self.app.draft_changed()
        with self.app.quiet():
            p = PRESETS[name]
            for k in ("warp", "weft"):
                self.gui[f"{k}_unit"].value = UNITS[0]
                self.gui[f"{k}_text"].value = table_text(p.strain, getattr(p, k))
        self.refresh()

    def csv_uploaded(self, key: str, name: str, data: bytes) -> None:
        text, kind = self.app.scene_draft.csv_table(name, data)
        with self.app.quiet():
            self.gui[f"{key}_unit"].value = UNITS[1] if kind == "stress" else UNITS[0]
            self.gui[f"{key}_text"].value = text
        self.set_tables()
