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
import io
import math
import re
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import yaml

from .. import patterns
from ..config import Scene, SceneError, load_scene, scene_from_dict
from ..material import MaterialError, check_table, parse_table_csv
from ..mold import MoldError, cache_mold, load_mold, load_mold_bytes
from ..patterns import PatternError
from ..presets import PRESETS
from ..sizingspec import REDUCTION_RANGE
from .scenes import bundled_match, check_references, check_scene_files, open_bundled, scrub

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
#: 2-5 s per 100,000 triangles on a shared 2-core machine (docs/benchmarks/benchmarks.md, "Mold uploads")
#: and about 2.4 kB of memory per triangle at its peak, so the limit keeps an upload under
#: about half a minute and 1.2 GB; a larger mesh can still be named in a scene file
MOLD_UPLOAD_MAX_TRIANGLES = 500_000
PATTERN_EXTS = (".dxf", ".svg")
#: most bytes of an uploaded pattern file (it is read in a worker thread, the work bounded by
#: clothsim.patternlimits; a garment's DXF-AAMA export is a few hundred kB; the viewer's own upload
#: limit applies too) and most pieces listed from one
PATTERN_UPLOAD_MAX_BYTES = 4 * 1024 * 1024
PATTERN_UPLOAD_MAX_PIECES = 100
#: lattice divisions of a piece added from an uploaded pattern along its longer side
PATTERN_DEFAULT_DIVISIONS = 24
ROTATE_MAX = 3600.0  # [deg]


