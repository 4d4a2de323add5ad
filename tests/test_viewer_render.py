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
    assert legend_text("weft strain", "strain_weft", lo, hi, True) == "**weft strain**: 0 everywhere"


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


def test_colour_bar_has_ticks_at_the_ranges_nice_values():
    """Issue 15, item 19: the colour bar carries tick marks with values. For 0 .. 0.1 the ticks
    are 0, 0.05, 0.1, drawn as dark marks under the gradient at columns 0, 128 and 255 of a
    256-pixel bar (nothing between them), with their labels written below."""
    from clothsim.viewer.glb import (BAR_HEIGHT, LABEL_HEIGHT, TICK_LENGTH, colorbar_image,
                                     colorbar_with_ticks, nice_ticks, tick_label)

    img, ticks = colorbar_with_ticks(0.0, 0.1, 256)
    assert ticks == [0.0, 0.05, 0.1]
    assert [tick_label(t, 0.05) for t in ticks] == ["0", "0.05", "0.1"]
    assert img.shape == (BAR_HEIGHT + TICK_LENGTH + LABEL_HEIGHT, 256, 3)
    assert (img[:BAR_HEIGHT] == colorbar_image(256, BAR_HEIGHT)).all()  # the gradient unchanged
    for row in range(BAR_HEIGHT, BAR_HEIGHT + TICK_LENGTH):
        dark = np.nonzero(img[row].max(axis=1) < 100)[0]
        assert dark.tolist() == [0, 128, 255], (row, dark)
    labels = img[BAR_HEIGHT + TICK_LENGTH:]
    assert (labels.max(axis=2) < 150).sum() > 20  # the values are drawn
    # other ranges: round steps inside the range, at most five, at least two
    assert nice_ticks(-7.8e-8, 1.1e-8) == [-6e-8, -4e-8, -2e-8, 0.0]
    assert nice_ticks(0.0, 3.25) == [0.0, 1.0, 2.0, 3.0]
    assert nice_ticks(101325.0, 101400.0) == [101340.0, 101360.0, 101380.0, 101400.0]
    assert nice_ticks(1.0, 1.0) == [] and nice_ticks(0.0, float("nan")) == []
    img, ticks = colorbar_with_ticks(-0.013, 0.052, 256)
    cols = np.nonzero(img[BAR_HEIGHT + 1].max(axis=1) < 100)[0]
    assert ticks == [0.0, 0.02, 0.04]
    assert cols.tolist() == [round((t + 0.013) / 0.065 * 255) for t in ticks]


def test_viewer_colour_bar_follows_the_range():
    """The viewer's colour-bar image has the ticks of the range it shows."""
    import time

    import pytest

    pytest.importorskip("viser")
    from clothsim.viewer import ViewerApp
    from clothsim.viewer.glb import BAR_HEIGHT, nice_ticks, tick_x
    from viewer_util import free_port, small_scene

    app = ViewerApp(small_scene(), port=free_port())
    try:
        assert app.wait_idle(300)
        app.panels["view"].gui["auto_range"].value = False
        app.panels["view"].gui["range_min"].value = -1.0
        app.panels["view"].gui["range_max"].value = 3.0
        assert app.wait_idle(300)
        want = tick_x(nice_ticks(-1.0, 3.0), -1.0, 3.0, 256).tolist()
        assert want == [0, 64, 128, 191, 255]

        def tick_columns():
            img = app.panels["view"].gui["legend_img"].image
            if img is None or img.shape[0] <= BAR_HEIGHT:
                return None
            return np.nonzero(img[BAR_HEIGHT + 1].max(axis=1) < 100)[0].tolist()

        # (the image is set on the loop pass that draws the new range: poll the image itself)
        t0 = time.time()
        while tick_columns() != want and time.time() - t0 < 60:
            time.sleep(0.05)
        assert app.panels["view"].gui["legend_img"].image.shape[1] == 256
        assert tick_columns() == want
    finally:
        app.close()
