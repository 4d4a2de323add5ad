"""The run panel: title, status line, Start / Pause / Step / Reset, Apply and the unapplied edits."""

from __future__ import annotations

import html

import numpy as np

from ...diagnostics import seam_report, sheet_health
from ...labels import record_field
from ...records import Diagnostics, RunSummary
from ..render import Frame, fmt
from . import Panel

#: what undetermined nodes mean and what to do (issue 28, item 18)
UNDETERMINED_ADVICE = ("Undetermined: nothing fixes where these nodes sit (slack springs, no contact, no "
                       "constraint). Hold the ends along the axis, add pre-tension, or switch on "
                       "`shear:`/`bending:` springs.")
#: the summary figures the status line shows, named and in the units of the one field list
#: (clothsim.records), as summary.json, the report and the sweeps name them
RESIDUAL, LIMIT, CONTACT = (record_field(RunSummary, k) for k in ("residual", "e", "contact_count"))
SLACK, SPRINGS, UNDETERMINED, WEFT_EXTENT = (record_field(Diagnostics, k) for k in (
    "slack_springs", "spring_count", "undetermined_nodes", "min_weft_extent_ratio"))
STATE_TEXT = {"idle": "ready", "max_iterations": "stopped (max iterations)", "time_limit": "stopped (time limit)"}


class RunPanel(Panel):
    def __init__(self, app):
        super().__init__(app)
        self.status_text = ""
        self.health = ""
        self.health_key: tuple | None = None

    def build(self, gui) -> None:
        app, g = self.app, self.gui
        g["title"] = gui.add_markdown(f"**clothsim** · {html.escape(app.sim.scene.name)}")
        g["status"] = gui.add_markdown("starting ...")
        g["run"] = gui.add_button_group("Run", ("Start", "Pause", "Step", "Reset"))

        def on_run(event) -> None:
            v = event.target.value
            {"Start": app.start, "Pause": app.pause, "Step": app.step, "Reset": app.reset}[v]()

        g["run"].on_click(on_run)
        g["apply"] = gui.add_button("Apply edits", disabled=True, hint="rebuild the model from the edited scene, "
                                                                        "keeping the current shape (a run "
                                                                        "goes on)")
        g["apply"].on_click(lambda _e: app.apply())
        g["pending"] = gui.add_markdown("No unapplied edits.")
        app.err("run")

    def sync(self) -> None:
        pending = self.app.scene_draft.pending
        if pending:
            self.gui["pending"].content = (
                f"**Unapplied edits:** {', '.join(sorted(pending))}. *Apply* keeps the current "
                f"shape as a warm start; *Reset* restarts from the initial deformation.")
        else:
            self.gui["pending"].content = "No unapplied edits."
        self.gui["apply"].disabled = not pending

    def update_status(self, running: bool, last: Frame | None) -> None:
        """The status line (called by the update loop)."""
        sim = self.app.sim
        status = sim.status
        r = sim.residual
        if not np.isfinite(r):
            r = self.app.initial_residual()
        it = sim.state.iteration
        e = sim.settings.e
        contact = int(np.count_nonzero(last.in_contact)) if last is not None else 0
        state = STATE_TEXT.get(status, status)
        if status == "converged" and np.isfinite(r) and r > e:  # e was tightened after the run
            state = "not converged at the new e (Start continues)"
        # iterations per second: the running rate, or the last run's mean (the solver's final
        # progress report carries no rate); nothing before any run
        ips = sim.ips
        last_run = sim.last_result
        if not running and last_run is not None and last_run.wall_time_s > 0:
            ips = last_run.iterations / last_run.wall_time_s
        rate = f" · {ips:,.0f} it/s" if ips > 0 else ""
        text = status_line(state, it, r, e, contact, rate, sim.method)
        if sim.message and status not in ("running", "idle", "paused"):
            text += f"  \n<small>{html.escape(sim.message)}</small>"
        if not running and last is not None:
            text += "  \n" + self.health_text(last)
        if text != self.status_text:
            self.status_text = text
            self.gui["status"].content = text

    def health_text(self, f: Frame) -> str:
        """Slack springs, undetermined nodes and the sheet's narrowest weft extent: a band that
        gathers into a rope or a region held by nothing is shown, not hidden."""
        key = (id(f.model), f.iteration, id(f.positions))
        if self.health_key != key:
            self.health = health_line(sheet_health(f.model, f.positions, f.in_contact)) + seam_text(
                f.model, f.positions)
            self.health_key = key
        return self.health


def status_line(state: str, iteration: int, residual: float, e: float, contact: int, rate: str,
                method: str) -> str:
    """The status line's first line: the state, the iteration, the residual against the limit e,
    the contact nodes (named and in units as the field list has them), the rate and the solver."""
    return (f"**{state}** · iteration {iteration} · {RESIDUAL.label} {fmt(residual, 3)} {RESIDUAL.unit} "
            f"({LIMIT.label} = {fmt(e, 2)} {LIMIT.unit}) · {contact} {CONTACT.label}{rate} · {method}")


def health_line(h: dict) -> str:
    """The sheet's health (clothsim.diagnostics.sheet_health: slack springs, undetermined nodes,
    narrowest weft extent), named as the field list names them, with a warning and advice when
    the sheet gathers or nodes are undetermined."""
    ratio = h["min_weft_extent_ratio"]
    warn = ratio < 0.5 or h["undetermined_nodes"] > 0
    txt = (f"{h['slack_springs']} {SLACK.label} of {h['spring_count']} {SPRINGS.label} · "
           f"{h['undetermined_nodes']} {UNDETERMINED.label} · {WEFT_EXTENT.label} {ratio:.0%}")
    if ratio < 0.5:
        txt += " (the sheet gathers: nothing holds its width)"
    if h["undetermined_nodes"] > 0:
        txt += f"  \n{UNDETERMINED_ADVICE}"
    return f"<small>{'⚠ ' if warn else ''}{txt}</small>"


def seam_text(model, positions) -> str:
    """One line per seam: its widest gap [m] and, for an eased seam, its ease [%] (empty
    without seams)."""
    if not model.seams:
        return ""
    rows = seam_report(model, positions)["seams"]
    parts = [f"seam {n}: widest gap {fmt(r['max_gap_m'], 2)} m"
             + (f" (ease {r['ease_pct']:.1f} %)" if r["ease_pct"] > 0.01 else "") for n, r in enumerate(rows)]
    return "  \n<small>" + " · ".join(parts) + "</small>"
