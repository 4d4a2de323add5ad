"""The View tab and the colour legend: which field colours the sheet, its range, opacities and
which helpers are shown. These are display settings, not edits: they only mark the view dirty."""

from __future__ import annotations

import numpy as np

from ..fields import FIELDS, FRICTION_COLOURS
from ..glb import colorbar_image, colorbar_with_ticks, nice_ticks, tick_x
from ..render import DEFAULT_SHEET_OPACITY, ViewSettings
from . import Panel


#: the colour bar's width [pixels]
BAR_WIDTH = 256


def friction_bar(width: int, height: int = 12) -> np.ndarray:
    """The stick/slip colour bar: one block per category, in their order (uint8 RGB)."""
    cols = np.asarray(FRICTION_COLOURS, np.uint8)
    idx = np.minimum((np.arange(width) * len(cols)) // width, len(cols) - 1)
    return np.repeat(cols[idx][None, :, :], height, axis=0)


class ViewPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self.legend = ""
        self.bar_key = None  # what the colour bar image shows: (ticks, their columns)

    def build_legend(self, gui) -> None:
        self.gui["legend_img"] = gui.add_image(colorbar_image(BAR_WIDTH, 12), format="png")
        self.gui["legend"] = gui.add_markdown("")

    def build(self, gui) -> None:
        g, app = self.gui, self.app
        g["field"] = gui.add_dropdown("Colour by", tuple(FIELDS), initial_value="warp strain")
        g["auto_range"] = gui.add_checkbox("Auto range", True)
        # with Auto range on they show the range the colour bar spans (issue 28, item 18)
        g["range_min"] = gui.add_number("Range min", 0.0, min=-1e12, max=1e12, step=1e-6,
                                        hint="the colour bar's low end (set by Auto range while it is on)")
        g["range_max"] = gui.add_number("Range max", 1.0, min=-1e12, max=1e12, step=1e-6,
                                        hint="the colour bar's high end (set by Auto range while it is on)")
        g["sheet_opacity"] = gui.add_slider("Sheet opacity", min=0.2, max=1.0, step=0.05,
                                            initial_value=DEFAULT_SHEET_OPACITY)
        for k in ("field", "auto_range", "range_min", "range_max", "sheet_opacity"):
            g[k].on_update(lambda _e: app.view_changed())
        g["show_fixed"] = gui.add_checkbox("Show constrained nodes", True)
        g["show_outlines"] = gui.add_checkbox("Show panel outlines", True,
                                              hint="pattern panels: each panel's outline as a magenta line")
        g["show_outlines"].on_update(lambda _e: app.view_changed())
        g["show_mold"] = gui.add_checkbox("Show mold", True)
        g["mold_opacity"] = gui.add_slider("Mold opacity", min=0.1, max=1.0, step=0.05, initial_value=0.6)
        for k in ("show_fixed", "show_mold", "mold_opacity"):
            g[k].on_update(lambda _e: app.view_changed(mold=True))
        g["frame"] = gui.add_button("Frame the sheet", hint="point the camera at the sheet as it is now "
                                                            "(also done when a stretch takes it off the view)")
        g["frame"].on_click(lambda e: app.post(lambda: app.frame(e.client)) if e.client is not None else None)

    def settings(self) -> ViewSettings:
        g = self.gui
        return ViewSettings(field=g["field"].value, auto_range=bool(g["auto_range"].value),
                            range_min=float(g["range_min"].value), range_max=float(g["range_max"].value),
                            sheet_opacity=float(g["sheet_opacity"].value), show_fixed=bool(g["show_fixed"].value),
                            show_mold=bool(g["show_mold"].value), mold_opacity=float(g["mold_opacity"].value),
                            show_outlines=bool(g["show_outlines"].value))

    def show_range(self, lo: float, hi: float) -> None:
        """(update loop) With Auto range on, Range min and max show the range the colour bar
        spans (4 significant digits; not counted as edits), so that turning Auto range off keeps
        the colours as they are."""
        g = self.gui
        if not g["auto_range"].value:
            return
        vals = tuple(float(f"{x:.4g}") for x in (lo, hi))
        if (g["range_min"].value, g["range_max"].value) != vals:
            with self.app.quiet():
                g["range_min"].value, g["range_max"].value = vals

    def set_legend(self, text: str) -> None:
        if text != self.legend:
            self.legend = text
            self.gui["legend"].content = text

    def set_colorbar(self, lo: float, hi: float, key: str) -> None:
        """The colour bar with tick marks and values for the range [lo, hi] of field ``key``
        (glb.colorbar_with_ticks; the bare bar for the in-contact field, whose legend names its two
        colours); the image is sent again only when its ticks change."""
        if key == "friction":  # categorical: one block per category
            if self.bar_key != "friction":
                self.bar_key = "friction"
                self.gui["legend_img"].image = friction_bar(BAR_WIDTH)
            return
        ticks = [] if key == "contact" else nice_ticks(lo, hi)
        cols = tuple(tick_x(ticks, lo, hi, BAR_WIDTH).tolist()) if ticks else ()
        bar_key = (tuple(ticks), cols)
        if bar_key == self.bar_key:
            return
        self.bar_key = bar_key
        img = colorbar_with_ticks(lo, hi, BAR_WIDTH)[0] if ticks else colorbar_with_ticks(0.0, 0.0, BAR_WIDTH)[0]
        self.gui["legend_img"].image = img
