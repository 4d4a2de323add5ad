"""``python app.py report RESULT_DIR``: one self-contained HTML file of a result folder, to send a client.

The file opens offline with no server: every image is a base64-embedded PNG (matplotlib, Agg),
the styles are inline, and nothing is fetched from a URL. It holds the dates and clothsim versions,
the run's status line, the headline figures (the classed probe's reading and class, the girth mean
at B, the gradient, the greatest sensor reading; the single-node peak for reference), the contact
pressure map with the body in three views (front, side, top) with the probes marked and a colour
scale chosen or stated (``--pmax``), the table per measuring level (levels.csv, or the profile's
slices), the profile with the class band and the gradient, the warp and weft strain maps, the
probes and classes, the material curves, the model's assumptions, the scene in short and the
convergence plot (:mod:`.report_html`, :mod:`.report_figures`, :mod:`.report_levels`).

The report is built from the folder alone (issue 31 item 5): ``result.npz`` carries the faces,
the node fields, the body near the garment and the scene in short (:mod:`.folder`), so a folder
moved or mailed, or whose body file has moved, is reported all the same. Nothing is recompiled
and ``scene.yaml`` is not read.

A result folder is something people mail each other, so it is read as untrusted input: its files
pass the same checks as scene files (:func:`clothsim.fileio.check_input_file`: regular files
under a size cap, no link out of the folder), result.npz's arrays are held to the run's node count
before they are decompressed, summary.json's and the scene summary's numbers must be JSON numbers
(a string, list or object where a number belongs is refused naming the file and key; see
:func:`check_summary`), levels.csv's numeric cells must be numbers, and every string that reaches
the page is HTML-escaped. Figures draw user text literally (never as mathtext), and a figure that
cannot be drawn leaves a note in its place and a warning; it never costs the report.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import MMHG
from ..fileio import TEXT_LIMIT, check_input_file, excerpt, open_input, read_input_bytes, read_text
from ..reportdata import BODY_MAX_FACES
from .report_levels import LEVELS_LIMIT, read_levels

class ReportError(ValueError):
    pass


#: largest summary.json read [bytes] (a run's is a few kB; with many probes and profiles, tens of kB)
SUMMARY_LIMIT = TEXT_LIMIT
#: largest history.csv read [bytes]: a line (about 55 bytes) per iteration, 11 MB for the default
#: 200,000 iterations
HISTORY_LIMIT = 256 * 2**20
#: largest result.npz read [bytes] (compressed; its arrays are also held to the scene's node count)
NPZ_LIMIT = 4 * 2**30


class Fields(NamedTuple):
    """What result.npz holds for the report (see clothsim.compression.folder)."""

    pos: np.ndarray             #: (N, 3) [m] the deformed garment's nodes
    faces: np.ndarray           #: (F, 3) its display triangles
    pressure_mmhg: np.ndarray   #: (N,) contact pressure (inf where the sheet gathered into a rope)
    in_contact: np.ndarray      #: (N,) bool
    strain_warp: np.ndarray     #: (N,) each node's mean warp spring strain
    strain_weft: np.ndarray     #: (N,)
    body_v: np.ndarray          #: (V, 3) [m] the body near the garment
    body_f: np.ndarray          #: (B, 3)
    scene: dict                 #: the scene in short (scene_summary)


#: each array the report reads from result.npz: its largest uncompressed size [bytes] per node of
#: the run (summary.json's node_count), or, for the body and the scene summary, in all
_PER_NODE = {"positions": 24, "in_contact": 1, "contact_pressure": 8, "node_strain_warp": 8, "node_strain_weft": 8,
             "faces": 8 * 3 * 4}
_FIXED = {"body_vertices": 12 * 3 * BODY_MAX_FACES, "body_faces": 4 * 3 * BODY_MAX_FACES,
          "scene_summary": 4 * SUMMARY_LIMIT}


def read_fields(out: Path, s: dict) -> Fields:
    """result.npz's arrays (read as untrusted input: each array's declared size is held to what
    the run's node count needs before anything is decompressed; shapes, kinds and node ids are
    checked) and its scene summary (numbers checked as in summary.json). ReportError naming the
    file for anything else; a folder written before the report read folders alone (no faces)
    is refused with what to do."""
    path = out / "result.npz"
    n = s.get("node_count")
    if n is None or n < 1:
        raise ReportError(f"{out / 'summary.json'}: node_count: missing; not a run summary 'clothsim run --out' wrote")
    caps = {k: v * n + 4096 for k, v in _PER_NODE.items()} | {k: v + 4096 for k, v in _FIXED.items()}
    arrays = {}
    try:
        with open_input(path, ReportError, limit=NPZ_LIMIT, what="result file") as fh, np.load(fh) as d:
            for key, cap in caps.items():
                if f"{key}.npy" not in d.zip.namelist():
                    continue
                size = d.zip.getinfo(f"{key}.npy").file_size
                if size > cap:
                    raise ReportError(f"{path}: {key} holds {size:,} bytes, more than the scene's {n:,} nodes "
                                      f"need; not the result of this summary.json")
            for key in caps:
                if f"{key}.npy" in d.zip.namelist():
                    arrays[key] = d[key]
    except (OSError, ValueError, KeyError, EOFError, AttributeError, zipfile.BadZipFile) as exc:
        if isinstance(exc, ReportError):
            raise
        raise ReportError(f"{path}: cannot be read ({type(exc).__name__}: {excerpt(exc, 80, quote=False)})") from None
    for key in ("positions", "in_contact"):
        if key not in arrays:
            raise ReportError(f"{path}: no {key}; not a result file clothsim wrote")
    pg, cg = arrays["positions"], arrays["in_contact"]
    if pg.dtype.kind not in "fiu" or cg.dtype.kind not in "biu":
        raise ReportError(f"{path}: positions / in_contact are not numbers")
    if pg.size != 3 * n or cg.size != n:
        raise ReportError(f"{path}: positions {pg.shape} and in_contact {cg.shape} do not hold the scene's "
                          f"{n:,} nodes; not the result of this summary.json")
    for key in ("faces", "contact_pressure", "node_strain_warp", "node_strain_weft", "scene_summary"):
        if key not in arrays:
            raise ReportError(f"{path}: no {key}: written by a clothsim older than the report that reads the folder "
                              f"alone; run the scene again with 'clothsim run --out'")
    node = {}
    for key in ("contact_pressure", "node_strain_warp", "node_strain_weft"):
        a = arrays[key]
        if a.dtype.kind not in "fiu" or a.size != n:
            raise ReportError(f"{path}: {key} {a.shape} does not hold the scene's {n:,} nodes as numbers")
        node[key] = np.asarray(a, float).reshape(-1)
    faces = _index_array(path, "faces", arrays["faces"], n)
    bv = arrays.get("body_vertices", np.zeros((0, 3)))
    if bv.dtype.kind not in "fiu" or bv.ndim != 2 or bv.shape[1] != 3:
        raise ReportError(f"{path}: body_vertices {bv.shape} is not a list of points (V, 3)")
    bf = _index_array(path, "body_faces", arrays.get("body_faces", np.zeros((0, 3), np.int32)), len(bv))
    return Fields(np.ascontiguousarray(pg.reshape(-1, 3), dtype=float), faces, node["contact_pressure"] / MMHG,
                  np.ascontiguousarray(cg.reshape(-1), dtype=bool), node["node_strain_warp"],
                  node["node_strain_weft"], np.asarray(bv, float), bf,
                  check_scene_summary(arrays["scene_summary"], f"{path}: scene_summary"))


def _index_array(path: Path, key: str, a: np.ndarray, n: int) -> np.ndarray:
    if a.dtype.kind not in "iu" or a.ndim != 2 or a.shape[1] != 3:
        raise ReportError(f"{path}: {key} {a.shape} is not a list of triangles (F, 3) of node ids")
    if a.size and (a.min() < 0 or a.max() >= n):
        raise ReportError(f"{path}: {key} names a node outside 0..{n - 1}")
    return np.asarray(a, np.int64)


def check_scene_summary(a: np.ndarray, where: str) -> dict:
    """result.npz's scene_summary (JSON text) as a dict, its numbers checked: the materials'
    strains and tensions, friction_mu, the standards' class limits (a string or a list where a
    number belongs is refused naming the key; strings are escaped by the page)."""
    if a.dtype.kind != "U" or a.size != 1:
        raise ReportError(f"{where}: not text")
    try:
        d = json.loads(str(a.reshape(-1)[0]))
    except (json.JSONDecodeError, RecursionError, ValueError):
        raise ReportError(f"{where}: not valid JSON") from None
    c = _Check(where)
    c.obj(d, "scene_summary")
    c.number(d, "friction_mu", "friction_mu")
    for i, r in enumerate(c.items(d.get("friction_regions"), "friction_regions")):
        c.obj(r, f"friction_regions[{i}]")
        c.number(r, "friction", f"friction_regions[{i}].friction", null=False)
        if not isinstance(r.get("nodes"), str):
            c.fail(f"friction_regions[{i}].nodes", "not text", r.get("nodes"))
    c.number(d, "node_count", "node_count", integer=True)
    for i, m in enumerate(c.items(d.get("materials"), "materials")):
        c.obj(m, f"materials[{i}]")
        for name in ("strain", "tension_n_per_m"):
            vals = c.items(m.get(name), f"materials[{i}].{name}")
            coords = dict(enumerate(vals))
            for j in range(len(vals)):
                vals[j] = c.number(coords, j, f"materials[{i}].{name}[{j}]", null=False)
        if len(m.get("strain") or []) != len(m.get("tension_n_per_m") or []):
            c.fail(f"materials[{i}]", "strain and tension_n_per_m differ in length")
    for i, st in enumerate(c.items(d.get("standards"), "standards")):
        c.obj(st, f"standards[{i}]")
        for j, cl in enumerate(c.items(st.get("classes"), f"standards[{i}].classes")):
            c.obj(cl, f"standards[{i}].classes[{j}]")
            c.number(cl, "min", f"standards[{i}].classes[{j}].min", null=False)
            c.number(cl, "max", f"standards[{i}].classes[{j}].max")
    for i, f in enumerate(c.items(d.get("files"), "files")):
        c.obj(f, f"files[{i}]")
    c.items(d.get("stages"), "stages")
    return d

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


REPORT_NEEDS = ("summary.json", "result.npz")
#: each file of a result folder the report reads: (size cap [bytes], what it is in messages)
RESULT_INPUTS = {"summary.json": (SUMMARY_LIMIT, "run summary"), "result.npz": (NPZ_LIMIT, "result file"),
                 "history.csv": (HISTORY_LIMIT, "history file"), "levels.csv": (LEVELS_LIMIT, "levels file")}


def check_result_dir(result_dir: str | Path) -> Path:
    """The result folder, checked: it exists, is a folder and holds summary.json and result.npz
    (what ``clothsim run --out`` and ``fit --out`` write), each (and history.csv and levels.csv
    when there are) a regular file under its size cap and no link out of the folder
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


