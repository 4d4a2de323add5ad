"""User text in plots is text, and a plot never costs a result (issue 28 item 4).

A ``$`` in a scene, profile or sweep name was parsed as matplotlib mathtext: ``--set 'name=sleeve
$20_$30'`` converged, then the profile plot raised, exit 1 with a traceback and ``--out`` empty.
Every text from user data is drawn with ``parse_math=False`` (and ``usetex=False``), and a plot
that fails anyway is a warning: the numeric files are written all the same."""

from __future__ import annotations

import io
import json
import os

import numpy as np
import pytest
import yaml

from clothsim import sweep as sw

from conftest import ROOT, cli_main

SLEEVE = ROOT / "configs" / "class2_sleeve.yaml"
STRIP = ROOT / "configs" / "uniaxial_strip.yaml"
NAME = "sleeve $20_$30"
PROFILE = "profiles=[{name: 'leg $1_$2 \\alpha', axis: z, from: -0.035, to: 0.04, step: 0.005}]"
NUMERIC = ("result.npz", "history.csv", "sheet.ply", "scene.yaml", "probes.csv", "profiles.csv", "summary.json")


def test_a_dollar_in_scene_and_profile_names_is_drawn_as_text(tmp_path, capsys):
    out = tmp_path / "run"
    rc, err = cli_main(capsys, "run", str(SLEEVE), "--quiet", "--set", f"name={NAME}", "--set", PROFILE,
                    "--out", str(out))
    assert rc == 0, err
    assert all((out / n).is_file() for n in (*NUMERIC, "profiles.png")), sorted(os.listdir(out))
    assert json.loads((out / "summary.json").read_text())["name"] == NAME
    rc, err = cli_main(capsys, "report", str(out))
    assert rc == 0, err
    assert "profile plot" in (out / "report.html").read_text()


def test_user_text_is_never_mathtext():
    """The figures' texts that come from user data are plain text (a '$' pair would otherwise
    parse: 'a $x$ b' draws an italic x, no error to notice)."""
    import matplotlib.text

    from clothsim.compression import probes

    seen = []
    real = matplotlib.text.Text._preprocess_math

    def spy(self, s):
        seen.append((s, self.get_parse_math(), self.get_usetex()))
        return real(self, s)

    mp = pytest.MonkeyPatch()
    mp.setattr(matplotlib.text.Text, "_preprocess_math", spy)
    try:
        slices = [{"height_m": h, "mean_mmhg": 20.0 - h, "min_mmhg": 19.0, "max_mmhg": 21.0} for h in (0.0, 0.1)]
        probes.profile_png([{"name": "a $x$ b", "slices": slices}], "t $y$ z")
    finally:
        mp.undo()
    user = [(s, pm, tex) for s, pm, tex in seen if "$x$" in s or "$y$" in s]
    assert {s for s, _, _ in user} >= {"a $x$ b (mean)", "a $x$ b (min-max)", "t $y$ z"}, seen
    assert all(pm is False and tex is False for _, pm, tex in user), user


def test_a_failing_plot_costs_no_result_file(tmp_path, capsys, monkeypatch):
    """Any failure drawing profiles.png (here: savefig raising) is a warning; the numeric files are
    written and the run's exit status is its solve's."""
    from matplotlib.figure import Figure

    def broken(self, *a, **k):
        raise RuntimeError("the plot broke")

    monkeypatch.setattr(Figure, "savefig", broken)
    out = tmp_path / "run"
    rc, err = cli_main(capsys, "run", str(SLEEVE), "--quiet", "--out", str(out))
    assert rc == 0, err
    assert all((out / n).is_file() for n in NUMERIC), sorted(os.listdir(out))
    assert not (out / "profiles.png").exists()
    assert "warning: profiles.png not written (RuntimeError: the plot broke)" in err, err
    # the report: the plot's place says why it is missing
    rc, err = cli_main(capsys, "report", str(out))
    assert rc == 0, err
    text = (out / "report.html").read_text()
    assert "profile plot not drawn (RuntimeError: the plot broke)" in text
    assert "warning: report: profile plot not drawn" in err, err


def _sweep_file(tmp_path, name):
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump({
        "name": name, "base": os.path.relpath(STRIP, tmp_path),
        "set": {"fabric.divisions": [6, 2], "solver.method": "paper"},
        "sweep": {"mode": "grid", "parameters": {"solver.C": [1.5, 3], "name": ["a $1_$2", "b $3_$4"]}},
        "outputs": ["iterations", "energy"],
    }, sort_keys=False))
    return p


def test_sweep_plots_draw_user_text_as_text(tmp_path):
    s = sw.load_sweep(_sweep_file(tmp_path, "cost $20_$30"))
    rows = [{**r.params, "status": "converged", "iterations": 10 + i, "energy": 1.0 + i}
            for i, r in enumerate(s.runs)]
    written = sw.make_plots(s, rows, tmp_path / "out")
    assert len(written) == 4 and all(p.stat().st_size > 1000 for p in written)


def test_a_failing_sweep_plot_is_a_warning(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    def broken(self, *a, **k):
        raise RuntimeError("the plot broke")

    monkeypatch.setattr(Figure, "savefig", broken)
    p = _sweep_file(tmp_path, "s")
    with pytest.warns(UserWarning, match=r"plots not \(all\) written \(RuntimeError: the plot broke\); the results "
                                         r"are in .*summary.csv"):
        rep = sw.run_sweep(p, tmp_path / "out", workers=1, stream=io.StringIO())
    assert rep["statuses"] == {"converged": 4}, rep
    rows = (tmp_path / "out" / "summary.csv").read_text().splitlines()
    assert len(rows) == 5
    assert not list((tmp_path / "out" / "plots").glob("*.png"))
    assert np.isfinite(float(rows[1].split(",")[rows[0].split(",").index("energy")]))
