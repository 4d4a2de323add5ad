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

A result folder is something people mail each other, so it is read as untrusted input: its files
pass the same checks as scene files (:func:`clothsim.fileio.check_input_file`: regular files
under a size cap, no link out of the folder), summary.json's numbers must be JSON numbers (a
string, list or object where a number belongs is refused naming the file and key; see
:func:`check_summary`), and every string that reaches the page is HTML-escaped. Figures draw user
text literally (never as mathtext), and a figure that cannot be drawn leaves a note in its place
and a warning; it never costs the report.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
import warnings
import zipfile
from pathlib import Path

import numpy as np

from . import MMHG
from ..fileio import TEXT_LIMIT, check_input_file, excerpt, open_input, read_input_bytes, read_text

VIEWS = (("front", 0.0, -90.0), ("side", 0.0, 0.0), ("top", 90.0, -90.0))  # (name, elev, azim) [deg]


class ReportError(ValueError):
    pass


#: largest summary.json read [bytes] (a run's is a few kB; with many probes and profiles, tens of kB)
SUMMARY_LIMIT = TEXT_LIMIT
#: largest history.csv read [bytes]: a line (about 55 bytes) per iteration, 11 MB for the default
#: 200,000 iterations
HISTORY_LIMIT = 256 * 2**20
#: largest result.npz read [bytes] (compressed; its arrays are also held to the scene's node count)
NPZ_LIMIT = 4 * 2**30


def _t(v) -> str:
    """Any value as HTML text: str() of it, escaped (quotes too: safe in attributes)."""
    return html.escape(str(v), quote=True)


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


class _Missing(str):
    """The note of a figure that could not be drawn (a str: what the page shows instead)."""


def _missing(m: _Missing) -> str:
    return f"<p class='missing'>{_t(m)}</p>"


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(b64: str, alt: str, cls: str = "") -> str:
    c = f' class="{cls}"' if cls else ""
    return f'<img{c} alt="{_t(alt)}" src="data:image/png;base64,{b64}">'


def _fields(out: Path):
    """(scene, positions (N, 3), faces (F, 3), node pressure [mmHg] (N,), node warp strain (N,),
    node weft strain (N,)); a node's strain in one direction is that of its springs in that
    direction (topology.spread), engineering strain [-]."""
    from ..config import load_scene
    from ..compile import compile_model
    from ..model import State
    from ..results import node_fields

    scene = load_scene(out / "scene.yaml")
    model = compile_model(scene)
    topo = model.topology
    path = out / "result.npz"
    n = topo.node_count
    try:
        with open_input(path, ReportError, limit=NPZ_LIMIT, what="result file") as fh, np.load(fh) as d:
            # the arrays' sizes are what the archive declares (a small file can declare gigabytes):
            # held to what the scene's nodes need before anything is decompressed
            for key, per_node in (("positions", 24), ("in_contact", 1)):
                size = d.zip.getinfo(f"{key}.npy").file_size
                if size > per_node * n + 4096:
                    raise ReportError(f"{path}: {key} holds {size:,} bytes, more than the scene's {n:,} nodes "
                                      f"need; not the result of this scene.yaml")
            pg, cg = d["positions"], d["in_contact"]
    except (OSError, ValueError, KeyError, EOFError, AttributeError, zipfile.BadZipFile) as exc:
        if isinstance(exc, ReportError):
            raise
        raise ReportError(f"{path}: cannot be read ({type(exc).__name__}: {excerpt(exc, 80, quote=False)})") from None
    if pg.dtype.kind not in "fiu" or cg.dtype.kind not in "biu":
        raise ReportError(f"{path}: positions / in_contact are not numbers")
    if pg.size != 3 * n or cg.size != n:
        raise ReportError(f"{path}: positions {pg.shape} and in_contact {cg.shape} do not hold the scene's "
                          f"{n:,} nodes; not the result of this scene.yaml")
    # result.npz keeps a full rectangle's arrays as (nx+1, ny+1, ...) and a panel scene's flat
    # (N, ...) in node order
    pos = np.ascontiguousarray(pg.reshape(-1, 3), dtype=float)
    con = np.ascontiguousarray(cg.reshape(-1), dtype=bool)
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
    alt 'TITLE: front view' ...) and its colour bar (``img.colorbar``, alt 'TITLE colour bar');
    a note in their place when they cannot be drawn."""
    drawn = _figure(title, map_pngs, pos, faces, values, label, cmap)
    if isinstance(drawn, _Missing):
        return f"<figure class='map' id='map-{_t(key)}'>{_missing(drawn)}</figure>"
    views, bar = drawn
    imgs = "".join(_img(b64, f"{title}: {name} view", "view") for name, b64 in views)
    return (f"<figure class='map' id='map-{_t(key)}'><div class='views'>{imgs}"
            f"{_img(bar, f'{title} colour bar', 'colorbar')}</div>"
            f"<figcaption>{html.escape(title)}: {html.escape(label)}, front, side and top views</figcaption>"
            "</figure>")


HISTORY_COLUMNS = ("iteration", "residual_N")


def read_history(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(iterations, residuals [N]) of a history.csv (``clothsim run`` writes iteration,
    residual_N, energy_J, elapsed_s), None when the folder has none. The file passes the input
    checks (a regular file of at most HISTORY_LIMIT bytes, no link out of the folder); a header
    without the two columns or a cell that is not a number raises ReportError ``file:line: ...``."""
    if not os.path.lexists(path):
        return None
    from array import array

    # bytes, line by line (no list of lines, no text copy: a 2,000,000-iteration history is 100 MB)
    lines = io.BytesIO(read_input_bytes(path, ReportError, limit=HISTORY_LIMIT, what="history file"))
    first = lines.readline().decode("utf-8", "replace").rstrip("\r\n")
    header = [c.strip() for c in first.split(",")]
    for name in HISTORY_COLUMNS:
        if name not in header:
            raise ReportError(f"{path}:1: no '{name}' column (the header is {excerpt(first, 60)}; "
                              f"'clothsim run --out' writes iteration,residual_N,energy_J,elapsed_s)")
    cols = [(name, header.index(name), array("d")) for name in HISTORY_COLUMNS]
    for ln, line in enumerate(lines, 2):
        if not line.strip():
            continue
        cells = line.split(b",")
        if len(cells) != len(header):
            raise ReportError(f"{path}:{ln}: {len(cells)} cells, the header has {len(header)}")
        for name, c, values in cols:
            try:
                values.append(float(cells[c]))
            except ValueError:
                cell = cells[c].decode("utf-8", "replace").strip()
                raise ReportError(f"{path}:{ln}: {name} is not a number ({excerpt(cell)})") from None
    if not cols[0][2]:
        return None
    return np.frombuffer(cols[0][2]), np.frombuffer(cols[1][2])


