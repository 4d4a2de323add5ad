"""The report's page: HTML around the figures of :mod:`.report_figures`, from the numbers the
folder holds (summary.json, result.npz, levels.csv) and nothing else. Every string is
HTML-escaped (:func:`_t`); every number was checked to be a number when it was read
(:func:`clothsim.compression.report.check_summary`, ``check_scene_summary``, ``read_levels``)."""

from __future__ import annotations

import base64
import html
import math
import warnings
from datetime import datetime, timezone

import numpy as np

from ..records import field_rows, format_value
from ..version import __version__
from . import report_figures as rf
from .report_levels import SIDES, classify_with, levels_from_profiles

STYLE = ("body{font-family:sans-serif;margin:1.5em;max-width:1320px;color:#222}table{border-collapse:collapse;"
         "margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:left;font-size:14px}"
         "td.n{text-align:right;font-variant-numeric:tabular-nums}img{max-width:100%}figure{margin:.5em 0}"
         "figcaption{font-size:13px;color:#444;max-width:1100px}.missing{color:#a00}"
         "#headline{display:flex;flex-wrap:wrap;gap:10px;margin:1em 0}#headline div{border:1px solid #bbb;"
         "border-radius:6px;padding:8px 12px;min-width:170px}#headline b{font-size:22px;display:block}"
         "#headline span.k{font-size:12px;color:#555}ul{margin:.3em 0}small{color:#555}")


def _t(v) -> str:
    """Any value as HTML text: str() of it, escaped (quotes too: safe in attributes)."""
    return html.escape(str(v), quote=True)


def _num(v, fmt: str) -> str:
    """v (a number or None) formatted with fmt, or "n/a" when it is missing or not finite."""
    if v is None or not isinstance(v, (int, float)) or not math.isfinite(v):
        return "n/a"
    return format(v, fmt)


def _count(v) -> str:
    return "n/a" if v is None else str(v)


class _Missing(str):
    """The note of a figure that could not be drawn (a str: what the page shows instead)."""


def _figure(what: str, draw, *args):
    """draw(*args), or a _Missing note with a warning when the figure cannot be drawn (any error:
    the report is still written, with the note in the figure's place)."""
    from ..plottext import failure

    try:
        return draw(*args)
    except Exception as exc:  # noqa: BLE001
        msg = f"{what} not drawn ({failure(exc)})"
        warnings.warn(f"report: {msg}", stacklevel=2)
        return _Missing(msg)


def _img(png: bytes | _Missing, alt: str, cls: str = "") -> str:
    if isinstance(png, _Missing):
        return f"<p class='missing'>{_t(png)}</p>"
    c = f' class="{cls}"' if cls else ""
    return f'<img{c} alt="{_t(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'


def _probe_points(s: dict) -> list[dict]:
    return [{"name": p["name"], "center": p.get("center") or p["point"], "radius_m": p["radius_m"],
             "pressure_mmhg": p["pressure_mmhg"]} for p in s.get("probes") or []]


def _class_band(s: dict, scene: dict) -> dict | None:
    """{min, max, label} of the class the classed probe reads under the first standard."""
    cl = s.get("classes") or {}
    results = cl.get("results") or []
    for r in results:
        for st in scene.get("standards") or []:
            if st.get("name") != r.get("standard"):
                continue
            for c in st.get("classes") or []:
                if r.get("class") == f"class {c['name']}":
                    hi = "and more" if c["max"] is None else f"{c['max']:g}"
                    return {"min": c["min"], "max": c["max"],
                            "label": f"{st['name']} class {c['name']}: {c['min']:g}-{hi} mmHg"}
    return None


