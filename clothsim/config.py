"""Scene files: pydantic models, YAML load/save, ``--set`` overrides, error messages with file,
line and field path.

A scene is everything needed to repeat a run: fabric (size, divisions, warp/weft tables),
constraints, the initial deformation, the mold, the optional terms of eq. (1) and the solver
settings. Units are SI (m, N, Pa, N/m).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, Literal, Union

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .compression.spec import Classes, Probe, Profile, check_compression
from .material import MaterialError, Table, check_table, read_table_csv

SOLVER_METHODS = ("auto", "paper", "newton")
NODE_SETS = (
    "perimeter", "left", "right", "bottom", "top",
    "bottom_left", "bottom_right", "top_left", "top_right", "corners", "all",
)


from .errors import SceneError  # noqa: E402  (re-exported: clothsim.config.SceneError)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False)


def _finite(v, name="value"):
    if v is not None and not math.isfinite(v):
        raise ValueError(f"must be finite (got {v})")
    return v


def _positive(v):
    """None, or a positive finite number (else the validation message every such field gives)."""
    if v is not None and not (math.isfinite(v) and v > 0):
        raise ValueError(f"must be positive and finite (got {v})")
    return v


class MaterialSpec(_Strict):
    """A piecewise-linear tension-only table along one yarn direction.

    Either ``strain`` with ``stress`` [Pa] (needs ``fabric.thickness``) or with ``tension`` [N/m]
    (force per width, as strip tests report), or ``csv: path`` with a header
    ``strain,stress`` or ``strain,tension``, or ``preset: name`` (see clothsim.presets).
    ``scale`` (dimensionless, > 0; omitted = 1) multiplies the table's stress or tension values,
    so one field varies a material's stiffness (material sweeps) whatever its source."""

    strain: list[float] | None = None
    stress: list[float] | None = None
    tension: list[float] | None = None
    csv: str | None = None
    preset: str | None = None
    scale: float | None = None

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        return _positive(v)

    @model_validator(mode="after")
    def _check(self):
        given = [k for k in ("stress", "tension", "csv", "preset") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of stress, tension, csv or preset"
                             + (f" (got {', '.join(given)})" if given else ""))
        if given[0] in ("stress", "tension"):
            if self.strain is None:
                raise ValueError("strain: missing")
            try:
                check_table(self.strain, getattr(self, given[0]), given[0])
            except MaterialError as exc:
                raise ValueError(str(exc)) from None
        elif self.strain is not None:
            raise ValueError(f"strain: not used with {given[0]}")
        if self.preset is not None:
            from .presets import PRESETS
            if self.preset not in PRESETS:
                raise ValueError(f"preset: unknown '{self.preset}' (known: {', '.join(sorted(PRESETS))})")
        return self


class Fabric(_Strict):
    """The rectangular sheet: size [m] warp (x) by weft (y), lying in z = origin_z, divisions
    nx x ny, thickness [m] (needed with stress tables), warp and weft tables."""

    size: tuple[float, float]
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    divisions: tuple[int, int]
    thickness: float | None = None
    warp: MaterialSpec
    weft: MaterialSpec

    @field_validator("size")
    @classmethod
    def _size(cls, v):
        for x in v:
            _positive(x)
        return v

    @field_validator("origin")
    @classmethod
    def _origin(cls, v):
        for x in v:
            _finite(x)
        return v

    @field_validator("divisions")
    @classmethod
    def _div(cls, v):
        for x in v:
            if x < 1:
                raise ValueError(f"must be at least 1 (got {x})")
        if (v[0] + 1) * (v[1] + 1) > 4_000_000:
            raise ValueError(f"too many nodes ({(v[0] + 1) * (v[1] + 1)}; at most 4,000,000)")
        return v

    @field_validator("thickness")
    @classmethod
    def _thick(cls, v):
        return _positive(v)

    @model_validator(mode="after")
    def _needs_thickness(self):
        for name in ("warp", "weft"):
            m = getattr(self, name)
            if m.stress is not None and self.thickness is None:
                raise ValueError(f"thickness: needed because {name} is given as stress [Pa]")
        return self


