"""Pressure probes and profiles read from an equilibrium.

Both read the per-node contact pressure p_i [Pa] (:func:`clothsim.pressure.contact_reaction`:
normal reaction over deformed tributary area) and the contact flags c_i, interpolated linearly
over the deformed sheet's display triangles (``model.topology.faces``).

**Probe** (a sensor disc): the disc is the set of mold points within ``radius`` of the probe's
centre, the mold point closest to the probe's ``point``; distances are straight (3D, chord)
distances between mold points. On a limb of radius R a chord is shorter than the arc by about
s^3 / (24 R^2), so on a 5 cm limb a 1 cm disc holds about 0.1 % more surface than pi radius^2.
A point of the sheet belongs to the disc when its closest mold point does. The probe reads

    pressure = (integral of p over the sheet inside the disc) / (pi radius^2)  [Pa]

which is the total normal force the sensor feels over its area (a sheet that covers half the disc
reads half). ``contact_fraction`` is the sheet area in contact inside the disc over pi radius^2
(1: the disc is covered and pressed everywhere). The integral is evaluated on the triangles near
the disc, each split into k^2 sub-triangles (k so that a sub-triangle is about radius / 60 wide),
so the disc's outline is resolved well below the node spacing.

**Profile** (slices along an axis): at each height h the plane axis . x = h cuts the deformed
sheet into segments; along them p, c and the on-body flag b are interpolated linearly. A node is
*on the body* when it is in contact or lies within ``ON_BODY_GAP_M`` (0.5 mm) of the mold (its
signed distance <= 0.5 mm): a stretch of fabric lying on a flat of the body presses with no
reaction (Laplace: zero curvature, zero pressure) and is left out of the contact set, but a tape
round the limb measures it and a sensor under it reads zero. Per slice:

- girth [m] (``girth_m``): the integral of b along the cut, the fabric's length on the body;
- girth mean (``girth_mean_pa``, ``girth_mean_mmhg``): the integral of p along the cut over the
  girth, what a tape-and-sensor engineer averages round the limb (nodes on the body without
  reaction count at zero). This is the profile's reported statistic: the plot and the gradient
  check read it;
- contact length (``contact_length_m``, the integral of c along the cut) [m] and the contact mean
  (``mean_pa``, ``mean_mmhg``: the integral of p over the contact length), as before; where every
  node on the body is in contact (a tube on a cylinder or any convex section it presses all round)
  the two means are equal;
- the least and greatest pressure at the cut's points in contact (c >= 0.5).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from ..plottext import PLAIN, plain_legend
from ..pressure import MMHG, SensorDisc, finite_pressure, mold_closest
from ..records import ProbeReading


#: a probe whose disc is wider than this share of the sheet's largest extent says it is no local reading
PROBE_SPAN_WARN = 1.0

#: a node within this distance of the mold [m] is on the body (in a profile's girth) even without reaction
ON_BODY_GAP_M = 0.5e-3


def read_probe(model, positions: np.ndarray, in_contact: np.ndarray, pressure: np.ndarray, probe) -> dict:
    """One probe's reading (see the module docstring). positions (N, 3) [m], in_contact (N,)
    bool, pressure (N,) [Pa]. Returns name, point, centre [m] (on the mold), offset_m (point to
    mold), radius_m, force_n, pressure_pa, pressure_mmhg, contact_fraction, on_contact (bool)
    and a note."""
    r = float(probe.radius)
    out = {"name": probe.name, "point": [float(x) for x in probe.point], "radius_m": r}
    if model.mold is None:
        out.update(center=None, offset_m=math.nan, force_n=0.0, pressure_pa=0.0, pressure_mmhg=0.0,
                   contact_fraction=0.0, on_contact=False, note="no mold: nothing to press on")
        return ProbeReading(**out).to_dict()
    cp, sd = mold_closest(model.mold, np.asarray(probe.point, float)[None])
    centre = cp[0]
    out["center"] = [float(x) for x in centre]
    out["offset_m"] = float(abs(sd[0]))
    gathered = int((~np.isfinite(np.asarray(pressure, float))).sum())
    sensor = SensorDisc(r)
    force, contact_area = sensor.on_mold(model, positions, in_contact, pressure, centre)
    disc = sensor.area_m2
    pa = force / disc
    frac = min(1.0, contact_area / disc)
    on = bool(force > 0.0)
    note = "" if on else "off contact: no sheet presses on this disc"
    if on and frac < 0.999:
        note = f"partly in contact: {frac:.0%} of the disc is pressed"
    if gathered and on:
        note = (note + "; " if note else "") + f"{gathered} gathered node(s) of the sheet (line loads) left out"
    if out["offset_m"] > r:
        note = (note + "; " if note else "") + f"the point is {out['offset_m'] * 1e3:.3g} mm off the mold"
    across = float(np.ptp(np.asarray(positions, float).reshape(-1, 3), axis=0).max())
    if 2.0 * r > PROBE_SPAN_WARN * across:
        # a sensor as big as the garment (a radius typed in mm as m, 10 for 0.01) averages the
        # whole garment's force over a disc it does not cover: not a local pressure
        note = (note + "; " if note else "") + (f"the disc ({2 * r:.3g} m across) is wider than the sheet "
                                                f"({across:.3g} m across): not a local reading (radius in metres?)")
    out.update(force_n=force, pressure_pa=pa, pressure_mmhg=pa / MMHG, contact_fraction=frac, on_contact=on,
               note=note)
    return ProbeReading(**out).to_dict()


def _cut(X: np.ndarray, faces: np.ndarray, d: np.ndarray, vals: list[np.ndarray]):
    """Segments where the plane d = 0 cuts the triangles (d (N,) signed heights; d >= 0 counts as
    above, so a vertex on the plane is cut once; a plane through the sheet's lowest edge, which
    then cuts nothing, counts d > 0 as above). Returns (ends (S, 2, 3), [v at ends (S, 2)])."""
    above = d[faces] >= 0.0                                         # (F, 3)
    cut = above.any(axis=1) & ~above.all(axis=1)
    if not cut.any():
        above = d[faces] > 0.0
        cut = above.any(axis=1) & ~above.all(axis=1)
    f = faces[cut]
    a = above[cut]
    pts, vv = [], [[] for _ in vals]
    for e0, e1 in ((0, 1), (1, 2), (2, 0)):
        cross = a[:, e0] != a[:, e1]
        u, w = f[:, e0], f[:, e1]
        du, dw = d[u], d[w]
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(cross, du / np.where(cross, du - dw, 1.0), 0.0)
        pts.append((X[u] + t[:, None] * (X[w] - X[u]), cross))
        for n, v in enumerate(vals):
            vv[n].append(v[u] + t * (v[w] - v[u]))
    # every cut triangle has exactly two crossing edges: take them in edge order
    P = np.stack([q for q, _ in pts], 1)                            # (S, 3 edges, 3)
    C = np.stack([c for _, c in pts], 1)                            # (S, 3)
    order = np.argsort(~C, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(f))[:, None]
    ends = P[rows, order]
    vals_out = [np.stack(v, 1)[rows, order] for v in vv]
    return ends, vals_out


def on_body(model, positions: np.ndarray, in_contact: np.ndarray, gap: float = ON_BODY_GAP_M) -> np.ndarray:
    """(N,) bool: the nodes in contact or within ``gap`` [m] of the mold (signed distance <= gap,
    so a node inside the mold counts too). Without a mold: the contact flags."""
    c = np.asarray(in_contact, bool)
    if model.mold is None:
        return c.copy()
    _, sd = mold_closest(model.mold, np.asarray(positions, float))
    return c | (sd <= gap)


def read_profile(model, positions: np.ndarray, in_contact: np.ndarray, pressure: np.ndarray, profile) -> dict:
    """One profile (see the module docstring): {name, axis, slices: [{height_m, girth_m,
    girth_mean_pa, girth_mean_mmhg, contact_length_m, mean_pa, mean_mmhg, min_mmhg, max_mmhg}],
    gradient: {...}} (the gradient of the girth mean). Slices without contact have contact length
    0 and pressures None (girth_m is still the fabric's length on the body there)."""
    axis = np.asarray(profile.unit_axis(), float)
    X = np.asarray(positions, float)
    p, _ = finite_pressure(np.asarray(pressure, float))
    c = np.asarray(in_contact, float)
    b = on_body(model, X, in_contact).astype(float)
    faces = model.topology.faces
    hx = X @ axis
    slices = []
    for h in profile.heights():
        ends, (pe, ce, be) = _cut(X, faces, hx - h, [p, c, b])
        seg = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        clen = float((seg * ce.mean(axis=1)).sum())
        girth = float((seg * be.mean(axis=1)).sum())
        row = {"height_m": float(h), "girth_m": girth, "girth_mean_pa": None, "girth_mean_mmhg": None,
               "contact_length_m": clen, "mean_pa": None, "mean_mmhg": None, "min_mmhg": None, "max_mmhg": None}
        if clen > 0.0:
            force = float((seg * pe.mean(axis=1)).sum())       # the integral of p round the slice [N/m]
            mean = force / clen
            on = ce >= 0.5
            row.update(girth_mean_pa=force / girth, girth_mean_mmhg=force / girth / MMHG,
                       mean_pa=mean, mean_mmhg=mean / MMHG,
                       min_mmhg=float(pe[on].min()) / MMHG if on.any() else None,
                       max_mmhg=float(pe[on].max()) / MMHG if on.any() else None)
        slices.append(row)
    return {"name": profile.name, "axis": [float(a) for a in axis], "slices": slices,
            "gradient": gradient_check(slices, profile.steady_tolerance_mmhg)}


def reported_mmhg(s: dict) -> float | None:
    """A slice's reported pressure [mmHg]: its girth mean; a summary written before the girth mean
    existed (its slices have only the contact mean, ``mean_mmhg``) reads its contact mean."""
    return s["girth_mean_mmhg"] if "girth_mean_mmhg" in s else s["mean_mmhg"]


def gradient_check(slices: list[dict], tolerance_mmhg: float = 0.1) -> dict:
    """Ankle (first slice in contact) to calf (last): does the reported pressure (the girth mean,
    :func:`reported_mmhg`) fall steadily (no rise above ``tolerance_mmhg`` from one slice to the
    next), and by how much?"""
    on = [s for s in slices if reported_mmhg(s) is not None]
    if len(on) < 2:
        return {"falls_steadily": None, "note": "fewer than two slices in contact: no gradient to check"}
    m = np.array([reported_mmhg(s) for s in on])
    rises = np.diff(m)
    worst = int(np.argmax(rises))
    steady = bool(rises.max() <= tolerance_mmhg and m[0] - m[-1] > tolerance_mmhg)
    out = {
        "from_height_m": on[0]["height_m"], "to_height_m": on[-1]["height_m"],
        "from_mmhg": float(m[0]), "to_mmhg": float(m[-1]),
        "drop_mmhg": float(m[0] - m[-1]),
        "drop_percent": float(100.0 * (m[0] - m[-1]) / m[0]) if m[0] > 0 else None,
        "largest_rise_mmhg": float(max(0.0, rises.max())),
        "falls_steadily": steady,
    }
    if steady:
        out["note"] = (f"falls steadily from {m[0]:.1f} to {m[-1]:.1f} mmHg "
                       f"({out['drop_percent']:.0f} % lower at {on[-1]['height_m']:.3g} m)")
    elif m[-1] - m[0] > tolerance_mmhg:
        out["note"] = (f"rises from {m[0]:.1f} mmHg at {on[0]['height_m']:.3g} m to {m[-1]:.1f} mmHg at "
                       f"{on[-1]['height_m']:.3g} m: not graduated")
    elif rises.max() <= tolerance_mmhg:
        out["note"] = f"does not fall: {m[0]:.1f} mmHg at {on[0]['height_m']:.3g} m, {m[-1]:.1f} mmHg at {on[-1]['height_m']:.3g} m"
    else:
        out["note"] = (f"does not fall steadily: rises by {rises[worst]:.2f} mmHg between "
                       f"{on[worst]['height_m']:.3g} m and {on[worst + 1]['height_m']:.3g} m")
    return out


#: the class of a probe with no contact under its disc
NO_READING = "no reading (no contact under the probe)"


def probes_csv(readings: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["name", "x_m", "y_m", "z_m", "radius_m", "force_N", "pressure_Pa", "pressure_mmHg",
                "contact_fraction", "on_contact", "classes", "note"])
    for r in readings:
        c = r.get("center") or r["point"]
        cls = "; ".join(f"{k}: {v}" for k, v in r.get("classes", {}).items())
        w.writerow([r["name"], *(f"{x:.6g}" for x in c), f"{r['radius_m']:.6g}", f"{r['force_n']:.6g}",
                    f"{r['pressure_pa']:.6g}", f"{r['pressure_mmhg']:.4f}", f"{r['contact_fraction']:.4f}",
                    int(r["on_contact"]), cls, r["note"]])
    return buf.getvalue()


def profiles_csv(profiles: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    # the first seven columns as before (mean_* the contact mean); the girth and its mean follow
    w.writerow(["profile", "height_m", "contact_length_m", "mean_Pa", "mean_mmHg", "min_mmHg", "max_mmHg",
                "girth_m", "girth_mean_Pa", "girth_mean_mmHg"])
    f = lambda v, fmt: "" if v is None else format(v, fmt)  # noqa: E731
    for pf in profiles:
        for s in pf["slices"]:
            w.writerow([pf["name"], f"{s['height_m']:.6g}", f"{s['contact_length_m']:.6g}", f(s["mean_pa"], ".6g"),
                        f(s["mean_mmhg"], ".4f"), f(s["min_mmhg"], ".4f"), f(s["max_mmhg"], ".4f"),
                        f(s.get("girth_m"), ".6g"), f(s.get("girth_mean_pa"), ".6g"),
                        f(s.get("girth_mean_mmhg"), ".4f")])
    return buf.getvalue()


def profile_png(profiles: list[dict], title: str = "") -> bytes:
    """A PNG (matplotlib, Agg): the reported pressure [mmHg] (x: the girth mean, :func:`reported_mmhg`)
    against height [m] (y) per profile, the band from the least to the greatest pressure in contact shaded; the pressure axis runs from 0 to 1.1 x
    the greatest reading. The title and the profiles' names are drawn as written (never as
    mathtext: clothsim.plottext)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0, 4.5), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    top = 0.0  # the greatest reading drawn [mmHg]
    for pf in profiles:
        on = [s for s in pf["slices"] if reported_mmhg(s) is not None]
        if not on:
            continue
        h = [s["height_m"] for s in on]
        m = [reported_mmhg(s) for s in on]
        what = "girth mean" if "girth_mean_mmhg" in on[0] else "mean"
        line, = ax.plot(m, h, "o-", ms=3, label=f"{pf['name']} ({what})")
        ax.fill_betweenx(h, [s["min_mmhg"] if s["min_mmhg"] is not None else v for s, v in zip(on, m)],
                         [s["max_mmhg"] if s["max_mmhg"] is not None else v for s, v in zip(on, m)],
                         color=line.get_color(), alpha=0.2, label=f"{pf['name']} (min-max)")
        top = max(top, *m, *(v for s in on for v in (s["min_mmhg"], s["max_mmhg"]) if v is not None))
    # from 0 with 10 % headroom past the greatest reading: a uniform profile (a vertical line) is
    # drawn inside the axes, not on their right edge
    ax.set_xlim(0.0, 1.1 * top if top > 0 else 1.0)
    ax.ticklabel_format(axis="x", useOffset=False)
    ax.set_xlabel("contact pressure [mmHg]")
    ax.set_ylabel("height along the axis [m]")
    ax.set_title(title or "pressure profile", **PLAIN)   # names are user text, never mathtext
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:  # no slice in contact: nothing to label
        plain_legend(ax, fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()
