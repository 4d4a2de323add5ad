"""The viewer's scene draft: the edited scene the panels change, with one typed operation per kind
of edit. No viser import: everything here is testable without a server or a browser.

Every operation validates the *whole* scene before anything changes: an invalid edit raises
(SceneError, MaterialError, MoldError or ValueError, with a message meant for the user) and leaves
the draft exactly as it was. A valid model edit is recorded in :attr:`SceneDraft.pending` (the
groups waiting for *Apply*); solver settings are not model edits (the viewer sends them to the
running relaxation) and are only mirrored here so that the saved scene carries them.
"""

from __future__ import annotations

import copy
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

from ..config import Scene, SceneError, scene_from_dict
from ..material import MaterialError, check_table, parse_table_csv
from ..mold import MoldError, cache_mold, load_mold, load_mold_bytes
from ..presets import PRESETS

ROOT = Path(__file__).resolve().parent.parent.parent
MOLD_DIR = ROOT / "static" / "molds"
MOLD_EXTS = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf", ".txt", ".pts", ".tri", ".vtk", ".wrl", ".vrml")
AXES_CHOICES = ("xyz", "xy", "xz", "yz", "x", "y", "z")
RANGE_NODES = "(index ranges)"
SCENE_MOLD = "scene's mold"

#: Bounds of the numeric editors (issue: an unbounded integer typed into a field used to reach
#: viser's message stream and break it for every tab). Generous for any real scene; the model's
#: own memory check decides what a machine can build.
MAX_ITERATIONS_MAX = 10**9
DIVISIONS_MAX = 10_000
ABS_LENGTH_MAX = 1e3  # [m] sizes, offsets, lifts and displacements
STRETCH_MAX = 100.0
C_MAX = 1e6
THICKNESS_MM_MAX = 1e3  # [mm]
MOLD_SCALE_MAX = 1e6
#: most triangles an uploaded mold may have: parsing and building its search tree takes about
#: 2-5 s per 100,000 triangles on a shared 2-core machine (docs/benchmarks.md, "Mold uploads")
#: and about 2.4 kB of memory per triangle at its peak, so the limit keeps an upload under
#: about half a minute and 1.2 GB; a larger mesh can still be named in a scene file
MOLD_UPLOAD_MAX_TRIANGLES = 500_000


def parse_table_text(text: str) -> tuple[list[float], list[float]]:
    """A material table typed as one ``strain, value`` pair per line (comma, semicolon or spaces
    between; ``#`` starts a comment). Raises MaterialError naming the line."""
    strain: list[float] = []
    value: list[float] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        toks = [t for t in re.split(r"[,;\s]+", line) if t]
        if len(toks) != 2:
            raise MaterialError(f"line {n}: expected two numbers 'strain, value' (got '{raw.strip()[:60]}')")
        try:
            a, b = float(toks[0]), float(toks[1])
        except ValueError:
            raise MaterialError(f"line {n}: not a number in '{raw.strip()[:60]}'") from None
        strain.append(a)
        value.append(b)
    return strain, value


def table_text(strain, value) -> str:
    """The inverse of :func:`parse_table_text`: one ``strain, value`` line per point."""
    return "\n".join(f"{float(s):g}, {float(v):g}" for s, v in zip(strain, value))