IndexRange = tuple[int, int]


class NodeRange(_Strict):
    """Explicit inclusive index ranges; negative indices count from the end (-1 = last)."""

    i: IndexRange | int | None = None
    j: IndexRange | int | None = None


class Constraint(_Strict):
    """Nodes held on some axes (paper 3.2.3), optionally moved before relaxing.

    nodes: a named set (perimeter, left, right, bottom, top, corners, bottom_left, ...) or
    index ranges ``{i: [a, b], j: [c, d]}``. axes: the constrained axes, any of x, y, z.
    displacement [m]: added to the selected nodes. stretch: scale factor (or [sx, sy]) about the
    sheet centre in the sheet plane, applied to the selected nodes."""

    nodes: Union[Literal[NODE_SETS], NodeRange]  # type: ignore[valid-type]
    axes: str = "xyz"
    displacement: tuple[float, float, float] | None = None
    stretch: float | tuple[float, float] | None = None

    @field_validator("nodes", mode="before")
    @classmethod
    def _nodes(cls, v):
        if isinstance(v, str) and v not in NODE_SETS:
            raise ValueError(f"unknown node set '{v}' (known: {', '.join(NODE_SETS)}; or give {{i: [a, b], j: [c, d]}})")
        if not isinstance(v, (str, dict)) and not isinstance(v, NodeRange):
            raise ValueError(f"must be a node set name or {{i: [a, b], j: [c, d]}} (got {v!r})")
        return v

    @field_validator("axes")
    @classmethod
    def _axes(cls, v):
        if not v or any(c not in "xyz" for c in v) or len(set(v)) != len(v):
            raise ValueError(f"must be a non-empty subset of 'xyz' (got '{v}')")
        return v

    @field_validator("stretch")
    @classmethod
    def _stretch(cls, v):
        vals = [v] if isinstance(v, (int, float)) else (list(v) if v is not None else [])
        for s in vals:
            if not (math.isfinite(s) and s > 0):
                raise ValueError(f"must be positive (got {s})")
        return v

    @field_validator("displacement")
    @classmethod
    def _disp(cls, v):
        if v is not None:
            for x in v:
                _finite(x)
        return v


class Wrap(_Strict):
    """Initial sheet wrapped on a cylinder around a mold (the paper's torso set-up): the sheet's
    warp (x) direction goes round the cylinder's axis, weft along it."""

    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = Field(gt=0)
    start_angle: float = 0.0  # degrees, where the sheet's left edge sits


class Initial(_Strict):
    """The initial deformation that keeps the sheet off the mold (paper 3.1).

    lift [m]: interior nodes raised along +z by a smooth dome of this height.
    file: an earlier result's positions (nx+1, ny+1, 3) provide the free coordinates.
    wrap: the sheet rolled onto a cylinder. perturb [m] with seed: a random perturbation of the
    free coordinates (tests start from perturbed states). auto_clearance: lift the sheet just
    clear of the mold if it touches it, instead of refusing the scene. interpolate (default true):
    free nodes start with the in-plane stretch of the constrained ones spread smoothly over the
    sheet (harmonic interpolation), a far better start than the paper's literal one (constrained
    nodes moved alone), which ``interpolate: false`` restores."""

    lift: float = 0.0
    file: str | None = None
    wrap: Wrap | None = None
    perturb: float = 0.0
    seed: int = 0
    auto_clearance: bool = False
    interpolate: bool = True

    @field_validator("lift", "perturb")
    @classmethod
    def _fin(cls, v):
        return _finite(v)


class Gravity(_Strict):
    """Gravity (eq. 1, W): areal density [kg/m^2] times g [m/s^2] along direction."""

    areal_density: float = Field(gt=0)
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    g: float = 9.80665

    @field_validator("direction")
    @classmethod
    def _dir(cls, v):
        if not all(math.isfinite(x) for x in v) or sum(x * x for x in v) == 0:
            raise ValueError(f"must be a non-zero finite vector (got {list(v)})")
        return v


class SpringTerm(_Strict):
    """An optional linear spring family (shear diagonals or bending skip-one springs) with
    tension per width ``stiffness * strain`` [N/m], resisting tension and compression."""

    stiffness: float = Field(gt=0)


