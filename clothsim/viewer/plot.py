"""The convergence plot: the residual ||V||inf [N] against the iteration on a log axis, with the
target e as a dashed line, and for a staged run a grey dotted vertical line where each stage
began (the x axis's label names them). Built once; :meth:`ResidualPlot.update` is called by the
update loop only and re-sends the arrays only when what they show changed."""

from __future__ import annotations

import contextlib
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


#: the stage marks' series (a staged run): one polyline that runs below the plot (clipped away)
#: and goes up and down through the whole height at each stage's first iteration
MARK_SERIES = {"label": "stage starts", "stroke": "#495057", "width": 1.0, "dash": (2.0, 3.0),
               "points": {"show": False}}


def with_marks(x: np.ndarray, columns: list[np.ndarray], marks, low: float, high: float):
    """(x, columns, mark column): ``x`` and its series ``columns`` with three points inserted at
    each mark's iteration (every column holding its value there, interpolated: the residual on a
    log scale) and the marks' column: ``low`` (below the plot) everywhere but the middle one of
    each inserted three, ``high`` (above it), so that it draws a vertical line at each mark."""
    if not len(x):
        return x, columns, np.zeros(0)
    xs, cols, mk = [x], [[c] for c in columns], [np.full(len(x), low)]
    for b in sorted(float(b) for b, _ in marks):
        xs.append(np.full(3, b))
        for c, col in zip(cols, columns):
            v = math.exp(np.interp(b, x, np.log(np.maximum(col, 1e-300))))
            c.append(np.full(3, v))
        mk.append(np.array([low, high, low]))
    order = np.argsort(np.concatenate(xs), kind="stable")
    return (np.concatenate(xs)[order], [np.concatenate(c)[order] for c in cols], np.concatenate(mk)[order])


def marks_label(marks) -> str:
    """The x axis's label: "iteration" and, for a staged run, where each stage began."""
    if not marks:
        return "iteration"
    return "iteration · stages: " + ", ".join(f"{name or 'load steps'} from {int(b)}" for b, name in marks)


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
        self.marked = False  # the stage marks' series is shown
        # a context in which the series and data messages go out together (the server's atomic)
        self.atomic = contextlib.nullcontext

    def due(self, running: bool) -> bool:
        """Whether an update would be sent now (at most every few frames while running)."""
        return not running or time.perf_counter() - self._last >= max(0.25, 8 * self.min_period)

    def update(self, hist: tuple[np.ndarray, np.ndarray], live: tuple[np.ndarray, np.ndarray],
               e: float, initial_residual: Callable[[], float], running: bool, marks=()) -> None:
        """Show ``hist`` (iterations, residuals [N]) followed by the ``live`` points after it; ``initial_residual()``
        [N] is drawn flat when there is nothing yet; ``marks`` [(iteration, stage name)]: where
        each stage of a staged run began (a vertical line each). At most every few frames while
        running."""
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
        marks = tuple((int(b), str(n)) for b, n in marks)
        key = (len(x), float(x[-1]), float(y[-1]), float(y.min()), e, marks)
        if key == self._key:
            return
        self._key = key
        self._last = now
        lo = min(float(y.min()), e) * 0.8
        hi = max(float(y.max()), e) * 1.25
        splits = decades(lo, hi)
        plot = self.handle
        if (splits, marks) != self._axes_key:
            self._axes_key = (splits, marks)
            plot.axes = ({"label": marks_label(marks)},
                         {"splits": splits, "values": tuple(f"1e{round(math.log10(s))}" for s in splits),
                          "size": 48})
            # a third of a decade above the top tick, so that its label is not cut by the plot's edge
            plot.scales = {"x": {"time": False},
                           "y": {"distr": 3, "log": 10, "range": (splits[0], splits[-1] * TOP_PAD)}}
        if marks:
            x, (y, ee), m = with_marks(x, [y, np.full_like(y, e)], marks, splits[0] / 10.0,
                                       splits[-1] * TOP_PAD * 10.0)
            data = (x, y, ee, m)
        else:
            data = (x, y, np.full_like(y, e))
        if bool(marks) == self.marked:
            plot.data = data
            return
        self.marked = bool(marks)
        with self.atomic():  # series and data change length together
            plot.series = tuple(plot.series[:3]) + ((MARK_SERIES,) if marks else ())
            plot.data = data
