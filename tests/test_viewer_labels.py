"""Issue 29 item 1: the viewer reads the one field list (clothsim.records). Its status line, the
sheet's health, the convergence plot's series and the probe readouts name a figure and give its
unit as summary.json, the report and the sweeps do, instead of keys and units written by hand
(the status said "residual ... N (e = ...)", the plot "||V||inf [N]" and "target e", each typed
again in the viewer). No browser, no server: the pure formatting functions."""

from __future__ import annotations

import dataclasses
import re

import pytest

from clothsim.labels import axis_label, record_field
from clothsim.records import OUTPUT_FIELDS, Diagnostics, ProbeReading, RunSummary


def test_record_field_gives_a_records_label_and_unit():
    f = record_field(RunSummary, "residual")
    assert (f.label, f.unit) == (OUTPUT_FIELDS["residual"].label, OUTPUT_FIELDS["residual"].unit) == \
        ("residual ||V||inf", "N")
    p = record_field(ProbeReading, "pressure_mmhg")
    meta = next(x for x in dataclasses.fields(ProbeReading) if x.name == "pressure_mmhg").metadata
    assert (p.label, p.unit) == (meta["label"], meta["unit"]) == ("pressure", "mmHg")
    with pytest.raises(KeyError, match="no field 'nope'"):
        record_field(Diagnostics, "nope")


def test_the_status_line_names_the_summary_fields_as_the_field_list_does():
    from clothsim.viewer.panels.run import status_line

    text = status_line("converged", 12, 1.5e-7, 1e-6, 35, " · 900 it/s", "newton")
    res, e, contact = OUTPUT_FIELDS["residual"], OUTPUT_FIELDS["e"], OUTPUT_FIELDS["contact_count"]
    assert f"{res.label} 1.50e-07 {res.unit}" in text, text
    assert f"({e.label} = 1.0e-06 {e.unit})" in text, text
    assert f"35 {contact.label}" in text, text
    # what the browser tests read from the page (tests/browser_util.py) is still there
    assert re.search(r"iteration \d+ · residual", text) and "iteration 12" in text


def test_the_sheet_health_names_the_diagnostics_fields():
    from clothsim.viewer.panels.run import health_line

    h = {"slack_springs": 40, "spring_count": 84, "undetermined_nodes": 3, "min_weft_extent_ratio": 0.3}
    text = health_line(h)
    for key, v in (("slack_springs", "40"), ("spring_count", "84"), ("undetermined_nodes", "3")):
        assert f"{v} {OUTPUT_FIELDS[key].label}" in text, (key, text)
    assert f"{OUTPUT_FIELDS['min_weft_extent_ratio'].label} 30%" in text, text
    assert text.startswith("<small>⚠ ") and "the sheet gathers" in text and "Hold the ends" in text
    calm = health_line({"slack_springs": 0, "spring_count": 84, "undetermined_nodes": 0, "min_weft_extent_ratio": 1.0})
    assert "⚠" not in calm and "gathers" not in calm


def test_the_convergence_plot_labels_its_series_from_the_field_list():
    from clothsim.viewer.plot import ResidualPlot

    seen = {}

    class Gui:
        def add_uplot(self, **kw):
            seen.update(kw)
            return object()

    ResidualPlot(Gui(), 1e-6, 0.05)
    labels = [s["label"] for s in seen["series"]]
    assert labels[1:] == [axis_label("residual"), axis_label("e")] == ["residual ||V||inf [N]",
                                                                       "convergence limit e [N]"]


def test_probe_readouts_take_their_unit_from_the_probe_reading():
    from types import SimpleNamespace

    from clothsim.viewer.panels.probes import ProbesPanel
    from clothsim.viewer.pick import probe_label, readout_text

    unit = record_field(ProbeReading, "pressure_mmhg").unit
    assert probe_label({"name": "ankle", "on_contact": True, "pressure_mmhg": 21.34, "contact_fraction": 1.0}) \
        == f"ankle 21.3 {unit}"
    panel = ProbesPanel(SimpleNamespace(gui={}, sim=SimpleNamespace(scene=SimpleNamespace(probes=[1]))))
    panel.readings = [{"name": "calf", "pressure_mmhg": 14.06, "contact_fraction": 1.0}]
    assert panel.table().splitlines()[0] == f"| probe | {unit} | covered |"
    r = {"node": 3, "panel": "sheet", "ij": (1, 2), "position": (0.0, 0.0, 0.0), "in_contact": True,
         "pressure_mmhg": 10.0, "strain_warp": 0.1, "strain_weft": 0.2, "tension_warp": 1.0, "tension_weft": 2.0}
    mmhg, pa = (record_field(Diagnostics, k).unit for k in ("max_contact_pressure_mmhg", "max_contact_pressure_pa"))
    assert f"10.00 {mmhg} (1333 {pa})" in readout_text(r)
