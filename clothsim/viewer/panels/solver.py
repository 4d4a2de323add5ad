"""The Solver tab: method, C, e and max iterations. These reach a running relaxation at once
(through :meth:`clothsim.simulation.Simulation.set_solver`, validated there); the method applies
from the next Start."""

from __future__ import annotations

from pydantic import ValidationError

from ...config import SOLVER_METHODS, SceneError, SolverSettings
from ..draft import C_MAX, MAX_ITERATIONS_MAX, as_float, as_int
from . import Panel


class SolverPanel(Panel):
    def build(self, gui) -> None:
        app, g = self.app, self.gui
        s = app.sim.settings
        g["method"] = app.on(gui.add_dropdown("Method", SOLVER_METHODS, initial_value=s.method),
                             lambda v: self.set(method=v), "solver")
        g["C"] = app.on(gui.add_number("C (step divisor)", float(s.C), step=0.1, min=0.0, max=C_MAX),
                        lambda v: self.set(C=as_float(v, "C", -C_MAX, C_MAX)), "solver")
        g["e"] = app.on(gui.add_text("e (limit on ||V||inf) [N]", f"{s.e:g}"),
                        lambda v: self.set(e=as_float(v, "e")), "solver")
        g["max_iterations"] = app.on(
            gui.add_number("Max iterations", int(s.max_iterations), step=1, min=0,
                           max=MAX_ITERATIONS_MAX),
            lambda v: self.set(max_iterations=as_int(v, "max iterations", 0, MAX_ITERATIONS_MAX)), "solver")
        gui.add_markdown("C, e and max iterations reach a running relaxation at once; the method "
                         "applies from the next Start.")
        app.err("solver")

    def sync(self) -> None:
        g = self.gui
        s = self.app.scene_draft.data.get("solver", {})
        default = {k: f.default for k, f in SolverSettings.model_fields.items()}  # the scene's defaults
        g["method"].value = s.get("method", default["method"])
        g["C"].value = float(s.get("C", default["C"]))
        g["e"].value = f"{float(s.get('e', default['e'])):g}"
        g["max_iterations"].value = int(s.get("max_iterations", default["max_iterations"]))

    def set(self, **kw) -> None:
        """Validate and send solver settings to the simulation; mirror them in the draft."""
        try:
            self.app.sim.set_solver(**kw)  # validates before recording the edit
        except ValidationError as exc:
            msgs = []
            for err in exc.errors():
                msg = err["msg"].removeprefix("Value error, ")
                msgs.append(f"{'.'.join(str(p) for p in err['loc'])}: {msg}")
            raise SceneError("; ".join(msgs)) from None
        self.app.scene_draft.record_solver(**kw)
