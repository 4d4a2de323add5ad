"""``python app.py report RESULT_DIR``: one self-contained HTML file of a result folder.

The file opens offline with no server: every image is a base64-embedded PNG (matplotlib, Agg),
the styles are inline, and nothing is fetched from a URL. It holds the run's status line, the
contact pressure [mmHg], warp strain and weft strain maps of the deformed sheet, each from three
views (front, side, top: one image each) with its colour bar and ticks, the probes table with
classes, the profile plot and gradient check, the convergence plot (residual against iteration),
the scene as run and the clothsim version.

The maps are recomputed from ``result.npz`` (positions, contact) and ``scene.yaml`` (the
compiled model's springs and ``model.topology.faces``), the same fields ``clothsim run`` writes;
every number in the tables is read from ``summary.json``.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
import zipfile
from pathlib import Path

import numpy as np

from . import MMHG

VIEWS = (("front", 0.0, -90.0), ("side", 0.0, 0.0), ("top", 90.0, -90.0))  # (name, elev, azim) [deg]


class ReportError(ValueError):
    pass


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(b64: str, alt: str, cls: str = "") -> str:
    c = f' class="{cls}"' if cls else ""
    return f'<img{c} alt="{html.escape(alt)}" src="data:image/png;base64,{b64}">'


def _fields(out: Path):
    """(scene, positions (N, 3), faces (F, 3), node pressure [mmHg] (N,), node warp strain (N,),
    node weft strain (N,)); a node's strain in one direction is that of its springs in that
    direction (topology.spread), engineering strain [-]."""
    from ..config import load_scene
    from ..compile import compile_model
    from ..grid import State
    from ..results import node_fields

    scene = load_scene(out / "scene.yaml")
    model = compile_model(scene)
    topo = model.topology
    try:
        with np.load(out / "result.npz") as d:
            pg, cg = d["positions"], d["in_contact"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ReportError(f"{out / 'result.npz'}: cannot be read ({type(exc).__name__}: {str(exc)[:80]})") from None
    # result.npz keeps a full rectangle's arrays as (nx+1, ny+1, ...) and a panel scene's flat
    # (N, ...) in node order
    pos = np.ascontiguousarray(pg.reshape(-1, 3), dtype=float)
    con = np.ascontiguousarray(cg.reshape(-1), dtype=bool)
    if pos.shape[0] != topo.node_count:
        raise ReportError(f"{out}: result.npz has {pos.shape[0]} nodes, the scene {topo.node_count}")
    strain, _, _, pressure = node_fields(model, State(pos, con, 0))
    wc, fc = topo.warp_count, topo.weft_count
    return (scene, pos, topo.faces, pressure / MMHG, topo.spread(strain[:wc], "warp"),
            topo.spread(strain[wc:wc + fc], "weft"))


def _map_scale(faces, values):
    """(face values (F,), lo, hi) of a node field: a face's value is the mean of its corners;
    the scale runs from min(0, least) so a uniform field reads as uniform, not as noise."""
    v = np.where(np.isfinite(values), values, np.nan)
    with np.errstate(invalid="ignore"):
        fv = np.nanmean(v[faces], axis=1) if faces.size else np.zeros(0)
    finite = fv[np.isfinite(fv)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    lo = min(lo, 0.0)
    if hi <= lo:
        hi = lo + (abs(lo) * 1e-3 or 1.0)
    return fv, lo, hi


def map_pngs(pos, faces, values, label: str, cmap: str) -> tuple[list[tuple[str, str]], str]:
    """A node field ``values`` (N,) on the deformed sheet (positions (N, 3) [m], faces (F, 3)):
    ([(view name, base64 PNG)] for the front, side and top views (each with its axes and ticks
    in metres), base64 PNG of the colour bar with ticks, labelled ``label``). Every view shares
    the one colour scale."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fv, lo, hi = _map_scale(faces, values)
    norm = Normalize(lo, hi)
    cm = colormaps[cmap]
    colors = cm(norm(np.nan_to_num(fv, nan=hi)))
    tri = pos[faces]
    c = pos.mean(axis=0)
    half = 0.5 * float(np.ptp(pos, axis=0).max()) or 1.0
    views = []
    for name, elev, azim in VIEWS:
        fig = Figure(figsize=(4.2, 4.2), dpi=90)
        fig.subplots_adjust(left=0.0, right=0.95, bottom=0.04, top=0.93)
        ax = fig.add_subplot(1, 1, 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolors="none", linewidths=0))
        for setter, ci in ((ax.set_xlim, c[0]), (ax.set_ylim, c[1]), (ax.set_zlim, c[2])):
            setter(ci - half, ci + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(f"{name} view")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.tick_params(labelsize=7)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(4))
        views.append((name, _png(fig)))
    fig = Figure(figsize=(1.5, 4.2), dpi=90)
    cax = fig.add_axes((0.12, 0.06, 0.22, 0.86))
    fig.colorbar(ScalarMappable(norm=norm, cmap=cm), cax=cax).set_label(label)
    cax.yaxis.set_major_locator(MaxNLocator(6))
    return views, _png(fig)