#: largest friction coefficient a scene takes (config's mold.friction bound)
FRICTION_MAX = 10.0


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
        self.patterns: dict[str, tuple[Path, list]] = {}  # label -> (stored file, its pieces)
        self.pattern_count = 0

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

    def mold_spec(self, label: str, scale, offset, up: str | None = None, surface: str | None = None,
                  smoothing=None) -> dict | None:
        """The spec of mold choice ``label`` with a scale (mesh files) and an offset [m] applied;
        ``up`` ('y' or 'z', mesh files): the file's up axis (None: the choice's own);
        ``surface`` ('auto', 'faceted' or 'smooth', mesh files; None: the choice's own; 'auto':
        smooth for a scan, see :func:`clothsim.mold.build.auto_surface`) and ``smoothing`` [m] (the
        smooth surface's blending radius; 0 or None: the mesh's own default)."""
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
            if surface is not None:
                if surface not in ("auto", "faceted", "smooth"):
                    raise MoldError(f"surface: must be 'auto', 'faceted' or 'smooth' (got {str(surface)[:20]!r})")
                spec.pop("smoothing", None)
                if surface == "faceted":
                    spec["surface"] = "faceted"
                elif surface == "smooth":
                    spec["surface"] = "smooth"
                    r = as_float(0.0 if smoothing is None else smoothing, "smoothing [m]", 0.0, ABS_LENGTH_MAX)
                    if r > 0:
                        spec["smoothing"] = r
                else:
                    spec.pop("surface", None)
        elif any(off):
            _kind, prm = next(iter(spec.items()))
            for key in ("center", "point", "min", "max"):
                if key in prm:
                    prm[key] = [a + b for a, b in zip(prm[key], off)]
        return spec

    def friction(self) -> float:
        """The draft's friction coefficient mu between the fabric and the mold (0: frictionless)."""
        return float((self.data.get("mold") or {}).get("friction") or 0.0)

    def set_friction(self, mu) -> Scene:
        """``mold.friction``: Coulomb's mu between the fabric and the mold, 0 to 10 (0 leaves the
        field out: the frictionless scene, bit for bit). A stage that sets ``mold.friction``
        overrides it from that stage on."""
        v = as_float(mu, "friction mu", 0.0, FRICTION_MAX)
        if self.data.get("mold") is None:
            if v == 0.0:
                return self.validate()
            raise ValueError("friction mu: the scene has no mold to have friction with")

        def mutate(d):
            if v > 0:
                d["mold"]["friction"] = v
            else:
                d["mold"].pop("friction", None)

        return self.edit("friction", mutate)

    def set_mold(self, spec: dict | None):
        """Make ``spec`` the draft's mold (with the draft's friction coefficient and regions); returns the
        loaded Mold (parsed now, so that a broken file is refused here) or None for no mold."""
        mu = self.friction()
        regions = (self.data.get("mold") or {}).get("friction_regions")
        if spec is not None:
            spec = {k: v for k, v in spec.items() if k not in ("friction", "friction_regions")} \
                | ({"friction": mu} if mu > 0 else {}) | ({"friction_regions": regions} if regions else {})
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

    # ------------------------------------------------------------------ panels
    def panel_names(self) -> list[str]:
        return [p["name"] for p in self.data.get("panels", [])]

    def _panel_index(self, index) -> int:
        n = len(self.data.get("panels", []))
        if index is None or not isinstance(index, int) or not 0 <= index < n:
            raise SceneError("pick a panel" if n else "the scene has no pattern panels")
        return index

    def placement(self, index: int) -> tuple[str, dict]:
        """('transform' | 'wrap' | 'wrap_hull', its fields) of panel ``index`` (an omitted
        placement is the identity transform)."""
        pl = self.data["panels"][self._panel_index(index)].get("placement") or {}
        for kind in ("wrap", "wrap_hull", "transform"):
            if pl.get(kind) is not None:
                return kind, pl[kind]
        return "transform", {}

    def set_transform(self, index: int, translate, rotate) -> Scene:
        """Panel ``index`` placed rigidly: rotate [deg] about x, then y, then z, then translate [m]
        (clothsim.config.PanelTransform). A panel that was wrapped becomes a rigid placement."""
        i = self._panel_index(index)
        t = [as_float(x, "translate [m]", -ABS_LENGTH_MAX, ABS_LENGTH_MAX) for x in translate]
        r = [as_float(x, "rotate [deg]", -ROTATE_MAX, ROTATE_MAX) for x in rotate]
        return self.edit("panels", lambda d: d["panels"][i].__setitem__(
            "placement", {"transform": {"rotate": r, "translate": t}}))

    def set_wrap(self, index: int, radius, axis) -> Scene:
        """Panel ``index`` rolled round ``axis`` at ``radius`` [m] (clothsim.config.Wrap; its
        centre and start angle kept). Only for a panel placed with ``wrap``."""
        i = self._panel_index(index)
        kind, _w = self.placement(i)
        if kind != "wrap":
            raise SceneError(f"panels.{i}.placement: not a wrap placement (it is {kind}); edit it in the scene file")
        rad = as_float(radius, "wrap radius [m]", 0.0, ABS_LENGTH_MAX)
        ax = [as_float(x, "wrap axis", -ABS_LENGTH_MAX, ABS_LENGTH_MAX) for x in axis]
        return self.edit("panels", lambda d: d["panels"][i]["placement"]["wrap"].update(radius=rad, axis=ax))

    def reduction(self) -> float | None:
        """The garment's reduction [%] (clothsim.sizing), None when not given; the key ``levels``
        says whether the scene has measuring levels to reduce at."""
        g = self.data.get("garment") or {}
        r = g.get("reduction")
        return None if r is None else float(r)

    def has_levels(self) -> bool:
        return bool((self.data.get("garment") or {}).get("levels"))

    def set_reduction(self, value) -> Scene:
        """garment.reduction [%]: the garment's relaxed circumference at every measuring level is
        the body's girth there times (1 - value / 100). Needs the scene's ``garment.levels``."""

        if not self.has_levels():
            raise SceneError("garment.levels: the scene has no measuring levels; give them in the scene file")
        v = as_float(value, "garment reduction [%]", *REDUCTION_RANGE)
        return self.edit("panels", lambda d: d["garment"].update(reduction=v))

    def add_pattern(self, name: str, data: bytes) -> str:
        """Read an uploaded DXF or SVG pattern (clothsim.patterns.read_pattern) from a copy stored
        in ``upload_dir`` under a name chosen here; returns its label (a key of ``patterns``).
        Raises PatternError (file, piece, reason; the browser's file name, never the stored
        path) and refuses a file over PATTERN_UPLOAD_MAX_BYTES or with more than
        PATTERN_UPLOAD_MAX_PIECES pieces. The three steps, for a reader off the update loop:
        :meth:`pattern_slot`, :meth:`parse_pattern` (safe in a worker thread), :meth:`store_pattern`."""
        slot = self.pattern_slot(name, data)
        return self.store_pattern(slot, self.parse_pattern(slot, data))

    def pattern_slot(self, name: str, data: bytes) -> tuple[str, Path]:
        """(label name, stored path) for an upload, after the cheap checks (uploads accepted, a
        .dxf or .svg name, the byte limit); nothing is written yet."""
        label_name = _safe_name(name)
        if self.upload_dir is None:
            raise PatternError("uploads are not accepted here")
        ext = Path(str(name)).suffix.lower()
        if ext not in PATTERN_EXTS:
            raise PatternError(f"{label_name}: a pattern is a .dxf or .svg file (got '{ext or 'no extension'}')")
        if len(data) > PATTERN_UPLOAD_MAX_BYTES:
            raise PatternError(f"{label_name}: {len(data) / 2**20:.1f} MB, over the pattern limit of "
                               f"{PATTERN_UPLOAD_MAX_BYTES / 2**20:.0f} MB")
        self.pattern_count += 1
        return label_name, self.upload_dir / f"pattern_upload_{self.pattern_count}{ext}"

    @staticmethod
    def parse_pattern(slot: tuple[str, Path], data: bytes) -> list:
        """Write the upload to its slot and read its pieces (no draft state is read or changed:
        safe in a worker thread; the reader's bounds keep the work to seconds,
        clothsim.patternlimits). On a refusal the stored copy is removed."""
        label_name, stored = slot
        stored.write_bytes(data)
        try:
            pieces = patterns.read_pattern(stored)
        except PatternError as exc:
            stored.unlink(missing_ok=True)
            raise type(exc)(str(exc).replace(str(stored), label_name)) from None
        except BaseException:
            stored.unlink(missing_ok=True)
            raise
        if len(pieces) > PATTERN_UPLOAD_MAX_PIECES:
            stored.unlink(missing_ok=True)
            raise PatternError(f"{label_name}: {len(pieces)} pieces, more than {PATTERN_UPLOAD_MAX_PIECES}")
        return pieces

    def store_pattern(self, slot: tuple[str, Path], pieces: list) -> str:
        """Offer the pieces :meth:`parse_pattern` read; returns the pattern's label."""
        label_name, stored = slot
        label = f"{label_name} ({stored.stem.rsplit('_', 1)[-1]})"
        self.patterns[label] = (stored, pieces)
        return label

    def pattern_panel(self, label: str, piece: str, at=(0.0, 0.0, 0.0), taken=()) -> dict:
        """The panel spec of ``piece`` of uploaded pattern ``label``: read from the stored file,
        a lattice of PATTERN_DEFAULT_DIVISIONS spacings along its longer side, and placed rigidly
        with the corner of its outline's box at ``at`` [m]; named after the piece (made unique
        against ``taken``)."""
        if label not in self.patterns:
            raise SceneError(f"no uploaded pattern {str(label)[:60]!r}")
        path, pieces = self.patterns[label]
        pc = next((p for p in pieces if p.name == piece), None)
        if pc is None:
            raise SceneError(f"pattern {label[:60]}: no piece {str(piece)[:60]!r}")
        lo, hi = pc.outline.min(axis=0), pc.outline.max(axis=0)
        spacing = float(f"{max(hi - lo) / PATTERN_DEFAULT_DIVISIONS:.3g}")
        name, k = re.sub(r"\s+", "_", pc.name.strip()) or "panel", 1
        base = name
        while name in taken:
            k += 1
            name = f"{base}_{k}"
        at = [float(x) for x in at]
        return {"name": name, "pattern": {"file": str(path), "piece": pc.name}, "spacing": spacing,
                "placement": {"transform": {"translate": [at[0] - float(lo[0]), at[1] - float(lo[1]), at[2]]}}}

    def add_pattern_piece(self, label: str, piece: str, at=(0.0, 0.0, 0.0)) -> Scene:
        """Add ``piece`` of uploaded pattern ``label`` as a new panel (:meth:`pattern_panel`).
        A scene that is a ``fabric:`` rectangle has no panels to add to: the piece replaces the
        rectangle (see :meth:`replace_panels`)."""
        if not self.data.get("panels"):
            return self.replace_panels(label, [piece], at)
        spec = self.pattern_panel(label, piece, at, taken=set(self.panel_names()))
        return self.edit("panels", lambda d: d["panels"].append(spec))

    def replace_panels(self, label: str, pieces=None, at=(0.0, 0.0, 0.0)) -> Scene:
        """Make the pieces of uploaded pattern ``label`` (``pieces``: their names; None: all)
        the scene's panels, side by side from ``at`` [m] along x, 2 cm apart. The old panels'
        seams go (they name the old panels), and so do constraints naming an old panel; the
        rectangle's size and divisions go too (the fabric keeps its tables)."""
        if label not in self.patterns:
            raise SceneError(f"no uploaded pattern {str(label)[:60]!r}")
        all_pieces = self.patterns[label][1]
        names = [p.name for p in all_pieces] if pieces is None else list(pieces)
        x, specs, taken = float(at[0]), [], set()
        for nm in names:
            spec = self.pattern_panel(label, nm, (x, at[1], at[2]), taken)
            taken.add(spec["name"])
            specs.append(spec)
            pc = next(p for p in all_pieces if p.name == nm)
            x += float(pc.outline[:, 0].max() - pc.outline[:, 0].min()) + 0.02

        def mutate(d):
            d["panels"] = specs
            d.pop("seams", None)
            for k in ("size", "divisions"):
                d["fabric"].pop(k, None)
            d["constraints"] = [c for c in d.get("constraints", [])
                                if not (isinstance(c.get("nodes"), dict) and c["nodes"].get("panel") is not None
                                        and c["nodes"]["panel"] not in taken)]
            init = d.get("initial") or {}
            for k in ("wrap", "wrap_hull", "file"):
                init.pop(k, None)

        return self.edit("panels", mutate)

    # ------------------------------------------------------------------ files
    def scene_yaml(self) -> str:
        """The draft as YAML, file paths made absolute so it loads from wherever it is saved."""
        scene = self.validate().resolved()
        head = f"# saved by the clothsim viewer on {time.strftime('%Y-%m-%d %H:%M')}\n"
        mold = self.data.get("mold") or {}  # the draft's own spec (a dict, as in the YAML)
        if self.upload_dir is not None and str(self.upload_dir) in str(mold.get("path", "")):
            head += ("# the mold was uploaded: its temporary copy disappears when the viewer stops; "
                     "'Save scene + files (.zip)' keeps it\n")
        if self.upload_dir is not None and any(str(self.upload_dir) in str((p.get("pattern") or {}).get("file", ""))
                                               for p in self.data.get("panels", [])):
            head += ("# a panel's pattern was uploaded: its temporary copy disappears when the viewer stops; "
                     "'Save scene + files (.zip)' keeps it\n")
        if self.pending:
            head += f"# includes edits not yet applied in the viewer: {', '.join(sorted(self.pending))}\n"
        return head + scene.to_yaml()

    def scene_zip(self) -> bytes:
        """The draft and the files it references (an uploaded mold included) as a zip that reruns
        anywhere (see :func:`scene_zip_bytes`)."""
        head = (f"# saved by the clothsim viewer on {time.strftime('%Y-%m-%d %H:%M')}\n"
                "# unzip and run: python app.py run scene.yaml (file references are relative to this file)\n")
        if self.pending:
            head += f"# includes edits not yet applied in the viewer: {', '.join(sorted(self.pending))}\n"
        return scene_zip_bytes(self.validate(), head)


