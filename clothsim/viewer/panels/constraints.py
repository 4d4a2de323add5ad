"""The Constraints tab: the list of constraints, and an editor for one of them (a named node set,
the axes held, a stretch and a displacement)."""

from __future__ import annotations

import html

from ...config import NODE_SETS
from ..draft import AXES_CHOICES, RANGE_NODES, ConstraintEdit, describe_constraint
from . import Panel

NEW_CONSTRAINT = "+ new constraint"


class ConstraintsPanel(Panel):
    def build(self, gui) -> None:
        app, g = self.app, self.gui
        g["c_list"] = gui.add_markdown("")
        g["c_select"] = gui.add_dropdown("Constraint", (NEW_CONSTRAINT,))
        g["c_select"].on_update(lambda _e: None if app.is_quiet() else app.post(self.load_fields, "constraints"))
        g["c_nodes"] = gui.add_dropdown("Nodes", NODE_SETS + (RANGE_NODES,), initial_value="perimeter")
        g["c_axes"] = gui.add_dropdown("Axes", AXES_CHOICES, initial_value="xyz")
        g["c_stretch"] = gui.add_vector2("Stretch (sx, sy)", (1.0, 1.0), step=0.01, min=(0.0, 0.0),
                                         max=(100.0, 100.0))
        g["c_disp"] = gui.add_vector3("Displacement [m]", (0.0, 0.0, 0.0), step=0.001, min=(-1e3,) * 3,
                                      max=(1e3,) * 3)
        g["c_save"] = gui.add_button("Save constraint")
        g["c_save"].on_click(lambda _e: app.post(self.save, "constraints"))
        g["c_delete"] = gui.add_button("Delete constraint", color="red")
        g["c_delete"].on_click(lambda _e: app.post(self.delete, "constraints"))
        app.err("constraints")

    def sync(self, select: int | None = None) -> None:
        cons = self.app.scene_draft.constraints()
        g = self.gui
        if cons:
            g["c_list"].content = "\n".join(f"{n + 1}. {html.escape(describe_constraint(c))}"
                                            for n, c in enumerate(cons))
        else:
            g["c_list"].content = "*No constraints: the sheet is held by nothing but the mold.*"
        opts = tuple(f"{n + 1}: {describe_constraint(c)}" for n, c in enumerate(cons)) + (NEW_CONSTRAINT,)
        with self.app.quiet():
            g["c_select"].options = opts
            g["c_select"].value = opts[select] if select is not None and select < len(opts) else opts[0]
        self.load_fields()

    def selected(self) -> int | None:
        v = self.gui["c_select"].value
        if v == NEW_CONSTRAINT:
            return None
        return int(v.split(":", 1)[0]) - 1

    def load_fields(self) -> None:
        """Show the selected constraint in the editor."""
        k = self.selected()
        g = self.gui
        cons = self.app.scene_draft.constraints()
        c = cons[k] if k is not None and k < len(cons) else {"nodes": "perimeter", "axes": "xyz"}
        with self.app.quiet():
            g["c_nodes"].value = c["nodes"] if isinstance(c["nodes"], str) else RANGE_NODES
            g["c_axes"].value = c.get("axes", "xyz") if c.get("axes", "xyz") in AXES_CHOICES else "xyz"
            st = c.get("stretch")
            g["c_stretch"].value = (1.0, 1.0) if st is None else (
                (float(st), float(st)) if isinstance(st, (int, float)) else (float(st[0]), float(st[1])))
            g["c_disp"].value = tuple(float(x) for x in (c.get("displacement") or (0.0, 0.0, 0.0)))

    def save(self) -> None:
        """Save the editor's constraint (a new one, or over the selected one)."""
        g = self.gui
        edit = ConstraintEdit(nodes=g["c_nodes"].value, axes=g["c_axes"].value,
                              stretch=tuple(g["c_stretch"].value), displacement=tuple(g["c_disp"].value))
        k = self.app.scene_draft.save_constraint(self.selected(), edit)
        self.app.draft_changed()
        self.sync(select=k)

    def delete(self) -> None:
        k = self.selected()
        self.app.scene_draft.delete_constraint(k)
        self.app.draft_changed()
        self.sync(select=max(0, (k or 0) - 1))