def convergence_png(history: tuple[np.ndarray, np.ndarray] | None) -> str | None:
    """The convergence plot (residual against iteration, log scale) of read_history's columns;
    None without a history."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    if history is None:
        return None
    it, res = history
    if it.size > 20_000:   # a long run: every k-th point and the last one are drawn
        keep = np.unique(np.r_[np.arange(0, it.size, it.size // 10_000), it.size - 1])
        it, res = it[keep], res[keep]
    fig = Figure(figsize=(6.0, 3.6), dpi=90)
    ax = fig.add_subplot(1, 1, 1)
    ax.semilogy(it, np.maximum(res, 1e-300), "-o", ms=2)
    ax.set_xlabel("iteration")
    ax.set_ylabel("residual ||V||inf [N]")
    ax.set_title("convergence")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return _png(fig)


def summary_table(s: dict) -> str:
    """Every number and word of summary.json the field list (clothsim.records) names, with its
    unit: the run's, the diagnostics', the friction report's (friction.KEY) and each stage's
    (stage:NAME.KEY); the probes have their own table."""
    from ..records import field_rows, format_value

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


REPORT_NEEDS = ("summary.json", "result.npz", "scene.yaml")
#: each file of a result folder the report reads: (size cap [bytes], what it is in messages)
RESULT_INPUTS = {"summary.json": (SUMMARY_LIMIT, "run summary"), "result.npz": (NPZ_LIMIT, "result file"),
                 "scene.yaml": (TEXT_LIMIT, "scene file"), "history.csv": (HISTORY_LIMIT, "history file")}


def check_result_dir(result_dir: str | Path) -> Path:
    """The result folder, checked: it exists, is a folder and holds summary.json, result.npz and
    scene.yaml (what ``clothsim run --out`` and ``fit --out`` write), each (and history.csv when
    there is one) a regular file under its size cap and no link out of the folder
    (:func:`clothsim.fileio.check_input_file`, the check scene files pass: a FIFO or a link to
    ``/dev/zero`` is refused, not read). Raises ReportError naming the folder or file and what is
    wrong."""
    out = Path(result_dir)
    if not out.exists():
        raise ReportError(f"{out}: no such folder (give a folder written by 'clothsim run --out' or 'fit --out')")
    if not out.is_dir():
        raise ReportError(f"{out}: not a folder (give a folder written by 'clothsim run --out' or 'fit --out')")
    missing = [name for name in REPORT_NEEDS if not os.path.lexists(out / name)]
    if "summary.json" in missing:
        raise ReportError(f"{out}: not a result folder: no summary.json (a folder written by 'clothsim run --out' "
                          f"or 'fit --out' holds {', '.join(REPORT_NEEDS)})")
    if missing:
        raise ReportError(f"{out}: no {missing[0]} (a folder written by 'clothsim run --out' or 'fit --out')")
    for name, (limit, what) in RESULT_INPUTS.items():
        if os.path.lexists(out / name):
            check_input_file(out / name, ReportError, limit=limit, what=what)
    return out


def read_summary(path: Path) -> dict:
    """summary.json as a dict; ReportError naming the file if it cannot be read (the input
    checks of check_result_dir), is not JSON (nested too deeply included) or is not a JSON
    object."""
    text = read_text(path, ReportError, limit=SUMMARY_LIMIT)
    try:
        s = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ReportError(f"{path}: not valid JSON (line {exc.lineno} column {exc.colno}: {exc.msg}); "
                          f"rewrite it with 'clothsim run --out'") from None
    except RecursionError:
        raise ReportError(f"{path}: JSON nested too deeply (a run summary is a few levels deep)") from None
    except ValueError as exc:  # an integer of over 4300 digits
        raise ReportError(f"{path}: not valid JSON ({excerpt(exc, 80, quote=False)})") from None
    if not isinstance(s, dict):
        kind = {list: "list", str: "string"}.get(type(s), type(s).__name__)
        raise ReportError(f"{path}: not a run summary (a JSON {kind}, not an object)")
    return s


# ----------------------------------------------------------------------------- summary.json's shape

_JSON_KIND = {str: "a string", bool: "a boolean", list: "a list", dict: "an object", type(None): "null"}


class _Check:
    """Type checks of summary.json's fields, raising ReportError ``file: key: what`` (key as
    ``probes[0].pressure_mmhg``)."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, what: str, v=None):
        got = "" if v is None else f" (got {_JSON_KIND.get(type(v), type(v).__name__)}"
        if got and isinstance(v, (str, int, float)) and not isinstance(v, bool):
            got += f" {excerpt(v)}"
        elif got and isinstance(v, bool):
            got += f" {str(v).lower()}"
        raise ReportError(f"{self.path}: {key}: {what}{got + ')' if got else ''}; not a run summary "
                          f"'clothsim run --out' wrote")

    def number(self, obj: dict, name: str, key: str, *, null: bool = True, integer: bool = False):
        """obj[name]: a JSON number (an integer when ``integer``; null or missing when ``null``)."""
        v = obj.get(name)
        if v is None:
            if null:
                return None
            self.fail(key, "missing" if name not in obj else "not a number", None if name not in obj else "null")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, "not a number", v)
        if integer and not isinstance(v, int):
            self.fail(key, "not a whole number", v)
        if not integer:
            try:
                v = float(v)
            except OverflowError:
                self.fail(key, "out of range", v)
        obj[name] = v
        return v

    def obj(self, v, key: str) -> dict:
        if not isinstance(v, dict):
            self.fail(key, "not an object", v)
        return v

    def items(self, v, key: str) -> list:
        if v is None:
            return []
        if not isinstance(v, list):
            self.fail(key, "not a list", v)
        return v


