"""The convergence plot: the residual ||V||inf [N] against the iteration on a log axis, with the
target e as a dashed line. Built once; :meth:`ResidualPlot.update` is called by the update loop
only and re-sends the arrays only when what they show changed."""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from ..labels import axis_label

#: the plotted series' labels: the residual and its limit e as the field list names them
RESIDUAL_LABEL = axis_label("residual")
LIMIT_LABEL = axis_label("e")
PLOT_POINTS = 1500
TOP_PAD = 10.0 ** (1 / 3)  # room above the top tick label (issue 15, item 24)
#: uPlot padding [px] (top, right, bottom, left): in the browser the chart's canvas starts at the
#: top tick, whatever the scale's range, and cut that tick's label in half without it
PADDING = (14, 12, 0, 0)


def thin(x: np.ndarray, y: np.ndarray, n: int = PLOT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """At most about n points, evenly spread, the first and last kept."""
    if len(x) <= n:
        return x, y
    idx = np.unique(np.concatenate([np.linspace(0, len(x) - 1, n).astype(np.int64), [len(x) - 1]]))
    return x[idx], y[idx]


def decades(lo: float, hi: float) -> tuple[float, ...]:
    """Powers of ten covering [lo, hi] (lo > 0), at most about nine of them: the log axis ticks."""
    a = math.floor(math.log10(lo))
    b = math.ceil(math.log10(hi))
    if b <= a:
        b = a + 1
    step = max(1, math.ceil((b - a) / 8))
    return tuple(10.0 ** k for k in range(a, b + 1, step))


class ResidualPlot:
    """The uPlot of the residual history (cumulative history of the simulation plus the live
    points of the current run segment)."""

    def __init__(self, gui, e: float, min_period: float):
        self.min_period = min_period
        self.handle = gui.add_uplot(
            data=(np.array([0.0, 1.0]), np.array([1.0, 1.0]), np.array([e, e])),
            series=({"label": "iteration"},
                    {"label": RESIDUAL_LABEL, "stroke": "#1c7ed6", "width": 1.5},
                    {"label": LIMIT_LABEL, "stroke": "#e03131", "width": 1.0, "dash": (6.0, 4.0)}),
            scales={"x": {"time": False}, "y": {"distr": 3, "log": 10}},
            title="Convergence", aspect=1.8, padding=PADDING)
        self._key: tuple | None = None
        self._axes_key: tuple | None = None
        self._last = 0.0

    def due(self, running: bool) -> bool:
        """Whether an update would be sent now (at most every few frames while running)."""
        return not running or time.perf_counter() - self._last >= max(0.25, 8 * self.min_period)

    def update(self, hist: tuple[np.ndarray, np.ndarray], live: tuple[np.ndarray, np.ndarray],
               e: float, initial_residual: Callable[[], float], running: bool) -> None:
        """Show ``hist`` (iterations, residuals [N]) followed by the ``live`` points after it; ``initial_residual()``
        [N] is drawn flat when there is nothing yet. At most every few frames while running."""
        if not self.due(running):
            return
        now = time.perf_counter()
        hx, hy = hist
        lx, ly = live
        if len(hx) and len(lx):
            keep = lx > hx[-1]
            lx, ly = lx[keep], ly[keep]
        x = np.concatenate([hx, lx])
        y = np.concatenate([hy, ly])
        ok = np.isfinite(y) & (y > 0)
        x, y = x[ok], y[ok]
        if len(x) == 0:
            r0 = initial_residual()
            x, y = np.array([0.0, 1.0]), np.array([r0, r0])
        elif len(x) == 1:
            x, y = np.array([x[0] - 1, x[0]]), np.array([y[0], y[0]])
        x, y = thin(x, y)
        key = (len(x), float(x[-1]), float(y[-1]), float(y.min()), e)
        if key == self._key:
            return
        self._key = key
        self._last = now
        lo = min(float(y.min()), e) * 0.8
        hi = max(float(y.max()), e) * 1.25
        splits = decades(lo, hi)
        plot = self.handle
        if splits != self._axes_key:
            self._axes_key = splits
            plot.axes = ({"label": "iteration"},
                         {"splits": splits, "values": tuple(f"1e{round(math.log10(s))}" for s in splits),
                          "size": 48})
            # a third of a decade above the top tick, so that its label is not cut by the plot's edge
            plot.scales = {"x": {"time": False},
                           "y": {"distr": 3, "log": 10, "range": (splits[0], splits[-1] * TOP_PAD)}}
        plot.data = (x, y, np.full_like(y, e))
