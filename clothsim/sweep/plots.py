"""The sweep's plots: one PNG per (output, varied parameter), axes labelled from the field list."""

from __future__ import annotations

import io
import math
from pathlib import Path

from ..labels import axis_label
from ..plottext import PLAIN, plain_legend
from ..records import TIMING_KEYS
from .runs import _atomic_write
from .spec import Space, Sweep, _fmt


def _axis_values(values: list) -> tuple[list[float] | None, str]:
    """Numeric x positions for parameter values, or None for categorical ones, and an axis note."""
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return [float(v) for v in values], ""
    if all(isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) for x in v)
           and len(set(v)) == 1 for v in values):
        return [float(v[0]) for v in values], " (n of [n, n])"
    return None, ""


def _label(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return _fmt(v)


#: outputs that keep the books (timings) rather than describe the result: not plotted unless the
#: sweep file lists them under ``plots``
BOOKKEEPING = TIMING_KEYS


def plot_axes(sweep: Sweep, rows: list[dict]) -> list[str]:
    """The parameters the plots put on their x axis: in grid mode each parameter that takes more
    than one value; in zip mode one (the zipped parameters change together): ``sweep.x`` or the
    first that takes more than one value."""
    def varies(param):
        seen = []
        for r in rows:
            if r.get(param) not in seen:
                seen.append(r.get(param))
        return len(seen) > 1

    moving = [p for p in sweep.varied if varies(p)]
    if sweep.spec.sweep.mode == "zip":
        if sweep.spec.sweep.x is not None:
            return [sweep.spec.sweep.x]
        return moving[:1]
    return moving


def plot_outputs(sweep: Sweep, rows: list[dict]) -> list[str]:
    """The outputs plotted: the sweep file's ``plots``, or every numeric output but the
    bookkeeping ones (BOOKKEEPING: timings)."""
    chosen = sweep.spec.plots if sweep.spec.plots is not None else [
        o for o in sweep.spec.outputs if o not in BOOKKEEPING]
    return [o for o in chosen
            if any(isinstance(r.get(o), (int, float)) and not isinstance(r.get(o), bool) for r in rows)]


def make_plots(sweep: Sweep, rows: list[dict], out: Path) -> list[Path]:
    """One PNG per (plotted output, x axis): out/plots/<output>__vs__<param>.png, axes labelled
    with readable names and units (clothsim.labels). The x axes are :func:`plot_axes`, the
    outputs :func:`plot_outputs`.

    grid mode with several parameters: one line per combination of the other parameters (up to
    10, with a legend), otherwise points. zip mode: one line. Runs that did not converge are
    drawn hollow; failed runs (no value) are left out and counted in the title. Names and swept
    values are drawn as written, never as mathtext (clothsim.plottext)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    outputs = plot_outputs(sweep, rows)
    pdir = out / "plots"
    pdir.mkdir(parents=True, exist_ok=True)
    written = []
    varied = sweep.varied
    spaces = sweep.spec.sweep.parameters
    for param in plot_axes(sweep, rows):
        all_vals = []
        for r in rows:
            if r[param] not in all_vals:
                all_vals.append(r[param])
        xs_num, note = _axis_values(all_vals)
        others = [p for p in varied if p != param] if sweep.spec.sweep.mode == "grid" else []
        groups: dict[str, list[dict]] = {}
        for r in rows:
            key = ", ".join(f"{p}={_label(r[p])}" for p in others)
            groups.setdefault(key, []).append(r)
        logx = isinstance(spaces[param], Space) and spaces[param].logspace is not None
        if xs_num is not None and not logx and min(xs_num) > 0 and max(xs_num) / min(xs_num) >= 16 and len(xs_num) >= 4:
            logx = True
        for o in outputs:
            fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
            n_missing = 0
            as_lines = len(groups) <= 10
            cmap = plt.get_cmap("viridis" if len(groups) > 10 else "tab10")
            for gi, (key, grp) in enumerate(groups.items()):
                pts = []
                for r in grp:
                    y = r.get(o)
                    if not isinstance(y, (int, float)) or isinstance(y, bool) or not math.isfinite(y):
                        n_missing += 1
                        continue
                    x = xs_num[all_vals.index(r[param])] if xs_num is not None else all_vals.index(r[param])
                    pts.append((x, float(y), r["status"] == "converged"))
                if not pts:
                    continue
                pts.sort()
                color = cmap(gi / max(1, len(groups) - 1)) if len(groups) > 10 else cmap(gi % 10)
                if as_lines:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", color=color, lw=1.4,
                            label=key or None)
                for x, y, ok in pts:
                    ax.plot([x], [y], "o", ms=5, color=color, mfc=color if ok else "none",
                            alpha=1.0 if as_lines else 0.6)
            if xs_num is None:
                ax.set_xticks(range(len(all_vals)))
                ax.set_xticklabels([_label(v) for v in all_vals], rotation=30 if len(all_vals) > 6 else 0, **PLAIN)
            elif logx:
                from matplotlib.ticker import NullFormatter

                ax.set_xscale("log")
                ticks = sorted(set(xs_num))
                if len(ticks) <= 12:  # label the swept values themselves, not powers of ten
                    ax.set_xticks(ticks)
                    ax.set_xticklabels([f"{t:.4g}" for t in ticks])
                    ax.xaxis.set_minor_formatter(NullFormatter())
            ys = [r.get(o) for r in rows if isinstance(r.get(o), (int, float)) and not isinstance(r.get(o), bool)]
            pos = [y for y in ys if math.isfinite(y) and y > 0]
            if pos and len(pos) == len(ys) and max(pos) / min(pos) > 1e3:
                ax.set_yscale("log")
            # plain text: a field name or a unit is never parsed as mathtext
            ax.set_xlabel(axis_label(param) + note, **PLAIN)
            ax.set_ylabel(axis_label(o), **PLAIN)
            title = f"{sweep.spec.name or sweep.path.stem}: {o} against {param}"
            sub = []
            together = [p for p in varied if p != param] if sweep.spec.sweep.mode == "zip" else []
            if together:
                sub.append(f"zipped with {', '.join(together)}")
            if any(r["status"] != "converged" for r in rows if isinstance(r.get(o), (int, float))):
                sub.append("hollow = did not converge")
            if n_missing:
                sub.append(f"{n_missing} runs without a value (failed or pending)")
            if not as_lines:
                sub.append(f"{len(groups)} combinations of {', '.join(others)} as points")
            ax.set_title(title + ("\n" + "; ".join(sub) if sub else ""), fontsize=10, **PLAIN)
            ax.grid(True, alpha=0.3, which="both")
            if as_lines and others:
                plain_legend(ax, fontsize=8, title=None, loc="best", framealpha=0.8)
            fig.tight_layout()
            safe = f"{o}__vs__{param}".replace("/", "_").replace(":", "_")
            p = pdir / f"{safe}.png"
            buf = io.BytesIO()
            fig.savefig(buf, format="png")
            plt.close(fig)
            _atomic_write(p, buf.getvalue())
            written.append(p)
    return written