class Seam(_Strict):
    """A sewn seam (eq. 1, F_seams): node line ``a`` is sewn to node line ``b`` of the same sheet,
    node by node in index order (``reverse: true`` pairs a's first node with b's last). Each pair
    is joined by a zero-length linear spring, the sewing force ``k * gap`` [N] pulling the two
    nodes together, with ``k = stiffness x`` the pair's share of the seam length [m].

    a, b: node sets or index ranges as in constraints; each must select one line of nodes (a
    single i or a single j) and both the same number of nodes. stiffness [N/m per metre of seam,
    N/m^2]: omitted = 1000 x the stiffest slope of the warp and weft tables / the smaller grid
    spacing, so that the seam opens by about a thousandth of a grid spacing times the strain
    across it (``summary.json: max_seam_gap_m`` says by how much)."""

    a: Union[Literal[NODE_SETS], NodeRange]  # type: ignore[valid-type]
    b: Union[Literal[NODE_SETS], NodeRange]  # type: ignore[valid-type]
    reverse: bool = False
    stiffness: float | None = None

    @field_validator("a", "b", mode="before")
    @classmethod
    def _nodes(cls, v):
        return Constraint._nodes(v)

    @field_validator("stiffness")
    @classmethod
    def _k(cls, v):
        return _positive(v)


class SolverSettings(_Strict):
    """method: which solver; C: the paper's step divisor (eq. 4, > 1); e: the convergence limit on
    ||V||_inf [N] (eq. 6); max_iterations; time_limit_s: wall-clock bound (None = none)."""

    method: Literal[SOLVER_METHODS] = "auto"  # type: ignore[valid-type]
    C: float = 2.0
    e: float = 1e-6
    max_iterations: int = 200_000
    time_limit_s: float | None = None
    max_retries: int = 60
    stall_iterations: int = 2000
    # newton only: stiffness used at and below strain 0 on tension-only springs, as a fraction of
    # the table's first slope (regularises the singular Hessian of slack springs; shapes the
    # search direction only, never the forces); and whether to solve coarser grids first
    newton_kink: float = Field(default=1e-3, ge=0.0, le=1e3)
    newton_sequencing: bool = True

    @field_validator("C")
    @classmethod
    def _C(cls, v):
        if not (math.isfinite(v) and v > 1.0):
            raise ValueError(f"must be greater than 1 (got {v})")
        return v

    @field_validator("e")
    @classmethod
    def _e(cls, v):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"must be positive (got {v})")
        return v

    @field_validator("max_iterations", "max_retries", "stall_iterations")
    @classmethod
    def _pos(cls, v):
        if v < 1:
            raise ValueError(f"must be at least 1 (got {v})")
        return v


