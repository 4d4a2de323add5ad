"""The viewer's colour range and legend without a server (issue 15, item 19): rounding noise is
one colour and is called uniform; a real spread keeps its range, with its middle in the legend."""

from __future__ import annotations

import numpy as np

from clothsim.viewer.render import ViewSettings, field_range, is_uniform, legend_text


def test_noise_is_uniform_not_hotspots():
    """Weft strain of -7.8e-8 .. 1.1e-8 (rounding noise of compression_sleeve.yaml) spans less
    than 1 % of the colour range, and the legend says uniform."""
    rng = np.random.default_rng(1)
    vals = rng.uniform(-7.8e-8, 1.1e-8, 500)
    lo, hi = field_range(vals, "strain_weft", ViewSettings())
    assert hi - lo >= 1e-6 and lo <= vals.min() and hi >= vals.max()
    t = (vals - lo) / (hi - lo)
    assert np.ptp(t) < 0.1 and abs(t.mean() - 0.5) < 0.1
    assert is_uniform(vals, "strain_weft")
    assert legend_text("weft strain", "strain_weft", lo, hi, True) == "**weft strain**: uniform (0)"


def test_real_spread_keeps_its_range():
    vals = np.linspace(0.0, 0.1, 50)
    lo, hi = field_range(vals, "strain_warp", ViewSettings())
    assert (lo, hi) == (0.0, 0.1) and not is_uniform(vals, "strain_warp")
    assert legend_text("warp strain", "strain_warp", lo, hi) == "**warp strain**: 0 (dark) · 0.05 · 0.1 (yellow)"
    p = np.full(20, 3.0)  # a uniform tension of 3 N/m
    lo, hi = field_range(p, "tension", ViewSettings())
    assert lo < 3.0 < hi and hi - lo < 1e-3 and is_uniform(p, "tension")
    assert "uniform (3)" in legend_text("tension (max of warp, weft)", "tension", lo, hi, True)
    lo, hi = field_range(np.zeros(5), "pressure", ViewSettings())
    assert lo == 0.0 and hi > 0


def test_plot_leaves_room_above_the_top_tick():
    """Issue 15, item 24: the log axis' range ends above its top tick, so that the tick's label is
    not cut off by the plot's edge (it was: the range ended exactly at the top decade)."""
    from types import SimpleNamespace

    from clothsim.viewer.plot import ResidualPlot

    class Gui:
        def add_uplot(self, **kw):
            return SimpleNamespace(**kw, axes=None)

    plot = ResidualPlot(Gui(), e=1e-6, min_period=0.04)
    it = np.arange(1.0, 101.0)
    plot.update((it, 0.3 * 10 ** (-it / 20)), (np.zeros(0), np.zeros(0)), 1e-6, lambda: 0.3, running=False)
    splits = plot.handle.axes[1]["splits"]
    lo, hi = plot.handle.scales["y"]["range"]
    assert lo == splits[0] and hi >= 2 * splits[-1] and splits[-1] >= 0.3