def check_summary(s: dict, path: Path) -> dict:
    """summary.json ``s`` (parsed) with every field the report shows checked: the numbers must be
    JSON numbers (null where a run may write null: a residual never evaluated, a pressure where
    the sheet gathered), the counts whole numbers, the probes, profiles and classes lists and
    objects of the shape clothsim writes. A string, list or object where a number belongs (markup
    in ``iterations`` from a mailed result folder) raises ReportError naming the file and the key;
    strings are not checked here (the page escapes every one). Numbers are returned as floats
    (counts as ints)."""
    c = _Check(path)
    for name in ("iterations", "contact_count", "node_count"):
        c.number(s, name, name, integer=True)
    for name in ("residual", "max_contact_pressure_mmhg"):
        c.number(s, name, name)
    for i, p in enumerate(c.items(s.get("probes"), "probes")):
        k = f"probes[{i}]"
        c.obj(p, k)
        for name in ("radius_m", "pressure_mmhg", "pressure_pa", "contact_fraction"):
            c.number(p, name, f"{k}.{name}", null=False)
        where = "center" if p.get("center") else "point"
        pt = p.get(where)
        if not isinstance(pt, list) or len(pt) != 3:
            c.fail(f"{k}.{where}", "not a point [x, y, z]", pt)
        coords = dict(enumerate(pt))
        for j in range(3):
            pt[j] = c.number(coords, j, f"{k}.{where}[{j}]", null=False)
        if p.get("classes") is not None:
            c.obj(p["classes"], f"{k}.classes")
    if s.get("classes"):
        cl = c.obj(s["classes"], "classes")
        c.number(cl, "pressure_mmhg", "classes.pressure_mmhg", null=False)
        for i, r in enumerate(c.items(cl.get("results"), "classes.results")):
            c.obj(r, f"classes.results[{i}]")
    for i, pf in enumerate(c.items(s.get("profiles"), "profiles")):
        k = f"profiles[{i}]"
        c.obj(pf, k)
        for j, sl in enumerate(c.items(pf.get("slices"), f"{k}.slices")):
            c.obj(sl, f"{k}.slices[{j}]")
            c.number(sl, "height_m", f"{k}.slices[{j}].height_m", null=False)
            for name in ("mean_mmhg", "girth_mean_mmhg", "min_mmhg", "max_mmhg"):
                c.number(sl, name, f"{k}.slices[{j}].{name}")
        if pf.get("gradient") is not None:
            c.obj(pf["gradient"], f"{k}.gradient")
    return s


