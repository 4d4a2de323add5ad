"""The Stages tab: the friction coefficient mu of the mold (an edit, applied with Apply like the
other model edits), the scene's loading path (``stages:``) listed with each finished stage's
report, a run that pauses at the end of the current stage, and the finished stages' end states
shown one by one or replayed.

A staged run keeps the state at its start and at each stage's end
(:attr:`clothsim.simulation.Simulation.stage_ends`); showing one of them is a display setting,
like the View tab's: the simulation goes on (or stays) where it is, and **Live** shows it again.
The buttons only record a request; the update loop carries it out (:meth:`StagesPanel.frame`).
"""

from __future__ import annotations

import html
import threading
import time

import numpy as np

from ..draft import FRICTION_MAX
from ..render import Frame, fmt
from . import Panel

LIVE = "live"
#: how long a replay shows each stage's end state [s]
REPLAY_STEP_S = 1.5


def stage_label(k: int, name: str) -> str:
    """The Show dropdown's label of stage end ``k`` (0: the start)."""
    return "start" if k == 0 else f"{k}: end of {name or 'load steps'}"


def stages_markdown(rows: list[dict]) -> str:
    """The stages as a markdown table: stage, load steps, what it changes, its state and, once
    done, its result: Newton iterations, residual [N], stick / slip nodes and cone violation."""
    if not rows:
        return "This scene has no stages and no friction: it is solved in one go."
    out = ["| # | stage | steps | changes | state | result |", "|---|---|---|---|---|---|"]
    for n, r in enumerate(rows, 1):
        rep = r.get("report") or {}
        fr = rep.get("friction") or {}
        res = ""
        if rep:
            res = f"{rep['iterations']} it, {fmt(rep['residual'], 2)} N"
            if "stick" in fr:
                res += f"; stick / slip {fr['stick']} / {fr['slip']}, cone {fmt(fr['cone_violation'], 2)}"
        changes = html.escape(r["changes"] or "-")
        cells = [str(n), html.escape(r["name"]), str(r["steps"]), changes,
                 f"**{r['state']}**" if r["state"] == "current" else r["state"], res]
        out.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(out)


class StagesPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self._lock = threading.Lock()
        self._request: str | None = None  # a button's request, for the update loop
        self.shown: int | None = None  # the stage end shown (index into stage_ends), None: live
        self.replay_t0: float | None = None  # when the replay being played began
        self._ends = None  # the stage_ends list the dropdown was built from
        self._table_key = None
        self._cached = None  # (StageEnd, its Frame)
        self.last_shown: Frame | None = None  # the stage frame the 3D view showed last (the loop's)

    def build(self, gui) -> None:
        app, g = self.app, self.gui
        g["mu"] = app.on(gui.add_number("Friction mu (mold)", 0.0, step=0.01, min=0.0, max=FRICTION_MAX,
                                        hint="Coulomb's coefficient between the fabric and the mold (one "
                                             "value for sticking and sliding; 0: frictionless), outside "
                                             "the scene's friction regions (mold.friction_regions, given "
                                             "in its file). Applied with Apply edits; a stage that sets "
                                             "mold.friction overrides it from that stage on"),
                         self.set_mu, "friction")
        app.err("friction")
        g["stages_table"] = gui.add_markdown("")
        g["stage_run"] = gui.add_button("Run to the end of this stage",
                                        hint="run until the current stage is solved, then pause (Start goes on)")
        g["stage_run"].on_click(lambda _e: app.run_stage())
        g["stage_show"] = gui.add_dropdown("Show", (LIVE,), initial_value=LIVE,
                                           hint="the state at the start or at a finished stage's end (display "
                                                "only: the run stays where it is)")
        g["stage_show"].on_update(lambda _e: None if app.is_quiet() else self._ask("show"))
        g["stage_nav"] = gui.add_button_group("Stages", ("Previous", "Next", "Replay", "Live"))
        g["stage_nav"].on_click(lambda e: self._ask(str(e.target.value)))
        g["stage_note"] = gui.add_markdown("")

    def sync(self) -> None:
        self.gui["mu"].value = self.app.scene_draft.friction()

    def set_mu(self, v) -> None:
        self.app.scene_draft.set_friction(v)
        self.app.draft_changed()

    # ------------------------------------------------------------------ requests (any thread)
    def _ask(self, what: str) -> None:
        """A button or the dropdown: record the request and wake the update loop."""
        with self._lock:
            self._request = what
        self.app.view_changed()

    # ------------------------------------------------------------------ update loop
    def reset(self) -> None:
        """(update loop) A new model: back to the live state."""
        self.shown = None
        self.replay_t0 = None

    def frame(self) -> Frame | None:
        """(update loop) The frame to show instead of the live one (a stage end), or None: carry
        out the recorded request, advance a replay, refresh the list and the dropdown."""
        sim = self.app.sim
        ends = sim.stage_ends
        if self._ends and ends is not self._ends and (not ends or ends[0] is not self._ends[0]):
            self.reset()  # another run (Apply, Reset): its own stage ends
        self._refresh(sim, ends)
        with self._lock:
            req, self._request = self._request, None
        n = len(ends)
        if req == "show":
            v = self.gui["stage_show"].value
            labels = [stage_label(k, e.name) for k, e in enumerate(ends)]
            self.shown = labels.index(v) if v in labels else None
            self.replay_t0 = None
        elif req == "Live":
            self.shown, self.replay_t0 = None, None
        elif req in ("Previous", "Next") and n:
            cur = self.shown if self.shown is not None else n
            self.shown = int(np.clip(cur + (1 if req == "Next" else -1), 0, n - 1))
            self.replay_t0 = None
        elif req == "Replay" and n:
            self.replay_t0 = time.perf_counter()
            self.shown = 0
        if self.replay_t0 is not None:
            k = int((time.perf_counter() - self.replay_t0) / REPLAY_STEP_S)
            if k >= n:
                self.replay_t0 = None  # the replay ends on the last stage's end, and stays there
            self.shown = min(k, n - 1)
        if self.shown is not None and self.shown >= n:
            self.shown = None
        self._show_choice(ends)
        if self.shown is None:
            return None
        e = ends[self.shown]
        if self._cached is None or self._cached[0] is not e:  # one Frame per stage end: shown once
            self._cached = (e, Frame(e.positions, e.in_contact, e.iteration, e.model))
        return self._cached[1]

    @property
    def replaying(self) -> bool:
        return self.replay_t0 is not None

    def _show_choice(self, ends) -> None:
        """The dropdown and the note say what the 3D view shows."""
        label = LIVE if self.shown is None else stage_label(self.shown, ends[self.shown].name)
        if self.gui["stage_show"].value != label:
            with self.app.quiet():
                self.gui["stage_show"].value = label
        if self.shown is None:
            note = "Showing the live state." if ends else ""
        else:
            e = ends[self.shown]
            what = "the start" if self.shown == 0 else f"the end of stage {self.shown} ({html.escape(e.name)})"
            note = (f"Showing **{what}**: iteration {e.iteration}"
                    + (f" · replay {self.shown + 1} of {len(ends)}" if self.replaying else "")
                    + " · *Live* shows the run again.")
        if self.gui["stage_note"].content != note:
            self.gui["stage_note"].content = note

    def _refresh(self, sim, ends) -> None:
        rows = sim.stage_list()
        key = (tuple((r["name"], r["state"], id(r["report"])) for r in rows), len(ends))
        if key != self._table_key:
            self._table_key = key
            self.gui["stages_table"].content = stages_markdown(rows)
        if ends is not self._ends:
            self._ends = ends
            opts = (LIVE,) + tuple(stage_label(k, e.name) for k, e in enumerate(ends))
            with self.app.quiet():
                self.gui["stage_show"].options = opts