def map_figure(key: str, title: str, pos, faces, values, label: str, cmap: str) -> str:
    """A ``<figure class='map' id='map-KEY'>``: the three views of a node field (``img.view``,
    alt 'TITLE: front view' ...) and its colour bar (``img.colorbar``, alt 'TITLE colour bar')."""
    views, bar = map_pngs(pos, faces, values, label, cmap)
    imgs = "".join(_img(b64, f"{title}: {name} view", "view") for name, b64 in views)
    return (f"<figure class='map' id='map-{html.escape(key)}'><div class='views'>{imgs}"
            f"{_img(bar, f'{title} colour bar', 'colorbar')}</div>"
            f"<figcaption>{html.escape(title)}: {html.escape(label)}, front, side and top views</figcaption>"
            "</figure>")


def convergence_png(history_csv: Path) -> str | None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    try:
        data = np.genfromtxt(history_csv, delimiter=",", names=True)
    except (OSError, ValueError):
        return None
    it = np.atleast_1d(data["iteration"])
    res = np.atleast_1d(data["residual_N"])
    if not it.size:
        return None
    fig = Figure(figsize=(6.0, 3.6), dpi=90)
    ax = fig.add_subplot(1, 1, 1)
    ax.semilogy(it, np.maximum(res, 1e-300), "-o", ms=2)
    ax.set_xlabel("iteration")
    ax.set_ylabel("residual ||V||inf [N]")
    ax.set_title("convergence")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return _png(fig)


def _fmt(v, nd=2) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return html.escape(str(v))


def probes_table(probes: list[dict]) -> str:
    rows = ["<table id='probes'><tr><th>probe</th><th>centre [m]</th><th>radius [mm]</th><th>pressure [mmHg]</th>"
            "<th>pressure [Pa]</th><th>contact fraction</th><th>classes</th><th>note</th></tr>"]
    for p in probes:
        c = p.get("center") or p["point"]
        cls = "<br>".join(f"{html.escape(k)}: {html.escape(v)}" for k, v in p.get("classes", {}).items()) or "-"
        rows.append(
            f"<tr><td>{html.escape(p['name'])}</td><td>({c[0]:.4f}, {c[1]:.4f}, {c[2]:.4f})</td>"
            f"<td>{p['radius_m'] * 1e3:.1f}</td><td class='mmhg'>{p['pressure_mmhg']:.2f}</td>"
            f"<td class='pa'>{p['pressure_pa']:.1f}</td><td class='frac'>{p['contact_fraction']:.3f}</td>"
            f"<td>{cls}</td><td>{html.escape(p['note'])}</td></tr>")
    rows.append("</table>")
    return "\n".join(rows)