def build_report(result_dir: str | Path) -> str:
    """The report's HTML text for a result folder (see the module docstring). Raises ReportError
    (naming the file) for a folder that is not a result folder or holds a damaged file."""
    out = check_result_dir(result_dir)
    s = check_summary(read_summary(out / "summary.json"), out / "summary.json")
    history = read_history(out / "history.csv")
    try:
        return _build(out, s, history)
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        raise ReportError(f"{out / 'summary.json'}: not a run summary clothsim wrote "
                          f"({type(exc).__name__}: {excerpt(exc, 80, quote=False)})") from None


def _num(v, fmt: str) -> str:
    """v (a number or None: check_summary) formatted with fmt, or "n/a" when it is missing or not
    finite (a run stopped before its residual was evaluated writes null)."""
    if v is None or not math.isfinite(v):
        return "n/a"
    return format(v, fmt)


def _count(v) -> str:
    return "n/a" if v is None else str(v)


def _build(out: Path, s: dict, history) -> str:
    scene, pos, faces, p_mmhg, strain_warp, strain_weft = _fields(out)
    name = _t(s.get("name", ""))
    peak = s.get("max_contact_pressure_mmhg")
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>clothsim report: {name}</title>",
        "<style>body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse;"
        "margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:left;font-size:14px}"
        "img{max-width:100%}.views{display:flex;flex-wrap:wrap;align-items:center}.views img.view{width:31%}"
        ".views img.colorbar{width:6%;min-width:60px}figure{margin:.5em 0}figcaption{font-size:13px;color:#444}"
        "pre{background:#f4f4f4;padding:8px;overflow:auto;font-size:12px}.missing{color:#a00}</style></head><body>",
        f"<h1>clothsim report: {name}</h1>",
        f"<p id='status'>{_t(s.get('status'))}: {_count(s.get('iterations'))} iterations, residual "
        f"<span id='residual'>{_num(s.get('residual'), '.3e')}</span> N, solver {_t(s.get('solver'))}, "
        f"{_count(s.get('contact_count'))} contact nodes of {_count(s.get('node_count'))}; peak contact pressure "
        + (f"<span id='peak'>{_num(peak, '.2f')}</span> mmHg. clothsim " if peak is not None else
           f"<span id='peak'>none</span> ({_t(s.get('contact_pressure_note', ''))}). clothsim ")
        + f"<span id='version'>{_t(s.get('clothsim_version'))}</span>.</p>",
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
        parts.append(f"<h3>Classes of probe {_t(c.get('probe'))} ({c['pressure_mmhg']:.2f} mmHg)</h3><table id='classes'>"
                     "<tr><th>standard</th><th>class</th><th>source</th></tr>"
                     + "".join(f"<tr><td>{_t(r.get('standard'))}</td><td>{_t(r.get('class'))}</td>"
                               f"<td>{_t(r.get('source'))}</td></tr>" for r in c.get("results") or []) + "</table>")
    if s.get("profiles"):
        from .probes import profile_png

        parts.append("<h2>Profiles</h2>")
        png = _figure("profile plot", profile_png, s["profiles"], str(s.get("name", "")))
        parts.append(_missing(png) if isinstance(png, _Missing) else
                     _img(base64.b64encode(png).decode("ascii"), "profile plot"))
        for pf in s["profiles"]:
            g = pf.get("gradient") or {}
            parts.append(f"<p class='gradient'><b>{_t(pf.get('name'))}</b>: {_t(g.get('note', ''))}</p>")
    conv = _figure("convergence plot", convergence_png, history)
    if conv:
        parts += ["<h2>Convergence</h2>", _missing(conv) if isinstance(conv, _Missing) else
                  _img(conv, "convergence plot")]
    parts += ["<h2>Summary</h2>", summary_table(s)]
    scene_text = read_text(out / "scene.yaml", ReportError, limit=TEXT_LIMIT)
    parts += ["<h2>Scene</h2>", f"<pre id='scene'>{_t(scene_text)}</pre>",
              f"<p>Written by clothsim {_t(s.get('clothsim_version'))}.</p></body></html>"]
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