def build_report(result_dir: str | Path, pmax: float | None = None) -> str:
    """The report's HTML text for a result folder (see the module docstring). Raises ReportError
    (naming the file) for a folder that is not a result folder or holds a damaged file."""
    out = check_result_dir(result_dir)
    s = check_summary(read_summary(out / "summary.json"), out / "summary.json")
    history = read_history(out / "history.csv")
    fields = read_fields(out, s)
    levels = read_levels(out / "levels.csv", ReportError)
    from .report_html import build_html

    try:
        return build_html(s, history, fields, levels, pmax)
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        raise ReportError(f"{out / 'summary.json'}: not a run summary clothsim wrote "
                          f"({type(exc).__name__}: {excerpt(exc, 80, quote=False)})") from None


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


def write_report(result_dir: str | Path, path: str | Path | None = None, pmax: float | None = None) -> Path:
    """Write the report (default RESULT_DIR/report.html); returns its path. Raises ReportError
    (naming the file and the problem) for a bad result folder or a path that cannot be written."""
    from ..fileio import describe_write_error
    from ..results import atomic_write_bytes

    check_result_dir(result_dir)
    target = Path(path) if path else Path(result_dir) / "report.html"
    flag = "--out" if path else "report"
    check_report_path(target, flag)
    text = build_report(result_dir, pmax)
    try:
        atomic_write_bytes(target, text.encode("utf-8"))
    except OSError as exc:
        raise ReportError(describe_write_error(exc, target, flag)) from None
    return target