# ---------------------------------------------------------------------- scene files: zip, open
SCENE_EXTS = (".yaml", ".yml", ".zip")
ZIP_MAX_MEMBERS = 200


def _safe_name(name: str) -> str:
    """A plain file name (letters, digits, '._-'), never a path."""
    base = re.sub(r"[^A-Za-z0-9._-]", "_", Path(str(name)).name)[:80].lstrip(".")
    return base or "file"


def scene_zip_bytes(scene: Scene, head: str = "") -> bytes:
    """A zip holding ``scene.yaml`` and every file the scene references (mold mesh, CSV tables,
    pattern files, initial positions) under ``files/``, the scene's references rewritten to those
    relative paths: unzip it anywhere and ``python app.py run scene.yaml`` reruns it. The mold is
    stored as ``files/mold<ext>``, the others under their own names."""
    d = scene.resolved().to_dict()
    stored: dict[str, str] = {}  # source path -> name in the zip
    used: set[str] = set()

    def add(path: str, name: str | None = None) -> str:
        src = str(Path(path).resolve())
        if src not in stored:
            arc = "files/" + (name or _safe_name(Path(src).name))
            k = 1
            while arc in used:
                k += 1
                stem, ext = Path(arc).stem, Path(arc).suffix
                arc = f"files/{stem}_{k}{ext}"
            used.add(arc)
            stored[src] = arc
        return stored[src]

    if (d.get("mold") or {}).get("path"):
        d["mold"]["path"] = add(d["mold"]["path"], "mold" + Path(d["mold"]["path"]).suffix.lower())
    for panel in d.get("panels", []):
        if panel.get("pattern"):
            panel["pattern"]["file"] = add(panel["pattern"]["file"])
    for holder in [d["fabric"]] + d.get("panels", []):
        for key in ("warp", "weft"):
            if (holder.get(key) or {}).get("csv"):
                holder[key]["csv"] = add(holder[key]["csv"])
    if d.get("initial", {}).get("file"):
        d["initial"]["file"] = add(d["initial"]["file"])
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("scene.yaml", head + yaml.safe_dump(d, sort_keys=False))
        for src, arc in stored.items():
            z.write(src, arc)
    return buf.getvalue()