def _levels(s, f, levels):
    """(rows, from_file): levels.csv's rows, or rows from the profiles (report_levels); the row
    that is B marked ``b`` (levels.csv: the level named B, none without one, as on an arm; the
    profile: the slice nearest the classed probe's height, else the lowest)."""
    if levels:
        rows, from_file = levels, True
        b = next((r for r in rows if str(r.get("level") or "").strip().upper() == "B"), None)
    elif s.get("profiles"):
        rows, from_file = levels_from_profiles(s["profiles"], f.body_v, f.body_f, f.pos, f.faces), False
        probes = {p["name"]: p for p in s.get("probes") or []}
        p = probes.get((s.get("classes") or {}).get("probe"))
        b = None
        if p is not None and rows:
            axis = np.asarray(s["profiles"][0].get("axis") or (0, 0, 1), float)
            h = float(np.asarray(p.get("center") or p["point"], float) @ (axis / np.linalg.norm(axis)))
            b = min(rows, key=lambda r: abs(r["height"] - h))
    else:
        return [], False
    rows = [r for r in rows]
    if b is None and not from_file:   # levels.csv without a level B (an arm) has no B
        b = next((r for r in rows if r.get("mean") is not None), None)
    for r in rows:
        r["b"] = r is b
    return rows, from_file


