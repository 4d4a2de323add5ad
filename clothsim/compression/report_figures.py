"""The report's figures (matplotlib, Agg), drawn from a result folder's arrays alone.

**Maps.** A node field on the deformed garment, with the body near it (``result.npz``'s
``body_vertices`` / ``body_faces``) in light grey, from three orthographic views: front (seen
from -y), side (from -x or +x: the side where most probes are) and top (from +z). Each view is a
plain 2D axes in metres (no 3D axes: their tick labels overlapped); the triangles of body and
garment are drawn far to near (painter's order by their centroids' depth), the body shaded by how
squarely it faces the viewer. Probes are marked with a ring and labelled with their name and
reading; a probe on the far side of the garment is drawn dashed, its label saying ``(behind)``.

**Colour scale** (:func:`colour_scale`): pressure from 0 to ``pmax``: given (``report --pmax``),
or by default the 95th percentile of the contact nodes' pressure rounded up to a whole number of
tick steps (1, 2, 2.5 or 5 times a power of ten); nodes above it take the top colour (the bar's
end is a triangle) and the caption says how many there are and the single-node peak. The ticks
run from the bottom of the scale to its top, so the top tick is the scale's maximum.
"""

from __future__ import annotations

import io
import math

import numpy as np

from ..plottext import PLAIN, plain_legend

#: the default pressure scale's top: this percentile of the contact nodes' pressure [%]
PMAX_PERCENTILE = 95.0
#: a view's direction of sight (unit vector from the viewer into the scene), right and up axes
VIEW_AXES = {"front": ((0, 1, 0), (1, 0, 0), (0, 0, 1)), "side -x": ((1, 0, 0), (0, -1, 0), (0, 0, 1)),
             "side +x": ((-1, 0, 0), (0, 1, 0), (0, 0, 1)), "top": ((0, 0, -1), (1, 0, 0), (0, 1, 0))}
AXIS_NAMES = {(1, 0, 0): "x [m]", (0, 1, 0): "y [m]", (0, 0, 1): "z [m]", (0, -1, 0): "-y [m]"}


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    return Figure


def png_bytes(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def nice_step(x: float) -> float:
    """The least of 1, 2, 2.5, 5 times a power of ten that is >= x (x > 0)."""
    e = math.floor(math.log10(x))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        if m * 10.0 ** e >= x * (1 - 1e-12):
            return m * 10.0 ** e
    return 10.0 ** (e + 1)


def nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """Ticks from lo to hi (both ticks) in about n steps; lo and hi must be multiples of the
    step (see colour_scale)."""
    step = nice_step((hi - lo) / n)
    k = int(round((hi - lo) / step))
    t = np.array([_tidy(lo + step * i) for i in range(k + 1)])
    t[0], t[-1] = lo, hi
    return t


def _tidy(x: float) -> float:
    """x to 12 significant digits (0.4000000000000001 -> 0.4)."""
    return float(f"{x:.12g}")


def colour_scale(values: np.ndarray, pmax: float | None = None, *, percentile: float | None = PMAX_PERCENTILE,
                 contact: np.ndarray | None = None) -> dict:
    """The colour scale of a node field: {lo, hi, ticks, above, peak, how}. ``pmax`` given: 0
    (or the least value, when negative) to pmax. Else the top is the field's ``percentile`` over
    the nodes in ``contact`` (all finite nodes without it; the maximum when percentile is None)
    rounded up to a whole number of nice steps, and the bottom min(0, least) rounded down.
    ``above``: how many nodes exceed the top; ``peak``: the greatest finite value; ticks[-1] ==
    hi (the bar's top tick is its maximum)."""
    v = np.asarray(values, float).reshape(-1)
    fin = np.isfinite(v)
    sel = fin & (np.asarray(contact, bool).reshape(-1) if contact is not None else True)
    pool = v[sel] if sel.any() else v[fin]
    peak = float(v[fin].max()) if fin.any() else 0.0
    least = float(v[fin].min()) if fin.any() else 0.0
    if pmax is not None:
        top, how = float(pmax), f"0 to {pmax:g} (chosen with --pmax)"
    elif pool.size:
        top = float(np.percentile(pool, percentile)) if percentile is not None else float(pool.max())
        how = (f"the {percentile:g}th percentile of the {'contact ' if contact is not None else ''}nodes' values"
               if percentile is not None else "the greatest value")
    else:
        top, how = 1.0, "no values"
    lo = min(0.0, least)
    if not top > lo:
        top = lo + (abs(lo) or 1.0)
    step = nice_step((top - lo) / 5.0)
    if pmax is None:
        top = _tidy(step * math.ceil(top / step - 1e-9))
    lo = _tidy(step * math.floor(lo / step + 1e-9))
    if pmax is None:
        ticks = nice_ticks(lo, top)
    else:   # the chosen top is a tick; the step's ticks below it, none closer than 0.4 step
        below = np.array([_tidy(x) for x in np.arange(lo, top, step)])
        ticks = np.r_[below[below < top - 0.4 * step], top]
    return {"lo": lo, "hi": top, "ticks": ticks, "above": int((v[fin] > top * (1 + 1e-12)).sum()), "peak": peak,
            "how": how}


def _view_dirs(name: str):
    d, r, u = (np.asarray(a, float) for a in VIEW_AXES[name])
    return d, r, u


def _project(P, name):
    d, r, u = _view_dirs(name)
    return P @ r, P @ u, P @ d   # depth: larger is farther


def side_view(probe_points, centre) -> str:
    """'side -x' (seen from -x) when most probes lie on the -x side of the garment's centre,
    else 'side +x'."""
    if probe_points is None or not len(probe_points):
        return "side -x"
    return "side -x" if float(np.mean(np.asarray(probe_points)[:, 0] - centre[0])) <= 0 else "side +x"


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def _outward(T: np.ndarray, body_v: np.ndarray, body_f: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the garment's triangles T (F, 3, 3), each turned to the side the
    body's normal points at its nearest body vertex (vertex normals: area-weighted face normals)."""
    from scipy.spatial import cKDTree

    B = body_v[body_f].astype(float)
    fn = np.cross(B[:, 1] - B[:, 0], B[:, 2] - B[:, 0])
    vn = np.zeros((len(body_v), 3))
    for k in range(3):
        np.add.at(vn, body_f[:, k], fn)
    c = T.mean(1)
    _, near = cKDTree(np.asarray(body_v, float)).query(c)
    n = _unit(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]))
    flip = np.einsum("ij,ij->i", n, vn[near]) < 0
    n[flip] *= -1
    return n