def open_scene_upload(name: str, data: bytes, dest: Path, limit_bytes: int) -> Scene:
    """A scene uploaded to the viewer (a ``.yaml`` or a ``.zip`` as *Save scene + files* writes
    it), validated like a scene file given on the command line. The file (or the zip's members)
    is written into ``dest``, a new private folder, so that relative references resolve inside it.
    A zip must hold exactly one ``.yaml`` at its top level (``scene.yaml`` preferred), at most
    ZIP_MAX_MEMBERS members of at most ``limit_bytes`` in all once unpacked, no absolute path,
    no ``..`` and no link. The scene may name only files of the upload (:func:`check_references`:
    a relative name inside ``dest``), which are read before it is returned
    (:func:`check_scene_files`). A ``.yaml`` whose bytes are those of a bundled scene
    (``configs/``) is opened from there instead, its files resolved beside it. Raises SceneError
    (or MoldError, MaterialError) with the uploaded file's name and the line and field, never
    ``dest``."""
    label = _safe_name(name)
    ext = Path(str(name)).suffix.lower()
    if ext not in SCENE_EXTS:
        raise SceneError(f"{label}: a scene is a .yaml file or a .zip of scene.yaml and its files (got '{ext or 'no extension'}')")
    bundled = bundled_match(data) if ext != ".zip" else None
    if bundled is not None:  # a scene from configs/: its files are beside it, not in the upload
        return open_bundled(bundled)
    dest.mkdir(mode=0o700, parents=True, exist_ok=False)
    if ext == ".zip":
        try:
            z = zipfile.ZipFile(io.BytesIO(data))
            infos = z.infolist()
        except (zipfile.BadZipFile, ValueError, OSError) as exc:
            raise SceneError(f"{label}: not a readable zip ({exc})") from None
        if len(infos) > ZIP_MAX_MEMBERS:
            raise SceneError(f"{label}: {len(infos)} members, more than {ZIP_MAX_MEMBERS}")
        if sum(i.file_size for i in infos) > limit_bytes:
            raise SceneError(f"{label}: unpacks to more than the upload limit of {limit_bytes / 2**20:.0f} MB")
        for i in infos:
            parts = Path(i.filename).parts
            is_link = (i.external_attr >> 16) & 0o170000 == 0o120000
            if i.filename.startswith(("/", "\\")) or ".." in parts or ":" in i.filename or is_link:
                raise SceneError(f"{label}: member {i.filename[:60]!r} is not a plain relative path")
        yamls = [i.filename for i in infos if "/" not in i.filename.rstrip("/")
                 and Path(i.filename).suffix.lower() in (".yaml", ".yml")]
        if "scene.yaml" in yamls:
            yamls = ["scene.yaml"]
        if len(yamls) != 1:
            raise SceneError(f"{label}: the zip must hold one scene .yaml at its top level (found "
                             f"{', '.join(yamls) or 'none'})")
        written = 0
        for i in infos:
            if i.is_dir():
                continue
            target = dest / i.filename
            target.parent.mkdir(parents=True, exist_ok=True)
            with z.open(i) as src:
                blob = src.read(limit_bytes + 1 - written)
            written += len(blob)
            if written > limit_bytes:
                raise SceneError(f"{label}: unpacks to more than the upload limit of {limit_bytes / 2**20:.0f} MB")
            target.write_bytes(blob)
        path = dest / yamls[0]
    else:
        path = dest / label
        path.write_bytes(data)

    try:
        scene = load_scene(path)
        check_references(scene, dest)
        check_scene_files(scene)
    except (SceneError, MoldError, MaterialError) as exc:
        raise type(exc)(scrub(str(exc), path, dest, label)) from None
    return scene