class Scene(_Strict):
    """A complete, validated scene. ``source`` (not part of the file) is where it was read from;
    relative paths inside resolve against its folder."""

    name: str = "scene"
    fabric: Fabric
    constraints: list[Constraint] = Field(default_factory=list)
    initial: Initial = Field(default_factory=Initial)
    mold: dict[str, Any] | None = None
    gravity: Gravity | None = None
    shear: SpringTerm | None = None
    bending: SpringTerm | None = None
    seams: list[Seam] = Field(default_factory=list)
    solver: SolverSettings = Field(default_factory=SolverSettings)
    # compression engineering (clothsim.compression.spec): sensors, slices along a limb, classes
    probes: list[Probe] = Field(default_factory=list)
    profiles: list[Profile] = Field(default_factory=list)
    classes: Classes | None = None

    model_config = ConfigDict(extra="forbid")
    _source: Path | None = None

    @model_validator(mode="after")
    def _compression_names(self):
        check_compression(self.probes, self.profiles, self.classes)
        return self

    @model_validator(mode="after")
    def _seams_fit(self):
        """Each seam joins two node lines of equal length that do not overlap."""
        if not self.seams:
            return self
        from .selection import SelectionError, seam_pairs
        from .topology import Topology

        topology = Topology.rectangle(*self.fabric.divisions)
        for n, seam in enumerate(self.seams):
            try:
                seam_pairs(seam, topology)
            except SelectionError as exc:
                raise ValueError(f"seams.{n}.{exc}") from None
        return self

    @property
    def base_dir(self) -> Path:
        return self._source.parent if self._source is not None else Path.cwd()

    @property
    def source(self) -> Path | None:
        return self._source

    def resolve(self, p: str | Path) -> Path:
        p = Path(p)
        return p if p.is_absolute() else self.base_dir / p

    def tables(self) -> tuple[Table, Table]:
        """(warp, weft) tension tables [N/m], CSV files and presets resolved."""
        return tuple(self._table(name) for name in ("warp", "weft"))  # type: ignore[return-value]

    def _table(self, name: str) -> Table:
        m: MaterialSpec = getattr(self.fabric, name)
        if m.preset is not None:
            from .presets import PRESETS
            p = PRESETS[m.preset]
            return Table(np.asarray(p.strain, float), np.asarray(getattr(p, name), float) * (m.scale or 1.0))
        if m.csv is not None:
            path = self.resolve(m.csv)
            strain, value, kind = read_table_csv(path)
        else:
            strain = np.asarray(m.strain, float)
            kind = "stress" if m.stress is not None else "tension"
            value = np.asarray(m.stress if m.stress is not None else m.tension, float)
        if kind == "stress":
            if self.fabric.thickness is None:
                raise SceneError(f"fabric.thickness: needed because {name} is given as stress [Pa]")
            value = value * self.fabric.thickness
        return Table(strain, value * (m.scale or 1.0))

    def to_dict(self) -> dict:
        d = self.model_dump(mode="json", exclude_none=True)
        for key in ("probes", "profiles"):  # optional sections: absent unless used
            if not d.get(key):
                d.pop(key, None)
        return d

    def resolved(self) -> "Scene":
        """A copy whose file references (CSV tables, initial file, mold path) are absolute, so the
        scene can be written anywhere and repeated exactly."""
        d = self.to_dict()
        for name in ("warp", "weft"):
            if d["fabric"][name].get("csv"):
                d["fabric"][name]["csv"] = str(self.resolve(d["fabric"][name]["csv"]))
        if d.get("initial", {}).get("file"):
            d["initial"]["file"] = str(self.resolve(d["initial"]["file"]))
        if d.get("mold") and d["mold"].get("path"):
            d["mold"]["path"] = str(self.resolve(d["mold"]["path"]))
        out = Scene.model_validate(d)
        out._source = self._source
        return out

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


# ----------------------------------------------------------------------------- loading


def _yaml_line(root: yaml.Node | None, loc: tuple) -> int | None:
    """Line (1-based) of the YAML node at path loc, or of the key of its deepest existing ancestor."""
    node = root
    line = root.start_mark.line + 1 if root is not None else None
    for key in loc:
        nxt = None
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if str(k.value) == str(key):
                    nxt = v
                    line = k.start_mark.line + 1
                    break
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
            nxt = node.value[key]
            line = nxt.start_mark.line + 1
        if nxt is None:
            break
        node = nxt
    return line


def _clean_loc(loc: tuple) -> tuple:
    """Drop pydantic's union/literal branch tags from a location."""
    out = []
    for part in loc:
        if isinstance(part, str) and (part.startswith("function-") or part in (
                "literal['perimeter','left','right','bottom','top','bottom_left','bottom_right','top_left','top_right','corners','all']",
                "NodeRange", "tuple[float, float]", "float", "int", "tuple[int, int]", "list[float]")):
            continue
        if isinstance(part, str) and part.startswith("literal["):
            continue
        out.append(part)
    return tuple(out)