def levels_table(rows: list[dict], from_file: bool, standards: list[dict]) -> str:
    b = next((r["mean"] for r in rows if r.get("b")), None)
    head = ["level", "height [m]", "body girth [cm]", "reduction [%]", "girth mean [mmHg]"]
    head += [f"{x} [mmHg]" for x in SIDES] if from_file else ["least [mmHg]", "greatest [mmHg]"]
    head += ["% of B", "class (at B)"]
    out = ["<table id='levels'><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"]
    for r in rows:
        g = r.get("girth")
        cells = [f"<td>{_t(r.get('level') or '')}</td>", f"<td class='n'>{_num(r.get('height'), '.3f')}</td>",
                 f"<td class='n'>{_num(None if g is None else 100 * g, '.1f')}</td>",
                 f"<td class='n'>{_num(r.get('reduction'), '.1f')}</td>",
                 f"<td class='n mean'>{_num(r.get('mean'), '.1f')}</td>"]
        keys = SIDES if from_file else ("min", "max")
        cells += [f"<td class='n'>{_num(r.get(k), '.1f')}</td>" for k in keys]
        pct = None if b in (None, 0) or r.get("mean") is None else 100.0 * r["mean"] / b
        cells.append(f"<td class='n'>{_num(pct, '.0f')}</td>")
        cls = ""
        if r.get("b") and r.get("mean") is not None and standards:
            try:
                cls = "B: " + "<br>".join(f"{_t(n)}: {_t(c)}" for n, c in classify_with(r["mean"], standards))
            except Exception:  # noqa: BLE001 (a class table that is not one: no class shown)
                cls = "n/a"
        cells.append(f"<td>{cls}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    src = ("from levels.csv (the measuring levels on the body: girth, the garment's reduction, the girth mean "
           "and the four sides)" if from_file else
           "from the profile's slices (no levels.csv in the folder): the body's girth there (the convex hull of "
           "its section, as a tape measures it) and the girth mean, least and greatest pressure round it")
    if not any(r.get("b") for r in rows):
        about_b = ("This body has no level B (an arm's levels are named otherwise), so no class and no percentage "
                   "of B is given.")
    else:
        about_b = ("A compression class is specified at B (levels.csv's level B, or the slice at the classed "
                   "probe's height); every level is given as a percentage of B" +
                   (" (B has no reading here: no contact at its height)." if b is None else "."))
    return out[0] + "".join(out[1:]) + f"<p><small>Per level, {src}. {about_b}</small></p>"


def summary_table(s: dict) -> str:
    """Every number and word of summary.json the field list (clothsim.records) names, with its
    unit: the run's, the diagnostics', the friction report's (friction.KEY) and each stage's
    (stage:NAME.KEY); the probes have their own table."""
    rows = ["<table id='summary'><tr><th>output</th><th>value</th><th>unit</th><th>meaning</th></tr>"]
    rows += [f"<tr id='summary-{_t(name)}'><td><code>{_t(name)}</code></td><td>{_t(format_value(v))}</td>"
             f"<td>{_t(f.unit)}</td><td>{_t(f.doc)}</td></tr>"
             for f, name, v in field_rows(s) if not name.startswith("probe:")]
    return "\n".join(rows + ["</table>"])


def probes_table(probes: list[dict]) -> str:
    rows = ["<table id='probes'><tr><th>probe</th><th>centre [m]</th><th>radius [mm]</th><th>pressure [mmHg]</th>"
            "<th>pressure [Pa]</th><th>contact fraction</th><th>classes</th><th>note</th></tr>"]
    for p in probes:
        c = p.get("center") or p["point"]
        cls = "<br>".join(f"{_t(k)}: {_t(v)}" for k, v in (p.get("classes") or {}).items()) or "-"
        rows.append(
            f"<tr><td>{_t(p['name'])}</td><td>({c[0]:.4f}, {c[1]:.4f}, {c[2]:.4f})</td>"
            f"<td>{p['radius_m'] * 1e3:.1f}</td><td class='mmhg'>{p['pressure_mmhg']:.2f}</td>"
            f"<td class='pa'>{p['pressure_pa']:.1f}</td><td class='frac'>{p['contact_fraction']:.3f}</td>"
            f"<td>{cls}</td><td>{_t(p.get('note', ''))}</td></tr>")
    rows.append("</table>")
    return "\n".join(rows)


def _headline(s: dict, rows: list[dict], from_file: bool) -> str:
    """The key figures: the classed probe and its class, the girth mean at B, the gradient, the
    greatest sensor-disc reading and (for reference) the single-node peak."""
    box = []

    def add(key, value, note=""):
        box.append(f"<div><span class='k'>{key}</span><b>{value}</b><small>{note}</small></div>")

    cl = s.get("classes") or {}
    probes = {p["name"]: p for p in s.get("probes") or []}
    if cl:
        p = probes.get(cl.get("probe"))
        r = f" (sensor disc, {p['radius_m'] * 1e3:.0f} mm radius)" if p else ""
        add(f"probe {_t(cl.get('probe'))}{r}", f"<span id='class-reading'>{cl['pressure_mmhg']:.1f}</span> mmHg",
            "<br>".join(f"{_t(x.get('standard'))}: {_t(x.get('class'))}" for x in cl.get("results") or []))
    for name, p in probes.items():
        if name != cl.get("probe"):
            add(f"probe {_t(name)}", f"{p['pressure_mmhg']:.1f} mmHg", f"contact fraction {p['contact_fraction']:.2f}")
    on = [r for r in rows if r.get("mean") is not None]
    b = next((r for r in on if r.get("b")), None)
    b_row = next((r for r in rows if r.get("b")), None)
    if b_row is not None and b is None:   # a level B without a reading (no contact there)
        add(f"girth mean at {_t(b_row.get('level') or 'B')}", "<span id='girth-mean-b'>no reading</span>",
            "no contact at its height: no class, no % of B")
    elif b is not None:
        last = on[-1]
        add(f"girth mean at {_t(b['level'])}" if from_file else f"girth mean at B, {b['height']:.3f} m",
            f"<span id='girth-mean-b'>{b['mean']:.1f}</span> mmHg",
            "the pressure averaged round the limb" + ("" if not from_file else " (levels.csv)"))
        if last is not b and b["mean"] > 0:
            add("gradient", f"{100.0 * last['mean'] / b['mean']:.0f} % of B",
                f"at {_t(last['level'])}" if from_file else f"at {last['height']:.3f} m")
    elif on:   # levels without a B (an arm): the first level's girth mean, no class, no % of B
        add(f"girth mean at {_t(on[0]['level'])}", f"<span id='girth-mean-first'>{on[0]['mean']:.1f}</span> mmHg",
            "the pressure averaged round the limb (levels.csv); no level B: no class, no % of B")
    if s.get("max_sensor_pressure_mmhg") is not None:
        add(f"greatest sensor reading (disc {1e3 * (s.get('sensor_radius_m') or 0):.0f} mm radius)",
            f"{_num(s.get('max_sensor_pressure_mmhg'), '.1f')} mmHg", "anywhere on the garment")
    peak = s.get("max_contact_pressure_mmhg")
    add("single-node peak", f"<span id='peak'>{_num(peak, '.2f')}</span> mmHg" if peak is not None else
        "<span id='peak'>none</span>", "one lattice node: not what a sensor reads" if peak is not None else
        _t(s.get("contact_pressure_note", "")))
    return "<div id='headline'>" + "".join(box) + "</div>"


def _frictional(scene: dict) -> bool:
    """Whether the scene in short has friction anywhere (mold.friction or a region above 0)."""
    return (scene.get("friction_mu") or 0.0) > 0 or any(r["friction"] > 0 for r in scene.get("friction_regions") or [])


def _regions_text(scene: dict) -> str:
    """The friction regions in words ("" without): "; mu = 1.2 on panel front, j 90% to 100%"."""
    return "".join(f"; mu = {r['friction']:g} on {_t(r['nodes'])}" for r in scene.get("friction_regions") or [])


def _assumptions(scene: dict, s: dict) -> str:
    mu = scene.get("friction_mu") or 0.0
    stages = scene.get("stages") or []
    frictional = _frictional(scene)
    fr = (f"Friction: Coulomb, mu = {mu:g} between garment and skin{_regions_text(scene)}, on the loading path "
          f"of the stages below (a result with friction depends on how the garment was put on)." if frictional else
          "No friction: the garment slides freely on the body; what holds it along the limb are the held rows "
          "(constraints).")
    items = [
        "Resting pressure on a rigid body: the body does not deform under the garment; the pressure is the "
        "normal contact force per area of the garment at equilibrium (quasi-static, no motion).",
        "The fabric is a membrane in tension only: warp and weft springs follow the tension-strain tables below "
        "and resist no compression; no bending stiffness.",
        fr,
        "Probes read as a sensor does: the normal force on the disc divided by its area; the girth mean is the "
        "pressure averaged along the cut round the limb.",
    ]
    if stages:
        items.append("Loading path: " + "; ".join(_t(x) for x in stages) + ".")
    return "<ul id='assumptions'>" + "".join(f"<li>{x}</li>" for x in items) + "</ul>"


def _scene_summary(scene: dict) -> str:
    mats = ", ".join(f"{_t(m.get('direction'))} ({len(m.get('strain') or [])} points)"
                     for m in scene.get("materials") or [])
    rows = [("scene", scene.get("name")), ("garment", scene.get("garment")), ("nodes", scene.get("node_count")),
            ("body", scene.get("body") or "none"), ("materials", None),
            ("friction", f"Coulomb, mu = {scene.get('friction_mu') or 0:g}{_regions_text(scene)}"
             if _frictional(scene) else "none (frictionless)"),
            ("held", f"{scene.get('constraints')} constraint(s)"), ("solver", scene.get("solver"))]
    out = ["<table id='scene'>"]
    for k, v in rows:
        out.append(f"<tr><th>{k}</th><td>{mats if k == 'materials' else _t(v)}</td></tr>")
    files = scene.get("files") or []
    if files:
        out.append("<tr><th>files</th><td>" + "<br>".join(
            f"{_t(f.get('field'))}: {_t(f.get('file'))} <small>sha256 {_t(str(f.get('sha256'))[:16])}...</small>"
            for f in files) + "</td></tr>")
    out.append("</table><p><small>The folder's scene.yaml holds the whole scene, its files by name (put them "
               "beside it to run it again).</small></p>")
    return "".join(out)


def build_html(s: dict, history, f, levels, pmax: float | None = None) -> str:
    """The page (see clothsim.compression.report)."""
    scene = f.scene
    name = _t(s.get("name", scene.get("name", "")))
    probes = _probe_points(s)
    rows, from_file = _levels(s, f, levels)
    scale = rf.colour_scale(f.pressure_mmhg, pmax, contact=f.in_contact)
    above = (f" {scale['above']} node{'s' if scale['above'] != 1 else ''} read more (up to {scale['peak']:.1f} mmHg) "
             f"and {'are' if scale['above'] != 1 else 'is'} drawn in the top colour." if scale["above"] else "")
    caption = (f"Contact pressure on the body, colour scale <span id='pmax'>{scale['lo']:g} to {scale['hi']:g}</span> "
               f"mmHg ({_t(scale['how'])}{', rounded up' if pmax is None else ''}).{above}"
               f"{' Probes: rings of their sensor discs, with their readings.' if probes else ''} "
               f"Choose the scale with 'report --pmax'.")
    maps = [("pressure", "pressure map", f.pressure_mmhg, "contact pressure [mmHg]", "viridis", scale, caption)]
    for key, title, v in (("warp-strain", "warp strain map", f.strain_warp), ("weft-strain", "weft strain map",
                                                                             f.strain_weft)):
        sc = rf.colour_scale(v, None, percentile=None)
        maps.append((key, title, v, f"{key.split('-')[0]} strain (engineering) [-]", "plasma", sc,
                     f"{title.capitalize()}: scale {sc['lo']:g} to {sc['hi']:g}."))
    run_date = scene.get("written_utc", "n/a")
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>clothsim report: {name}</title><style>{STYLE}</style></head><body>",
        f"<h1>clothsim report: {name}</h1>",
        f"<p id='dates'>Run {_t(run_date)} with clothsim <span id='version'>{_t(s.get('clothsim_version'))}</span>; "
        f"report {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} with clothsim {_t(__version__)}.</p>",
        f"<p id='status'>{_t(s.get('status'))}: {_count(s.get('iterations'))} iterations, residual "
        f"<span id='residual'>{_num(s.get('residual'), '.3e')}</span> N, solver {_t(s.get('solver'))}, "
        f"{_count(s.get('contact_count'))} contact nodes of {_count(s.get('node_count'))}.</p>",
        _headline(s, rows, from_file),
    ]
    for key, title, v, label, cmap, sc, cap in maps:
        png = _figure(title, rf.map_png, f.pos, f.faces, v, label, cmap, sc, f.body_v, f.body_f,
                      probes if key == "pressure" else ())
        parts += [f"<h2>{_t(title.capitalize())}</h2>",
                  f"<figure class='map' id='map-{key}' data-lo='{sc['lo']:g}' data-hi='{sc['hi']:g}' "
                  f"data-top-tick='{sc['ticks'][-1]:g}'>{_img(png, f'{title}: front, side and top views', 'map')}"
                  f"<figcaption>{cap}</figcaption></figure>"]
        if key == "pressure":
            if rows:
                parts += ["<h2>Measuring levels</h2>", levels_table(rows, from_file, scene.get("standards") or [])]
            if s.get("profiles") or rows:
                b = next((r["mean"] for r in rows if r.get("b")), None)
                png = _figure("profile plot", rf.profile_png, s.get("profiles") or [], _class_band(s, scene),
                              rows if from_file else None, str(s.get("name", "")), b,
                              from_file and not any(r.get("b") for r in rows))
                parts += ["<h2>Profile and gradient</h2>", _img(png, "profile plot")]
                for pf in s.get("profiles") or []:
                    g = pf.get("gradient") or {}
                    parts.append(f"<p class='gradient'><b>{_t(pf.get('name'))}</b>: {_t(g.get('note', ''))}</p>")
    if s.get("probes"):
        parts += ["<h2>Probes</h2>", "<p>A probe reads the normal contact force on the sheet within its disc divided "
                  "by the disc's area (pi radius^2), as a pressure sensor does.</p>", probes_table(s["probes"])]
    if s.get("classes"):
        c = s["classes"]
        parts.append(f"<h3>Classes of probe {_t(c.get('probe'))} ({c['pressure_mmhg']:.2f} mmHg)</h3><table id='classes'>"
                     "<tr><th>standard</th><th>class</th><th>source</th></tr>"
                     + "".join(f"<tr><td>{_t(r.get('standard'))}</td><td>{_t(r.get('class'))}</td>"
                               f"<td>{_t(r.get('source'))}</td></tr>" for r in c.get("results") or []) + "</table>")
    if scene.get("materials"):
        reached = {"warp": (float(np.nanmin(f.strain_warp)), float(np.nanmax(f.strain_warp))) if f.strain_warp.size
                   else None,
                   "weft": (float(np.nanmin(f.strain_weft)), float(np.nanmax(f.strain_weft))) if f.strain_weft.size
                   else None}
        png = _figure("material curves", rf.materials_png, scene["materials"], reached)
        parts += ["<h2>Material</h2>", _img(png, "material curves")]
    parts += ["<h2>Model and assumptions</h2>", _assumptions(scene, s), "<h2>Scene</h2>", _scene_summary(scene)]
    conv = _figure("convergence plot", rf.convergence_png, history)
    if conv:
        parts += ["<h2>Convergence</h2>", _img(conv, "convergence plot")]
    parts += ["<h2>Summary</h2>", summary_table(s)]
    parts.append(f"<p>Written by clothsim {_t(__version__)}; the run by clothsim {_t(s.get('clothsim_version'))}."
                 f"</p></body></html>")
    return "\n".join(parts)