def _faces_away(c, radius, d, body_v, body_f) -> bool:
    """Whether the body under a probe (its triangles within ``radius`` of the centre, their
    area-weighted normal) faces away from a viewer looking along ``d``: the probe is behind."""
    if body_f is None or not len(body_f):
        return False
    T = body_v[body_f].astype(float)
    near = np.linalg.norm(T.mean(1) - c, axis=1) <= max(radius, 1e-3)
    if not near.any():
        return False
    n = np.cross(T[near, 1] - T[near, 0], T[near, 2] - T[near, 0]).sum(0)
    nn = np.linalg.norm(n)
    return bool(nn > 0 and (n / nn) @ d > 0.25)


def draw_view(ax, name, pos, faces, face_rgba, body_v, body_f, probes):
    """One orthographic view on a 2D axes: the body's triangles (grey, shaded) and the garment's
    (face_rgba) far to near, and the probes (ring, label)."""
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Circle

    d, r, u = _view_dirs(name)
    layers = []   # (triangles, colours) drawn in this order, each far to near
    has_body = body_f is not None and len(body_f)
    if has_body:
        T = body_v[body_f].astype(float)
        n = _unit(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]))
        shade = 0.55 + 0.4 * np.abs(n @ d)
        layers.append((T, np.c_[shade, shade, shade * 0.97, np.ones(len(T))]))
    if len(faces):
        T = pos[faces]
        keep = np.isfinite(T).all(axis=(1, 2))
        if has_body:
            # the garment lies on the body: its triangles facing the viewer are drawn over the whole
            # body, the others (behind the limb) not at all; a triangle's outward side is the side
            # of the body normal nearest to it
            keep &= (_outward(T, body_v, body_f) @ d) < 0.15
        layers.append((T[keep], face_rgba[keep]))
    for T, C in layers:
        if not len(T):
            continue
        order = np.argsort(-(T.mean(1) @ d), kind="stable")   # far first
        xy = np.stack([T @ r, T @ u], axis=-1)[order]
        ax.add_collection(PolyCollection(xy, facecolors=C[order], edgecolors=C[order], linewidths=0.15))
    pts = pos.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    if len(pts):   # the garment and a margin round it (the body is cropped to about that)
        x, y = pts @ r, pts @ u
        pad = 0.12 * max(np.ptp(x), np.ptp(y), 1e-3)
        ax.set_xlim(x.min() - pad, x.max() + pad)
        ax.set_ylim(y.min() - pad, y.max() + pad)
        cx, cy = 0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max())
    else:
        cx = cy = 0.0
    ax.set_aspect("equal", adjustable="box")
    placed = []   # label anchors already used [points from the axes' origin]
    for p in sorted(probes, key=lambda q: -float(np.asarray(q["center"], float) @ u)):
        c = np.asarray(p["center"], float)
        px, py = c @ r, c @ u
        behind = _faces_away(c, p["radius_m"], d, body_v, body_f)
        ax.add_patch(Circle((px, py), p["radius_m"], fill=False, lw=1.6, ec="0.35" if behind else "black",
                            ls="--" if behind else "-", zorder=5))
        ax.plot([px], [py], "o", ms=3, color="black", zorder=6)
        label = f"{p['name']} {p['pressure_mmhg']:.1f} mmHg" + (" (behind)" if behind else "")
        right = px < cx   # the label towards the middle of the view, inside the axes
        dx, dy = (10 if right else -10), (-14 if py > cy else 10)
        at = ax.transData.transform((px, py)) * 72.0 / ax.figure.dpi
        while any(abs(at[0] + dx - x) < 110 and abs(at[1] + dy - y) < 13 for x, y in placed):
            dy -= 14   # below the label it would cover
        placed.append((at[0] + dx, at[1] + dy))
        ax.annotate(label, (px, py), xytext=(dx, dy), textcoords="offset points", ha="left" if right else "right",
                    fontsize=8, zorder=7, bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.5", "alpha": 0.9},
                    annotation_clip=False, **PLAIN)
    title = {"front": "front (from -y)", "top": "top (from +z)"}.get(name, f"side (from {name[-2:]})")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(AXIS_NAMES[tuple(int(a) for a in r)], fontsize=9)
    ax.set_ylabel(AXIS_NAMES[tuple(int(a) for a in u)], fontsize=9)
    ax.tick_params(labelsize=8)
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(4))
    ax.yaxis.set_major_locator(MaxNLocator(6))