def as_float(v, name: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """A finite number within [lo, hi], from a widget value (number or text); ValueError otherwise."""
    try:
        x = float(str(v).strip())
    except (ValueError, OverflowError):
        raise ValueError(f"{name}: not a number ('{str(v)[:40]}')") from None
    if not math.isfinite(x):
        raise ValueError(f"{name}: must be a finite number (got {str(v)[:40]})")
    if not lo <= x <= hi:
        raise ValueError(f"{name}: must be between {lo:g} and {hi:g} (got {x:g})")
    return x


def as_int(v, name: str, lo: int, hi: int) -> int:
    """A whole number within [lo, hi] from a widget value; ValueError otherwise (never an int too
    large for the message stream)."""
    try:
        x = float(v)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: not a number ('{str(v)[:40]}')") from None
    if not math.isfinite(x) or x != int(x):
        raise ValueError(f"{name}: must be a whole number (got {str(v)[:40]})")
    if not lo <= x <= hi:
        raise ValueError(f"{name}: must be between {lo} and {hi} (got {str(v)[:40]})")
    return int(x)


def describe_constraint(c: dict) -> str:
    """One line for a constraint spec (the constraints list and the selector)."""
    nodes = c["nodes"] if isinstance(c["nodes"], str) else \
        f"i {c['nodes'].get('i', 'all')}, j {c['nodes'].get('j', 'all')}"
    out = f"{nodes} · axes {c.get('axes', 'xyz')}"
    if c.get("stretch") is not None:
        out += f" · stretch {c['stretch']}"
    if c.get("displacement") is not None:
        out += f" · displacement {list(c['displacement'])} m"
    return out


@dataclass(frozen=True)
class ConstraintEdit:
    """What the constraint editor holds: a named node set (or ``RANGE_NODES`` to keep the edited
    constraint's index ranges), the constrained axes, the stretch (sx, sy) and the
    displacement [m] (dx, dy, dz)."""

    nodes: str
    axes: str
    stretch: tuple[float, float] = (1.0, 1.0)
    displacement: tuple[float, float, float] = (0.0, 0.0, 0.0)


class SceneDraft:
    """The edited scene (a plain dict, as in the YAML) and the edit groups not yet applied.

    ``source`` is the scene file (relative paths resolve against it); ``upload_dir`` is where the
    viewer stores accepted mold uploads (None: uploads are refused)."""

    def __init__(self, scene: Scene, upload_dir: Path | None = None):
        self.source = scene.source
        self.data: dict = scene.to_dict()
        self.pending: set[str] = set()
        self.upload_dir = upload_dir
        self.uploads: dict[str, dict] = {}  # label -> mold spec of an accepted upload
        self.upload_count = 0
        self.scene_mold_spec: dict | None = copy.deepcopy(self.data.get("mold"))

    # ------------------------------------------------------------------ core
    def validate(self, data: dict | None = None) -> Scene:
        """The Scene of ``data`` (default: the draft); raises SceneError with the field's name."""
        return scene_from_dict(copy.deepcopy(self.data if data is None else data), source=self.source)

    def edit(self, group: str, mutate) -> Scene:
        """Apply ``mutate(dict)`` to a copy of the draft; keep it only if the whole scene validates,
        and mark ``group`` pending."""
        new = copy.deepcopy(self.data)
        mutate(new)
        scene = self.validate(new)
        self.data = new
        self.pending.add(group)
        return scene

    def reset_to(self, scene: Scene) -> None:
        """The simulation took a new scene (Apply, Reset): the draft is that scene, nothing pending."""
        self.data = scene.to_dict()
        self.pending.clear()

    # ------------------------------------------------------------------ solver
    def record_solver(self, **kw) -> None:
        """Mirror solver settings the simulation accepted (not a model edit: nothing pending)."""
        self.data.setdefault("solver", {}).update(kw)

    # ------------------------------------------------------------------ fabric
    def set_size(self, lx, ly) -> Scene:
        """Sheet size [m] along warp and weft."""
        size = [as_float(lx, "size (warp)", 0.0, ABS_LENGTH_MAX), as_float(ly, "size (weft)", 0.0, ABS_LENGTH_MAX)]
        return self.edit("fabric", lambda d: d["fabric"].__setitem__("size", size))

    def set_divisions(self, nx, ny) -> Scene:
        """Grid divisions along warp and weft (whole numbers; the scene checks >= 1)."""
        n = [as_int(nx, "warp divisions", -DIVISIONS_MAX, DIVISIONS_MAX),
             as_int(ny, "weft divisions", -DIVISIONS_MAX, DIVISIONS_MAX)]
        return self.edit("fabric", lambda d: d["fabric"].__setitem__("divisions", n))

    def set_lift(self, lift) -> Scene:
        """Initial lift [m] of the sheet above its plane."""
        z = as_float(lift, "initial lift", -ABS_LENGTH_MAX, ABS_LENGTH_MAX)
        return self.edit("fabric", lambda d: d.setdefault("initial", {}).__setitem__("lift", z))

    # ------------------------------------------------------------------ materials
    def set_tables(self, warp: tuple[str, str], weft: tuple[str, str], thickness_mm) -> Scene:
        """Warp and weft tables typed as text, each with its kind ('tension' [N/m] or 'stress'
        [Pa]); ``thickness_mm`` [mm] (0: none; stress needs one)."""
        specs = {}
        for k, (text, kind) in (("warp", warp), ("weft", weft)):
            try:
                strain, value = parse_table_text(text)
                check_table(strain, value, kind)
            except MaterialError as exc:
                raise MaterialError(f"{k}: {exc}") from None
            specs[k] = {"strain": strain, kind: value}
        t = as_float(thickness_mm, "thickness [mm]", 0.0, THICKNESS_MM_MAX)

        def mutate(d):
            d["fabric"]["warp"] = specs["warp"]
            d["fabric"]["weft"] = specs["weft"]
            if t > 0:
                d["fabric"]["thickness"] = t / 1000.0
            else:
                d["fabric"].pop("thickness", None)

        return self.edit("material", mutate)

    def set_preset(self, name: str) -> Scene:
        """Both directions from a material preset (clothsim.presets)."""
        if name not in PRESETS:
            raise MaterialError(f"unknown preset {name!r}")
        return self.edit("material", lambda d: (d["fabric"].__setitem__("warp", {"preset": name}),
                                                d["fabric"].__setitem__("weft", {"preset": name})))

    def preset(self) -> str | None:
        """The preset both directions use, or None (custom tables)."""
        fab = self.data["fabric"]
        presets = {fab[k].get("preset") for k in ("warp", "weft")}
        return presets.pop() if len(presets) == 1 and None not in presets else None

    def material_values(self, key: str) -> tuple[list[float], list[float], str]:
        """(strain, value, 'stress'|'tension') of the warp or weft spec, presets and CSV files
        resolved."""
        spec = self.data["fabric"][key]
        if spec.get("preset"):
            p = PRESETS[spec["preset"]]
            return list(p.strain), list(getattr(p, key)), "tension"
        if spec.get("csv"):
            scene = self.validate()
            text = scene.resolve(spec["csv"]).read_text(encoding="utf-8-sig")
            s, v, kind = parse_table_csv(text, spec["csv"])
            return s.tolist(), v.tolist(), kind
        kind = "stress" if spec.get("stress") is not None else "tension"
        return list(spec["strain"]), list(spec[kind]), kind

    @staticmethod
    def csv_table(name: str, data: bytes) -> tuple[str, str]:
        """An uploaded CSV as (table text, kind); MaterialError if it is not a valid table."""
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise MaterialError(f"{name[:60]}: not a UTF-8 text file") from None
        strain, value, kind = parse_table_csv(text, name[:60])
        return table_text(strain, value), kind

    # ------------------------------------------------------------------ constraints
    def constraints(self) -> list[dict]:
        return self.data.get("constraints", [])

    def save_constraint(self, index: int | None, edit: ConstraintEdit) -> int:
        """Replace constraint ``index`` (None: append a new one); returns its index."""
        cons = self.constraints()
        if index is not None and not 0 <= index < len(cons):
            raise SceneError(f"no constraint {index + 1}")
        nodes = edit.nodes
        if nodes == RANGE_NODES:
            if index is None or isinstance(cons[index]["nodes"], str):
                raise SceneError("nodes: index ranges are edited in the scene YAML; pick a named set here")
            nodes = cons[index]["nodes"]
        if edit.axes not in AXES_CHOICES:
            raise SceneError(f"axes: one of {', '.join(AXES_CHOICES)}")
        c: dict = {"nodes": nodes, "axes": edit.axes}
        sx, sy = (as_float(x, "stretch", 0.0, STRETCH_MAX) for x in edit.stretch)
        if (sx, sy) != (1.0, 1.0):
            c["stretch"] = sx if sx == sy else [sx, sy]
        disp = [as_float(x, "displacement", -ABS_LENGTH_MAX, ABS_LENGTH_MAX) for x in edit.displacement]
        if any(disp):
            c["displacement"] = disp

        def mutate(d):
            lst = d.setdefault("constraints", [])
            if index is None:
                lst.append(c)
            else:
                lst[index] = c

        self.edit("constraints", mutate)
        return len(cons) if index is None else index

    def delete_constraint(self, index: int | None) -> None:
        if index is None or not 0 <= index < len(self.constraints()):
            raise SceneError("pick a constraint to delete")
        self.edit("constraints", lambda d: d["constraints"].pop(index))

    # ------------------------------------------------------------------ mold
    def mold_options(self) -> dict[str, dict | None]:
        """Label -> mold spec (None = no mold): the scene's own, none, the bundled files, three
        primitives placed under the sheet's centre, and the accepted uploads."""
        fab = self.data["fabric"]
        ox, oy, oz = (list(fab.get("origin", (0.0, 0.0, 0.0))) + [0.0, 0.0, 0.0])[:3]
        if "size" in fab:
            lx, ly = fab["size"]
        else:  # pattern panels: the extent of their outlines in their own planes
            pts = [q for p in self.data.get("panels", []) for q in (p.get("outline") or [])]
            lo = [min(q[k] for q in pts) for k in (0, 1)] if pts else [0.0, 0.0]
            hi = [max(q[k] for q in pts) for k in (0, 1)] if pts else [0.1, 0.1]
            ox, oy = lo
            lx, ly = max(hi[0] - lo[0], 1e-3), max(hi[1] - lo[1], 1e-3)
        cx, cy = ox + lx / 2, oy + ly / 2
        L = min(lx, ly)
        opts: dict[str, dict | None] = {}
        if self.scene_mold_spec is not None:
            opts[SCENE_MOLD] = self.scene_mold_spec
        opts["none"] = None
        if MOLD_DIR.is_dir():
            for p in sorted(MOLD_DIR.iterdir()):
                if p.suffix.lower() in MOLD_EXTS:
                    opts[f"file: {p.name}"] = {"path": str(p)}
        opts["sphere"] = {"sphere": {"center": [cx, cy, oz - 0.2 * L], "radius": 0.4 * L}}
        opts["box"] = {"box": {"min": [cx - 0.25 * L, cy - 0.25 * L, oz - 0.5 * L],
                               "max": [cx + 0.25 * L, cy + 0.25 * L, oz + 0.15 * L]}}
        opts["cylinder"] = {"cylinder": {"center": [cx, cy, oz - 0.15 * L], "axis": [0.0, 1.0, 0.0],
                                         "radius": 0.3 * L, "length": 1.5 * ly}}
        opts.update(self.uploads)
        return opts

    def mold_spec(self, label: str, scale, offset, up: str | None = None) -> dict | None:
        """The spec of mold choice ``label`` with a scale (mesh files) and an offset [m] applied;
        ``up`` ('y' or 'z', mesh files): the file's up axis (None: the choice's own)."""
        opts = self.mold_options()
        if label not in opts:
            raise MoldError(f"unknown mold choice {label[:60]!r}")
        spec = copy.deepcopy(opts[label])
        if spec is None:
            return None
        scale = as_float(scale, "mold scale", 0.0, MOLD_SCALE_MAX)
        off = [as_float(x, "mold offset", -ABS_LENGTH_MAX, ABS_LENGTH_MAX) for x in offset]
        if "path" in spec:
            base = float(spec.get("scale", 1.0)) if label == SCENE_MOLD else 1.0
            if not scale > 0:
                raise MoldError(f"scale: must be positive (got {scale})")
            spec["scale"] = base * scale
            if any(off) or "translate" in spec:
                t0 = spec.get("translate", [0.0, 0.0, 0.0])
                spec["translate"] = [a + b for a, b in zip(t0, off)]
            if spec["scale"] == 1.0:
                spec.pop("scale")
            if up is not None:
                if up not in ("y", "z"):
                    raise MoldError(f"up: must be 'y' or 'z' (got {str(up)[:20]!r})")
                if up == "y":
                    spec["up"] = "y"
                else:
                    spec.pop("up", None)
        elif any(off):
            _kind, prm = next(iter(spec.items()))
            for key in ("center", "point", "min", "max"):
                if key in prm:
                    prm[key] = [a + b for a, b in zip(prm[key], off)]
        return spec

    def set_mold(self, spec: dict | None):
        """Make ``spec`` the draft's mold; returns the loaded Mold (parsed now, so that a broken
        file is refused here) or None for no mold."""
        scene = self.validate({**self.data, "mold": spec})  # field-level check first
        mold = load_mold(spec, scene.base_dir) if spec is not None else None
        self.edit("mold", lambda d: d.__setitem__("mold", spec) if spec is not None else d.pop("mold", None))
        return mold

    def add_upload(self, name: str, data: bytes, scale, offset) -> str:
        """Parse an uploaded mold in memory (refused before anything is written if it is broken),
        store it in ``upload_dir`` under a name chosen here (never the browser's) and offer it as
        a mold choice; returns its label."""
        mold = self.parse_upload(name, data, scale, offset)
        return self.store_upload(name, data, mold, scale, offset)

    def parse_upload(self, name: str, data: bytes, scale, offset, progress=None):
        """The Mold of an uploaded file, parsed in memory with the panel's scale and offset (no
        draft state is read or changed: safe in a worker thread). Refuses (MoldError) a mesh of
        more than ``MOLD_UPLOAD_MAX_TRIANGLES`` triangles before the costly build;
        ``progress(fraction, stage)`` as in :func:`clothsim.mold.load_mold_bytes`."""
        if self.upload_dir is None:
            raise MoldError("uploads are not accepted here")
        scale = as_float(scale, "mold scale", 0.0, MOLD_SCALE_MAX)
        off = [as_float(x, "mold offset", -ABS_LENGTH_MAX, ABS_LENGTH_MAX) for x in offset]
        if not scale > 0:
            raise MoldError(f"scale: must be positive (got {scale})")
        return load_mold_bytes(data, name, scale=scale, translate=off, max_triangles=MOLD_UPLOAD_MAX_TRIANGLES,
                               progress=progress)

    def store_upload(self, name: str, data: bytes, mold, scale, offset) -> str:
        """Store an upload parsed by :meth:`parse_upload` (as ``mold``, with this scale and
        offset) and offer it as a mold choice; loading its spec with the same scale and offset
        then finds ``mold`` in the mold cache instead of parsing the file again. Returns its label."""
        if self.upload_dir is None:
            raise MoldError("uploads are not accepted here")
        self.upload_count += 1
        ext = Path(name).suffix.lower()
        stored = self.upload_dir / f"mold_upload_{self.upload_count}{ext if ext in MOLD_EXTS else ''}"
        stored.write_bytes(data)
        label = f"upload: {Path(name).name[:60]}"
        self.uploads[label] = {"path": str(stored)}
        if mold is not None:
            cache_mold(self.mold_spec(label, scale, offset), mold)
        return label

    # ------------------------------------------------------------------ files
    def scene_yaml(self) -> str:
        """The draft as YAML, file paths made absolute so it loads from wherever it is saved."""
        scene = self.validate().resolved()
        head = f"# saved by the clothsim viewer on {time.strftime('%Y-%m-%d %H:%M')}\n"
        mold = self.data.get("mold") or {}  # the draft's own spec (a dict, as in the YAML)
        if self.upload_dir is not None and str(self.upload_dir) in str(mold.get("path", "")):
            head += "# the mold was uploaded: its temporary copy disappears when the viewer stops\n"
        if self.pending:
            head += f"# includes edits not yet applied in the viewer: {', '.join(sorted(self.pending))}\n"
        return head + scene.to_yaml()
