"""The Fabric & mold tab: sheet size and divisions, initial lift; the mold (the scene's, a bundled
file, a primitive or an upload) with a scale and an offset."""

from __future__ import annotations

import viser

from ..draft import ABS_LENGTH_MAX, DIVISIONS_MAX, MOLD_SCALE_MAX, SCENE_MOLD
from . import Panel


class FabricPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self.mold_preview = None  # a validated Mold of the draft, shown until applied ("none": no mold)
        self.mold_warnings: list[str] = []  # "mold: ..." warnings (units, reach) of the last preview or apply

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
        up = gui.add_upload_button("Upload mold", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                   hint="STL, OBJ, PLY, OFF, GLB, the paper's .txt, .vtk, .wrl")
        up.on_upload(app.upload_callback(up, self.mold_uploaded, "mold"))
        g["mold_upload"] = up
        g["mold_info"] = gui.add_markdown("")
        app.err("mold")

    def sync(self) -> None:
        g = self.gui
        data = self.app.scene_draft.data
        fab = data["fabric"]
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
        g["lift"].value = float(self.app.scene_draft.data.get("initial", {}).get("lift", 0.0))
        with self.app.quiet():
            g["mold_up"].value = (data.get("mold") or {}).get("up") or "z"
        self.refresh_mold_options()

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
        return "**Pattern panels** (edit them in the scene file)\n\n" + "\n".join(rows)

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
        g = self.gui
        spec = self.app.scene_draft.mold_spec(g["mold"].value, g["mold_scale"].value, g["mold_offset"].value,
                                              g["mold_up"].value)
        mold = self.app.scene_draft.set_mold(spec)
        self.mold_preview = mold if mold is not None else "none"
        self.mold_warnings = []
        if mold is not None:  # units at once; the reach is checked when the edit is applied
            from ...mold import mold_scale_warning

            msg = mold_scale_warning(mold, self.app.sim.model.placement.size)
            self.mold_warnings = [f"mold: {msg}"] if msg else []
        self.app.draft_changed(mold=True)
        self.refresh_mold_info()

    def mold_uploaded(self, name: str, data: bytes) -> None:
        g = self.gui
        label = self.app.scene_draft.add_upload(name, data, g["mold_scale"].value, g["mold_offset"].value)
        self.refresh_mold_options(select=label)
        self.set_mold()