def map_png(pos, faces, values, label: str, cmap: str, scale: dict, body_v=None, body_f=None,
            probes=()) -> bytes:
    """One PNG: the three views of a node field with the body, and its colour bar (the scale's
    ticks, its top the scale's maximum; a triangle at the top when nodes exceed it)."""
    Figure = _mpl()
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    cm = colormaps[cmap]
    norm = Normalize(scale["lo"], scale["hi"], clip=True)
    v = np.asarray(values, float).reshape(-1)
    with np.errstate(invalid="ignore"):
        fv = np.nanmean(np.where(np.isfinite(v), v, np.nan)[faces], axis=1) if len(faces) else np.zeros(0)
    fv = np.where(np.isnan(fv), scale["hi"], fv)
    rgba = cm(norm(fv))
    centre = pos.reshape(-1, 3).mean(0) if pos.size else np.zeros(3)
    names = ("front", side_view([p["center"] for p in probes], centre), "top")
    P = pos.reshape(-1, 3)
    P = P[np.isfinite(P).all(1)]
    aspect = 1.0
    for name in names:
        _, r, u = _view_dirs(name)
        if len(P):
            aspect = max(aspect, np.ptp(P @ u) / max(np.ptp(P @ r), 1e-9))
    fig = Figure(figsize=(13.0, float(np.clip(2.9 * aspect + 1.2, 4.0, 9.0))), dpi=100, layout="constrained")
    gs = fig.add_gridspec(1, 4, width_ratios=[1, 1, 1, 0.07])
    for k, name in enumerate(names):
        draw_view(fig.add_subplot(gs[0, k]), name, pos.reshape(-1, 3), faces, rgba, body_v, body_f, probes)
    cax = fig.add_subplot(gs[0, 3])
    extend = "max" if scale["above"] else "neither"
    bar = fig.colorbar(ScalarMappable(norm=Normalize(scale["lo"], scale["hi"]), cmap=cm), cax=cax, extend=extend)
    bar.set_ticks(scale["ticks"])
    bar.set_ticklabels([format(t, "g") for t in scale["ticks"]])
    bar.ax.tick_params(labelsize=11)
    bar.set_label(label, fontsize=11)
    return png_bytes(fig)