REPORT_NEEDS = ("summary.json", "result.npz", "scene.yaml")


def check_result_dir(result_dir: str | Path) -> Path:
    """The result folder, checked: it exists, is a folder and holds summary.json, result.npz and
    scene.yaml (what ``clothsim run --out`` and ``fit --out`` write). Raises ReportError naming the
    folder and what is wrong."""
    out = Path(result_dir)
    if not out.exists():
        raise ReportError(f"{out}: no such folder (give a folder written by 'clothsim run --out' or 'fit --out')")
    if not out.is_dir():
        raise ReportError(f"{out}: not a folder (give a folder written by 'clothsim run --out' or 'fit --out')")
    missing = [name for name in REPORT_NEEDS if not (out / name).is_file()]
    if "summary.json" in missing:
        raise ReportError(f"{out}: not a result folder: no summary.json (a folder written by 'clothsim run --out' "
                          f"or 'fit --out' holds {', '.join(REPORT_NEEDS)})")
    if missing:
        raise ReportError(f"{out}: no {missing[0]} (a folder written by 'clothsim run --out' or 'fit --out')")
    return out


def read_summary(path: Path) -> dict:
    """summary.json as a dict; ReportError naming the file if it cannot be read, is not JSON or
    is not a JSON object."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        s = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ReportError(f"{path}: not valid JSON (line {exc.lineno} column {exc.colno}: {exc.msg}); "
                          f"rewrite it with 'clothsim run --out'") from None
    if not isinstance(s, dict):
        kind = {list: "list", str: "string"}.get(type(s), type(s).__name__)
        raise ReportError(f"{path}: not a run summary (a JSON {kind}, not an object)")
    return s


def build_report(result_dir: str | Path) -> str:
    """The report's HTML text for a result folder (see the module docstring). Raises ReportError
    (naming the file) for a folder that is not a result folder or holds a damaged file."""
    out = check_result_dir(result_dir)
    s = read_summary(out / "summary.json")
    try:
        return _build(out, s)
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        raise ReportError(f"{out / 'summary.json'}: not a run summary clothsim wrote "
                          f"({type(exc).__name__}: {str(exc)[:80]})") from None


def _num(v, fmt: str) -> str:
    """v formatted with fmt, or "n/a" when it is missing or not finite (a run stopped before its
    residual was evaluated writes null)."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return "n/a"
    return format(x, fmt) if math.isfinite(x) else "n/a"