def format_validation_error(exc: ValidationError, source: str, root: yaml.Node | None) -> str:
    """One line per problem: ``file:line: field.path: message``."""
    lines = []
    seen = set()
    for err in exc.errors():
        loc = _clean_loc(tuple(err["loc"]))
        msg = err["msg"]
        for prefix in ("Value error, ", "Assertion failed, "):
            if msg.startswith(prefix):
                msg = msg[len(prefix):]
        field = ".".join(str(p) for p in loc)
        # a model-level validator reports "sub: message" (sub may be a dotted path such as
        # seams.0.b): fold the sub-field into the path
        head = msg.split(": ", 1)[0] if ": " in msg else ""
        if head and " " not in head and all(p.replace("_", "").isalnum() for p in head.split(".")):
            sub, msg = msg.split(": ", 1)
            loc = loc + tuple(int(p) if p.isdigit() else p for p in sub.split("."))
            field = ".".join(str(p) for p in loc)
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
        elif err["type"] == "missing":
            msg = "missing"
        line = _yaml_line(root, loc) if root is not None else None
        where = f"{source}:{line}" if line else source
        text = f"{where}: {field}: {msg}" if field else f"{where}: {msg}"
        if (field, msg) in seen:
            continue
        seen.add((field, msg))
        lines.append(text)
    # union errors produce one entry per branch; keep the most specific ones
    return "\n".join(lines)


def _set_path(data: dict, path: str, value: Any) -> None:
    parts = path.split(".")
    node: Any = data
    for n, part in enumerate(parts):
        last = n == len(parts) - 1
        if isinstance(node, list):
            try:
                idx = int(part)
            except ValueError:
                raise SceneError(f"--set {path}: '{part}' is not a list index") from None
            if not -len(node) <= idx < len(node):
                raise SceneError(f"--set {path}: index {idx} out of range (list has {len(node)} items)")
            if last:
                node[idx] = value
            else:
                node = node[idx]
        else:
            if not isinstance(node, dict):
                raise SceneError(f"--set {path}: '{'.'.join(parts[:n])}' is not a mapping")
            if last:
                node[part] = value
            else:
                if node.get(part) is None:
                    node[part] = {}
                node = node[part]


def apply_overrides(data: dict, overrides: list[str] | dict[str, Any] | None) -> dict:
    """Return a copy of the raw scene dict with ``field.path=value`` overrides applied (values
    are parsed as YAML, so ``[80, 80]`` is a list and ``3`` a number)."""
    data = copy.deepcopy(data)
    if not overrides:
        return data
    items = overrides.items() if isinstance(overrides, dict) else []
    if not isinstance(overrides, dict):
        parsed = []
        for o in overrides:
            if "=" not in o:
                raise SceneError(f"--set {o}: expected field.path=value")
            k, v = o.split("=", 1)
            try:
                parsed.append((k.strip(), yaml.safe_load(v)))
            except yaml.YAMLError as exc:
                raise SceneError(f"--set {o}: value is not valid YAML ({exc})") from None
        items = parsed
    for k, v in items:
        _set_path(data, k, v)
    return data


def scene_from_dict(data: dict, source: str | Path | None = None, root: yaml.Node | None = None) -> Scene:
    """Validate a raw dict into a Scene; errors become SceneError with file:line: field: message."""
    label = str(source) if source is not None else "<scene>"
    if not isinstance(data, dict):
        raise SceneError(f"{label}: a scene must be a mapping (got {type(data).__name__})")
    try:
        scene = Scene.model_validate(data)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, label, root)) from None
    if source is not None:
        scene._source = Path(source).resolve()
    return scene


def read_yaml(path: str | Path, error: type[Exception] = SceneError) -> tuple[Any, yaml.Node | None]:
    """(data, node tree) of a YAML file; the tree gives line numbers for error messages. Failures
    raise ``error`` naming the file (and the line of a syntax error)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return yaml.safe_load(text), yaml.compose(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise error(f"{where}: not valid YAML ({getattr(exc, 'problem', exc)})") from None


def load_scene(path: str | Path, overrides: list[str] | dict[str, Any] | None = None) -> Scene:
    """Read and validate a scene YAML file, applying ``--set`` style overrides."""
    path = Path(path)
    data, root = read_yaml(path)
    if data is None:
        raise SceneError(f"{path}: empty scene file")
    data = apply_overrides(data, overrides)
    return scene_from_dict(data, path, root)


def dump_scene(scene: Scene, path: str | Path) -> None:
    Path(path).write_text(scene.to_yaml(), encoding="utf-8")