def profile_png(profiles: list[dict], band: dict | None, levels: list[dict] | None, title: str = "",
                b_mmhg: float | None = None, no_b: bool = False) -> bytes:
    """Two panels: the girth-mean pressure [mmHg] against height (the min-max band shaded, the
    class band of the classed probe as a grey stripe, the levels as labelled points) and each
    reading as a percentage of ``b_mmhg`` (the girth mean at B; default the lowest slice's): the
    gradient. ``no_b``: the levels have no B (an arm): the gradient panel says so, empty."""
    Figure = _mpl()
    fig = Figure(figsize=(10.0, 4.8), dpi=100, layout="constrained")
    ax, ag = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    top = 0.0
    if band:
        hi = band["max"] if band["max"] is not None else band["min"] * 1.25
        ax.axvspan(band["min"], hi, color="0.6", alpha=0.25, label=band["label"])
        top = hi
    for pf in profiles:
        on = [s for s in pf["slices"] if s["mean_mmhg"] is not None]
        if not on:
            continue
        h = np.array([s["height_m"] for s in on])
        m = np.array([s["mean_mmhg"] for s in on])
        line, = ax.plot(m, h, "o-", ms=3, label=f"{pf['name']}: girth mean")
        lo = [s["min_mmhg"] if s["min_mmhg"] is not None else s["mean_mmhg"] for s in on]
        hi = [s["max_mmhg"] if s["max_mmhg"] is not None else s["mean_mmhg"] for s in on]
        ax.fill_betweenx(h, lo, hi, color=line.get_color(), alpha=0.15, label=f"{pf['name']}: least to greatest")
        top = max(top, float(np.max(hi)))
        ref = b_mmhg if b_mmhg else m[0]
        if ref > 0 and not no_b:
            ag.plot(100.0 * m / ref, h, "o-", ms=3, color=line.get_color(), label=f"{pf['name']}: % of B")
    if levels:
        def at(x):   # where the level sits on the profile's axis (levels.csv's z, else its height)
            return x["z"] if x.get("z") is not None else x.get("height")

        lv = [x for x in levels if x.get("mean") is not None and at(x) is not None]
        if lv:
            ax.plot([x["mean"] for x in lv], [at(x) for x in lv], "s", color="black", ms=5, label="levels")
            for x in lv:
                ax.annotate(str(x["level"]), (x["mean"], at(x)), xytext=(5, -3), textcoords="offset points",
                            fontsize=8, **PLAIN)
                top = max(top, x["mean"])
            b = b_mmhg or lv[0]["mean"]
            if b > 0 and not no_b:
                ag.plot([100.0 * x["mean"] / b for x in lv], [at(x) for x in lv], "s-", color="black", ms=5,
                        label="levels: % of B")
    ax.set_xlim(0.0, 1.1 * top if top > 0 else 1.0)
    ax.set_xlabel("contact pressure [mmHg]")
    ax.set_ylabel("height [m]")
    ax.set_title(title or "pressure profile", **PLAIN)
    ag.axvline(100.0, color="0.5", lw=0.8)
    ag.set_xlim(0.0, max(110.0, ag.get_xlim()[1]))
    ag.set_xlabel("girth mean as % of B")
    ag.set_ylabel("height [m]")
    ag.set_title("gradient: no level B" if no_b else "gradient")
    for a in (ax, ag):
        a.grid(True, alpha=0.3)
        if a.get_legend_handles_labels()[0]:
            plain_legend(a, fontsize=8, loc="best")
    return png_bytes(fig)


def materials_png(materials: list[dict], reached: dict) -> bytes:
    """Tension [N/m] against strain [%] of each material table, the strain range the run reached
    in that direction (``reached``: {'warp': (least, greatest)}) shaded on its curve."""
    Figure = _mpl()
    fig = Figure(figsize=(6.4, 4.2), dpi=100, layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    for m in materials:
        x, y = np.asarray(m["strain"], float), np.asarray(m["tension_n_per_m"], float)
        line, = ax.plot(100.0 * x, y, "o-", ms=3, label=f"{m['direction']}")
        lo_hi = reached.get(str(m["direction"]).split()[0])
        if lo_hi is not None and lo_hi[1] > 0:
            a, b = max(0.0, lo_hi[0]), lo_hi[1]
            xs = np.linspace(a, b, 50)
            ax.plot(100.0 * xs, np.interp(xs, x, y), "-", lw=6, alpha=0.35, color=line.get_color())
            ax.plot([100.0 * b], [np.interp(b, x, y)], "D", ms=7, color=line.get_color(),
                    label=f"{m['direction']}: greatest strain in this run, {100 * b:.1f} %")
    ax.set_xlabel("strain [%]")
    ax.set_ylabel("tension [N/m]")
    ax.set_title("material curves (tension per width)")
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        plain_legend(ax, fontsize=8)
    return png_bytes(fig)


def convergence_png(history) -> bytes | None:
    """Residual against iteration (log scale); None without a history. A long run is thinned to
    about 10,000 points."""
    if history is None:
        return None
    Figure = _mpl()
    it, res = history
    if it.size > 20_000:
        keep = np.unique(np.r_[np.arange(0, it.size, it.size // 10_000), it.size - 1])
        it, res = it[keep], res[keep]
    fig = Figure(figsize=(6.0, 3.6), dpi=90, layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    ax.semilogy(it, np.maximum(res, 1e-300), "-o", ms=2)
    ax.set_xlabel("iteration")
    ax.set_ylabel("residual ||V||inf [N]")
    ax.set_title("convergence")
    ax.grid(True, which="both", alpha=0.3)
    return png_bytes(fig)