def _build(out: Path, s: dict) -> str:
    scene, pos, faces, p_mmhg, strain_warp, strain_weft = _fields(out)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>clothsim report: {html.escape(str(s.get('name', '')))}</title>",
        "<style>body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse;"
        "margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:left;font-size:14px}"
        "img{max-width:100%}.views{display:flex;flex-wrap:wrap;align-items:center}.views img.view{width:31%}"
        ".views img.colorbar{width:6%;min-width:60px}figure{margin:.5em 0}figcaption{font-size:13px;color:#444}"
        "pre{background:#f4f4f4;padding:8px;overflow:auto;font-size:12px}</style></head><body>",
        f"<h1>clothsim report: {html.escape(str(s.get('name', '')))}</h1>",
        f"<p id='status'>{html.escape(str(s.get('status')))}: {s.get('iterations')} iterations, residual "
        f"<span id='residual'>{_num(s.get('residual'), '.3e')}</span> N, solver {html.escape(str(s.get('solver')))}, "
        f"{s.get('contact_count')} contact nodes of {s.get('node_count')}; peak contact pressure "
        + (f"<span id='peak'>{s['max_contact_pressure_mmhg']:.2f}</span> mmHg. clothsim "
           if s.get('max_contact_pressure_mmhg') is not None else
           f"<span id='peak'>none</span> ({html.escape(str(s.get('contact_pressure_note', '')))}). clothsim ")
        + f"<span id='version'>{html.escape(str(s.get('clothsim_version')))}</span>.</p>",
        "<h2>Contact pressure [mmHg]</h2>",
        map_figure("pressure", "pressure map", pos, faces, p_mmhg, "contact pressure [mmHg]", "viridis"),
        "<h2>Warp strain</h2>",
        map_figure("warp-strain", "warp strain map", pos, faces, strain_warp, "warp strain (engineering) [-]",
                   "plasma"),
        "<h2>Weft strain</h2>",
        map_figure("weft-strain", "weft strain map", pos, faces, strain_weft, "weft strain (engineering) [-]",
                   "plasma"),
    ]
    if s.get("probes"):
        parts += ["<h2>Probes</h2>", "<p>A probe reads the normal contact force on the sheet within its disc "
                  "divided by the disc's area (pi radius^2), as a pressure sensor does.</p>", probes_table(s["probes"])]
    if s.get("classes"):
        c = s["classes"]
        parts.append(f"<h3>Classes of probe {html.escape(c['probe'])} ({c['pressure_mmhg']:.2f} mmHg)</h3><table id='classes'>"
                     "<tr><th>standard</th><th>class</th><th>source</th></tr>"
                     + "".join(f"<tr><td>{html.escape(r['standard'])}</td><td>{html.escape(r['class'])}</td>"
                               f"<td>{html.escape(r['source'])}</td></tr>" for r in c["results"]) + "</table>")
    if s.get("profiles"):
        from .probes import profile_png

        parts += ["<h2>Profiles</h2>",
                  _img(base64.b64encode(profile_png(s["profiles"], str(s.get("name", "")))).decode("ascii"), "profile plot")]
        for pf in s["profiles"]:
            g = pf["gradient"]
            parts.append(f"<p class='gradient'><b>{html.escape(pf['name'])}</b>: {html.escape(g.get('note', ''))}</p>")
    conv = convergence_png(out / "history.csv")
    if conv:
        parts += ["<h2>Convergence</h2>", _img(conv, "convergence plot")]
    parts += ["<h2>Scene</h2>", f"<pre id='scene'>{html.escape((out / 'scene.yaml').read_text())}</pre>",
              f"<p>Written by clothsim {html.escape(str(s.get('clothsim_version')))}.</p></body></html>"]
    return "\n".join(parts)


def check_report_path(target: Path, flag: str = "--out") -> None:
    """Refuse (ReportError) an HTML file path that cannot be written: a folder, a file in a folder
    that does not exist or is not writable. Checked before the figures are rendered."""
    parent = target.parent
    if target.is_dir():
        raise ReportError(f"{flag} {target}: is a folder (give the HTML file to write, e.g. {target / 'report.html'})")
    if not parent.exists():
        raise ReportError(f"{flag} {target}: its folder {parent} does not exist")
    if not parent.is_dir():
        raise ReportError(f"{flag} {target}: {parent} is not a folder")
    probe = parent / f".clothsim-probe{os.getpid()}"
    try:  # permission bits do not stop root; a read-only file system does
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except OSError as exc:
        raise ReportError(f"{flag} {target}: cannot write in {parent} ({exc.strerror or exc})") from None


def write_report(result_dir: str | Path, path: str | Path | None = None) -> Path:
    """Write the report (default RESULT_DIR/report.html); returns its path. Raises ReportError
    (naming the file and the problem) for a bad result folder or a path that cannot be written."""
    from ..fileio import describe_write_error
    from ..results import atomic_write_bytes

    check_result_dir(result_dir)
    target = Path(path) if path else Path(result_dir) / "report.html"
    flag = "--out" if path else "report"
    check_report_path(target, flag)
    text = build_report(result_dir)
    try:
        atomic_write_bytes(target, text.encode("utf-8"))
    except OSError as exc:
        raise ReportError(describe_write_error(exc, target, flag)) from None
    return target
