"""Scene files: pydantic models, YAML load/save, ``--set`` overrides, error messages with file,
line and field path.

A scene is everything needed to repeat a run: fabric (size, divisions, warp/weft tables),
constraints, the initial deformation, the mold, the optional terms of eq. (1) and the solver
settings. Units are SI (m, N, Pa, N/m).
"""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
import yaml
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, StrictBool, Tag,
                      ValidationError, field_validator, model_validator)

from .defaults import SOLVER_DEFAULTS
from .compression.levelspec import Levels
from .compression.spec import Classes, Probe, Profile, check_compression
from .legspec import LegParams
from .material import (TENSION_MAX, MaterialError, Table, check_table, read_table_csv,
                       warn_implausible_strain)

SOLVER_METHODS = ("auto", "paper", "newton")
NODE_SETS = (
    "perimeter", "left", "right", "bottom", "top",
    "bottom_left", "bottom_right", "top_left", "top_right", "corners", "all", "outline",
)


from .errors import SceneError  # noqa: E402  (re-exported: clothsim.config.SceneError)
from .fileio import fmt_beyond  # noqa: E402


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False)


#: bound on every coordinate, length and displacement [m]: far beyond any garment or mold, and
#: small enough that squared distances and spring energies cannot overflow a float
COORD_MAX = 1e6
#: bound on gravity's areal density [kg/m^2] (a 1 m thick steel plate is 7850) and on g [m/s^2]
DENSITY_MAX = 1e4
G_MAX = 1e4
#: bound on a seam's stiffness [N/m^2]: 1000 x TENSION_MAX / a 1 mm grid spacing
SEAM_STIFFNESS_MAX = 1e15


def _finite(v, name="value"):
    if v is not None and not math.isfinite(v):
        raise ValueError(f"must be finite (got {v})")
    return v


def _positive(v, hi: float | None = None, unit: str = ""):
    """None, or a positive finite number (else the validation message every such field gives),
    at most ``hi`` if given."""
    if v is not None and not (math.isfinite(v) and v > 0):
        raise ValueError(f"must be positive and finite (got {v})")
    if v is not None and hi is not None and v > hi:
        raise ValueError(f"at most {hi:.0e}{' ' + unit if unit else ''} (got {fmt_beyond(v, hi)})")
    return v


def _coords(v):
    """A coordinate, length or tuple of them [m], each finite with |x| <= COORD_MAX."""
    if v is None:
        return v
    for x in (v if isinstance(v, (tuple, list)) else [v]):
        _finite(x)
        if abs(x) > COORD_MAX:
            raise ValueError(f"|x| must be at most {COORD_MAX:.0e} m (got {fmt_beyond(x, COORD_MAX) if x > 0 else fmt_beyond(x, -COORD_MAX)})")
    return v


def _direction(v):
    if not all(math.isfinite(x) for x in v) or sum(x * x for x in v) == 0:
        raise ValueError(f"must be a non-zero finite vector (got {list(v)})")
    return v


def _strict_int(v):
    """Integers only: a YAML ``true`` is not 1; an integral float (2e5) is its integer."""
    if isinstance(v, bool):
        raise ValueError(f"must be an integer (got {str(v).lower()})")
    if isinstance(v, float):
        if not v.is_integer():
            raise ValueError(f"must be an integer (got {v})")
        return int(v)
    return v


#: an int field that refuses booleans (pydantic would take true as 1)
Int = Annotated[int, BeforeValidator(_strict_int)]


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
        return _positive(v, 1e6)

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
    nx x ny, thickness [m] (needed with stress tables), warp and weft tables. With ``panels``
    the fabric gives the panels' default tables and thickness, and size and divisions are not
    used (omit them)."""

    size: tuple[float, float] | None = None
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    divisions: tuple[Int, Int] | None = None
    thickness: float | None = None
    warp: MaterialSpec
    weft: MaterialSpec

    @field_validator("size")
    @classmethod
    def _size(cls, v):
        for x in v or ():
            _positive(x, COORD_MAX, "m")
        return v

    @field_validator("origin")
    @classmethod
    def _origin(cls, v):
        return _coords(v)

    @field_validator("divisions")
    @classmethod
    def _div(cls, v):
        if v is None:
            return v
        for x in v:
            if x < 1:
                raise ValueError(f"must be at least 1 (got {x})")
        if (v[0] + 1) * (v[1] + 1) > 4_000_000:
            raise ValueError(f"too many nodes ({(v[0] + 1) * (v[1] + 1)}; at most 4,000,000)")
        return v

    @field_validator("thickness")
    @classmethod
    def _thick(cls, v):
        return _positive(v, 1.0, "m")

    @model_validator(mode="after")
    def _needs_thickness(self):
        for name in ("warp", "weft"):
            m = getattr(self, name)
            if m.stress is not None and self.thickness is None:
                raise ValueError(f"thickness: needed because {name} is given as stress [Pa]")
        for name in ("warp", "weft"):  # tables in the file (CSV tables warn when read)
            m = getattr(self, name)
            if m.strain is not None:
                warn_implausible_strain(m.strain, f"fabric.{name}.strain")
        return self


IndexRange = tuple[Int, Int]


class NodeRange(_Strict):
    """Explicit inclusive index ranges; negative indices count from the end (-1 = last).

    With ``panels``: ``panel`` names the panel the selector reads (omitted: every panel);
    ``side`` a named set of that panel's lattice (left, right, ... as in constraints); ``edge``
    ``[v0, v1]`` the lattice nodes along the panel's outline from vertex v0 to vertex v1
    (counter-clockwise), ordered along it; a vertex is its index in the outline, or for a panel
    read from a pattern file the name of one of its notches (``notch1``, ``notch2``, ...)."""

    i: IndexRange | Int | None = None
    j: IndexRange | Int | None = None
    panel: str | None = None
    side: Literal[NODE_SETS] | None = None  # type: ignore[valid-type]
    edge: tuple[Int | str, Int | str] | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        kinds = [k for k in ("side", "edge") if getattr(self, k) is not None]
        if kinds and (self.i is not None or self.j is not None):
            raise ValueError(f"give either i/j ranges or {kinds[0]}, not both")
        if len(kinds) > 1:
            raise ValueError("give either side or edge, not both")
        if self.edge is not None and self.panel is None:
            raise ValueError("edge: needs panel (the panel whose outline it follows)")
        return self


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
            if s > 1e3:
                raise ValueError(f"at most 1e+03 (got {fmt_beyond(s, 1e3)})")
        return v

    @field_validator("displacement")
    @classmethod
    def _disp(cls, v):
        return _coords(v)


class PanelTransform(_Strict):
    """A rigid placement of a panel's plane in space: rotate [deg] about x, then y, then z, then
    translate [m]. The panel's outline lies in its plane's x-y."""

    rotate: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @field_validator("rotate")
    @classmethod
    def _fin(cls, v):
        for x in v:
            _finite(x)
        return v

    @field_validator("translate")
    @classmethod
    def _translate(cls, v):
        return _coords(v)


class Wrap(_Strict):
    """Initial sheet wrapped on a cylinder around a mold (the paper's torso set-up): the sheet's
    warp (x) direction goes round the cylinder's axis, weft along it."""

    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float
    start_angle: float = 0.0  # degrees, where the sheet's left edge sits

    @field_validator("axis")
    @classmethod
    def _axis(cls, v):
        return _direction(v)

    @field_validator("center")
    @classmethod
    def _center(cls, v):
        return _coords(v)

    @field_validator("radius")
    @classmethod
    def _radius(cls, v):
        return _positive(v, COORD_MAX, "m")

    @field_validator("start_angle")
    @classmethod
    def _angle(cls, v):
        return _finite(v)


class Region(_Strict):
    """An axis-aligned box [m]: ``min`` and ``max`` corners (min < max on every axis)."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    @field_validator("min", "max")
    @classmethod
    def _corner(cls, v):
        return _coords(v)

    @model_validator(mode="after")
    def _order(self):
        if not all(a < b for a, b in zip(self.min, self.max)):
            raise ValueError(f"min must be below max on every axis (got {list(self.min)}, {list(self.max)})")
        return self


class WrapHull(_Strict):
    """The sheet (or a panel) wrapped round a body slab, clear of it (clothsim.hullwrap): each row
    goes round the convex hull of the mold's cross-section at its height (the mold's part inside
    ``region``, when given), grown by ``clearance`` [m], by arc length. axis: the body axis;
    center [m]: a point on it, where the sheet's middle row sits; heights [m]: [lowest row,
    highest row] along the axis measured from center (omitted: the sheet's own height, centred);
    start_angle [deg]: the ray (in ``initial.wrap``'s frame) that marks the perimeter's start;
    offset: where the sheet's left edge sits, as a fraction of the perimeter past that start;
    fraction: the share of the perimeter each row's width covers (1: once round; 0.5 for each of
    two panels)."""

    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    clearance: float = 0.01
    heights: tuple[float, float] | None = None
    region: Region | None = None
    start_angle: float = 0.0
    offset: float = 0.0
    fraction: float = 1.0

    @field_validator("axis")
    @classmethod
    def _axis(cls, v):
        return _direction(v)

    @field_validator("center")
    @classmethod
    def _center(cls, v):
        return _coords(v)

    @field_validator("clearance")
    @classmethod
    def _clear(cls, v):
        _finite(v)
        if not 0 <= v <= COORD_MAX:
            raise ValueError(f"must be between 0 and {COORD_MAX:g} m (got {v})")
        return v

    @field_validator("heights")
    @classmethod
    def _heights(cls, v):
        if v is None:
            return v
        _coords(v)
        if not v[0] < v[1]:
            raise ValueError(f"must be [lowest, highest] with lowest < highest (got {list(v)})")
        return v

    @field_validator("start_angle", "offset")
    @classmethod
    def _fin(cls, v):
        return _finite(v)

    @field_validator("fraction")
    @classmethod
    def _fraction(cls, v):
        _finite(v)
        if not 0 < v <= 10:
            raise ValueError(f"must be above 0 and at most 10 (got {v})")
        return v


class PanelPlacement(_Strict):
    """Where a panel starts in space: ``transform`` (rigid; the default is the identity: the panel
    in z = 0), ``wrap`` (rolled round an axis at a radius, warp round the axis, like
    ``initial.wrap``) or ``wrap_hull`` (round a body: round the hull of the mold's slab, like
    ``initial.wrap_hull``)."""

    transform: PanelTransform | None = None
    wrap: Wrap | None = None
    wrap_hull: WrapHull | None = None

    @model_validator(mode="after")
    def _one(self):
        if sum(x is not None for x in (self.transform, self.wrap, self.wrap_hull)) > 1:
            raise ValueError("give one of transform, wrap and wrap_hull")
        return self


class PatternRef(_Strict):
    """A panel outline read from a pattern file (clothsim.patterns): ``file`` (.dxf or .svg,
    relative to the scene's folder), ``piece`` (its name; may be omitted when the file has one
    piece), ``units`` (mm, cm, m, in, px; omitted: declared in the file or detected) and
    ``tolerance`` [m] (chord error of flattened curves; default 0.5 mm)."""

    file: str
    piece: str | None = None
    units: str | None = None
    tolerance: float | None = None

    @field_validator("tolerance")
    @classmethod
    def _tol(cls, v):
        return _positive(v, 1.0, "m")


class Panel(_Strict):
    """A pattern panel: a closed ``outline`` [m] in the panel's own plane (at least 3 points,
    not crossing itself), ``grain`` the warp direction in that plane (default x), the lattice
    ``spacing`` [m] (one value or [dx, dy]) or ``divisions`` [nx, ny] of the outline's extent
    along and across the grain, its own ``warp``/``weft`` tables and ``thickness`` (default: the
    ``fabric``'s), and a ``placement``. Instead of ``outline``, ``pattern`` reads the outline (and
    the grainline, when ``grain`` is omitted) from a DXF or SVG pattern file. The lattice follows the grain and is cut to the outline
    with exact tributary areas (see clothsim.panels)."""

    name: str
    outline: list[tuple[float, float]] | None = None
    pattern: PatternRef | None = None
    grain: tuple[float, float] | None = None
    spacing: float | tuple[float, float] | None = None
    divisions: tuple[Int, Int] | None = None
    warp: MaterialSpec | None = None
    weft: MaterialSpec | None = None
    thickness: float | None = None
    placement: PanelPlacement = Field(default_factory=PanelPlacement)

    @field_validator("outline")
    @classmethod
    def _outline(cls, v):
        from .panels import PanelError, check_outline

        if v is None:
            return v
        try:
            check_outline(v, "outline")
        except PanelError as exc:
            raise ValueError(str(exc).removeprefix("outline: ")) from None
        return v

    @field_validator("spacing")
    @classmethod
    def _spacing(cls, v):
        for x in ([v] if isinstance(v, (int, float)) else (v or [])):
            _positive(x, COORD_MAX, "m")
        return v

    @field_validator("divisions")
    @classmethod
    def _div(cls, v):
        if v is not None:
            Fabric._div(v)
        return v

    @field_validator("thickness")
    @classmethod
    def _thick(cls, v):
        return _positive(v)

    @model_validator(mode="after")
    def _lattice(self):
        if (self.spacing is None) == (self.divisions is None):
            raise ValueError("give spacing or divisions (one of them)")
        if (self.outline is None) == (self.pattern is None):
            raise ValueError("give outline or pattern (one of them)")
        return self


class Initial(_Strict):
    """The initial deformation that keeps the sheet off the mold (paper 3.1).

    lift [m]: interior nodes raised along +z by a smooth dome of this height.
    file: an earlier result's positions (nx+1, ny+1, 3) provide the free coordinates.
    wrap: the sheet rolled onto a cylinder. wrap_hull: the sheet laid round the hull of the mold's
    slab at each row's height, clear of it (see :class:`WrapHull`). perturb [m] with seed: a random perturbation of the
    free coordinates (tests start from perturbed states). auto_clearance: lift the sheet just
    clear of the mold if it touches it, instead of refusing the scene. interpolate (default true):
    free nodes start with the in-plane stretch of the constrained ones spread smoothly over the
    sheet (harmonic interpolation), a far better start than the paper's literal one (constrained
    nodes moved alone), which ``interpolate: false`` restores."""

    lift: float = 0.0
    file: str | None = None
    wrap: Wrap | None = None
    wrap_hull: WrapHull | None = None
    perturb: float = 0.0
    seed: Int = 0
    auto_clearance: bool = False
    interpolate: bool = True

    @field_validator("lift", "perturb")
    @classmethod
    def _fin(cls, v):
        return _coords(v)

    @model_validator(mode="after")
    def _one_wrap(self):
        if self.wrap is not None and self.wrap_hull is not None:
            raise ValueError("give wrap or wrap_hull, not both")
        return self


class Gravity(_Strict):
    """Gravity (eq. 1, W): areal density [kg/m^2] times g [m/s^2] along direction."""

    areal_density: float
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    g: float = 9.80665

    @field_validator("areal_density")
    @classmethod
    def _rho(cls, v):
        return _positive(v, DENSITY_MAX, "kg/m^2")

    @field_validator("g")
    @classmethod
    def _g(cls, v):
        return _positive(v, G_MAX, "m/s^2")

    @field_validator("direction")
    @classmethod
    def _dir(cls, v):
        return _direction(v)


class SpringTerm(_Strict):
    """An optional linear spring family (shear diagonals or bending skip-one springs) with
    tension per width ``stiffness * strain`` [N/m], resisting tension and compression.
    stiffness: positive, at most 1e9 N/m (see clothsim.material.TENSION_MAX)."""

    stiffness: float

    @field_validator("stiffness")
    @classmethod
    def _k(cls, v):
        return _positive(v, TENSION_MAX, "N/m")


class Seam(_Strict):
    """A sewn seam (eq. 1, F_seams): node line ``a`` is sewn to node line ``b`` of the same sheet,
    node by node in index order (``reverse: true`` pairs a's first node with b's last). Each pair
    is joined by a zero-length linear spring, the sewing force ``k * gap`` [N] pulling the two
    nodes together, with ``k = stiffness x`` the pair's share of the seam length [m]. Sides of
    unequal node counts are sewn along arc length: each node of the denser side to the point of
    the other side at the same fraction of its length (the same law, k |gap|^2 / 2); a longer
    side gathers onto the shorter one (ease).

    a, b: node sets or index ranges as in constraints; each must select one line of nodes (a
    single i or a single j) or an outline edge. stiffness [N/m per metre of seam,
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
        return _positive(v, SEAM_STIFFNESS_MAX, "N/m^2")


class SolverSettings(_Strict):
    """method: which solver; C: the paper's step divisor (eq. 4, > 1); e: the convergence limit on
    ||V||_inf [N] (eq. 6); max_iterations; time_limit_s: wall-clock bound [s], positive and
    finite (omitted = none)."""

    method: Literal[SOLVER_METHODS] = SOLVER_DEFAULTS["method"]  # type: ignore[valid-type]
    C: float = SOLVER_DEFAULTS["C"]
    e: float = SOLVER_DEFAULTS["e"]
    max_iterations: Int = SOLVER_DEFAULTS["max_iterations"]
    time_limit_s: float | None = SOLVER_DEFAULTS["time_limit_s"]
    max_retries: Int = SOLVER_DEFAULTS["max_retries"]
    stall_iterations: Int = SOLVER_DEFAULTS["stall_iterations"]
    # newton only: stiffness used at and below strain 0 on tension-only springs, as a fraction of
    # the table's first slope (regularises the singular Hessian of slack springs; shapes the
    # search direction only, never the forces); and whether to solve coarser grids first
    newton_kink: float = Field(default=SOLVER_DEFAULTS["newton_kink"], ge=0.0, le=1e3)
    newton_sequencing: bool = SOLVER_DEFAULTS["newton_sequencing"]
    # load steps: the constraints' displacements (and stretches) are applied in this many equal
    # steps from the placed sheet, each solved to equilibrium from the one before (a path: with
    # friction the answer depends on it; without, only the last step's equilibrium counts)
    load_steps: Int = SOLVER_DEFAULTS["load_steps"]

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

    @field_validator("time_limit_s")
    @classmethod
    def _time(cls, v):
        return _positive(v)

    @field_validator("max_iterations", "max_retries", "stall_iterations", "load_steps")
    @classmethod
    def _pos(cls, v):
        if v < 1:
            raise ValueError(f"must be at least 1 (got {v})")
        return v


# ----------------------------------------------------------------------------- mold specs


def _short(v: Any, n: int = 40) -> str:
    """repr of a user value, cut to n characters (error messages never echo a whole input)."""
    r = repr(v)
    return r if len(r) <= n else r[: n - 3] + "..."


def _finite3(v, what: str = "3 finite numbers"):
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"must be {what} (got {list(v)})")
    return v


def _nonzero3(v):
    _finite3(v, "a non-zero finite vector")
    if sum(x * x for x in v) == 0:
        raise ValueError(f"must be a non-zero finite vector (got {list(v)})")
    return v


# the largest Coulomb coefficient a scene may give (measured fabric-skin values lie about 0.2-0.7)
FRICTION_MAX = 10.0


class _MoldFriction(_Strict):
    """friction: the Coulomb coefficient mu between the fabric and the mold (>= 0; one value for
    static and kinetic friction; omitted or 0: frictionless contact). A scene with mu > 0 is
    solved in load steps by Newton (``solver.load_steps``; see docs/method/friction.md)."""

    friction: float | None = None

    @field_validator("friction")
    @classmethod
    def _mu(cls, v):
        if v is not None and not (math.isfinite(v) and 0.0 <= v <= FRICTION_MAX):
            raise ValueError(f"must be a number from 0 to {FRICTION_MAX:g} (got {_short(v)})")
        return v


class MeshMoldSpec(_MoldFriction):
    """A mold read from a triangle-mesh file (any format :func:`clothsim.mold.load_mold` reads).

    path: the file (relative paths resolve against the scene file's folder); scale: a positive
    number, or three (per axis), multiplying the file's coordinates into metres (0.001 for a file
    in millimetres); rotate [deg]: about x, then y, then z; translate [m]: applied last;
    closed: true = must be watertight (inside = the enclosed volume), false = an open skin even
    if watertight, omitted = detected; up: the file's up axis, ``z`` (clothsim's own, the
    default) or ``y`` (most scans and glTF): a Y-up file is turned +90 degrees about x before
    everything else (its y becomes z, its front +z becomes -y); surface: 'faceted' (contact on
    the triangles themselves: CAD molds with real sharp edges) or 'smooth' (contact on a smooth
    surface blended from the triangles' planes: scans, whose triangles only sample a smooth
    body; the pressure then converges under refinement); omitted: smooth for a mesh that
    samples a smooth body (more than 10 % of its edges bend by 10-45 degrees: a scan), faceted
    otherwise (:func:`clothsim.mold.build.auto_surface`); smoothing [m]: the smooth surface's
    blending radius (default: adaptive, about the mesh's edge length; surface: smooth only)."""

    kind: ClassVar[str] = "mesh"
    path: str
    scale: Any = None
    translate: tuple[float, float, float] | None = None
    rotate: tuple[float, float, float] | None = None
    closed: StrictBool | None = None
    up: Literal["y", "z"] | None = None
    surface: Literal["faceted", "smooth"] | None = None  # None: auto_surface (smooth for a scan)
    smoothing: float | None = None

    @field_validator("smoothing")
    @classmethod
    def _smoothing(cls, v):
        return v if v is None else _positive(v)

    @model_validator(mode="after")
    def _smoothing_needs_smooth(self):
        if self.smoothing is not None and self.surface != "smooth":
            raise ValueError("smoothing: applies to surface: smooth only")
        return self

    @field_validator("path")
    @classmethod
    def _path(cls, v):
        if not v.strip():
            raise ValueError("must name a file")
        return v

    @field_validator("scale", mode="before")
    @classmethod
    def _scale(cls, v):
        if v is None:
            return v
        msg = f"must be a positive number or three positive numbers (got {_short(v)})"
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(msg)
            return float(v)
        if isinstance(v, (list, tuple)) and len(v) == 3 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0
                for x in v):
            return [float(x) for x in v]
        raise ValueError(msg)

    @field_validator("translate", "rotate")
    @classmethod
    def _vec(cls, v, info):
        if v is None:
            return v
        return _coords(_finite3(v)) if info.field_name == "translate" else _finite3(v)


class SphereParams(_Strict):
    """center [m], radius [m]."""

    center: tuple[float, float, float]
    radius: float

    @field_validator("center")
    @classmethod
    def _center(cls, v):
        return _coords(_finite3(v))

    @field_validator("radius")
    @classmethod
    def _radius(cls, v):
        return _positive(v, COORD_MAX, "m")


class CylinderParams(_Strict):
    """A finite capped cylinder: center [m], axis (any non-zero length), radius [m], length [m]
    (it spans center +- axis * length / 2)."""

    center: tuple[float, float, float]
    axis: tuple[float, float, float]
    radius: float
    length: float

    @field_validator("center")
    @classmethod
    def _center(cls, v):
        return _coords(_finite3(v))

    @field_validator("axis")
    @classmethod
    def _axis(cls, v):
        return _nonzero3(v)

    @field_validator("radius", "length")
    @classmethod
    def _pos(cls, v):
        return _positive(v, COORD_MAX, "m")


class PlaneParams(_Strict):
    """The half-space behind a plane: point [m] on it, outward normal (any non-zero length)."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    @field_validator("point")
    @classmethod
    def _point(cls, v):
        return _finite3(v)  # not bounded: a scene without a mold queries a plane 1e9 m away

    @field_validator("normal")
    @classmethod
    def _normal(cls, v):
        return _nonzero3(v)


class BoxParams(_Strict):
    """An axis-aligned box: min and max corners [m], max > min on every axis."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    @field_validator("min", "max")
    @classmethod
    def _corners(cls, v):
        return _coords(_finite3(v))

    @model_validator(mode="after")
    def _order(self):
        if not all(b > a for a, b in zip(self.min, self.max)):
            raise ValueError(f"max: must exceed min on every axis (got min {list(self.min)}, "
                             f"max {list(self.max)})")
        return self


class SphereMoldSpec(_MoldFriction):
    kind: ClassVar[str] = "sphere"
    sphere: SphereParams


class CylinderMoldSpec(_MoldFriction):
    kind: ClassVar[str] = "cylinder"
    cylinder: CylinderParams


class PlaneMoldSpec(_MoldFriction):
    kind: ClassVar[str] = "plane"
    plane: PlaneParams


class BoxMoldSpec(_MoldFriction):
    kind: ClassVar[str] = "box"
    box: BoxParams


class LegMoldSpec(_MoldFriction):
    """A limb from a size chart's girths at its measuring levels (:mod:`clothsim.legspec`)."""

    kind: ClassVar[str] = "leg"
    leg: LegParams


MOLD_PRIMITIVES = ("sphere", "cylinder", "plane", "box", "leg")
# pydantic puts the union branch's tag into error locations; format_validation_error drops these
_MOLD_TAGS = tuple(f"mold:{k}" for k in ("mesh", *MOLD_PRIMITIVES))


def _mold_tag(v: Any) -> str | None:
    """Which branch of MoldSpec a raw spec is: 'path' makes it a mesh file, else the primitive
    key it holds; None (refused: "exactly one of") when it holds none or several (a path and a
    sphere was reported as "mold.sphere: unknown field", though sphere is a documented key)."""
    if isinstance(v, BaseModel):
        kind = getattr(v, "kind", None)
        return f"mold:{kind}" if kind else None
    if not isinstance(v, dict):
        return None
    kinds = [k for k in ("path", *MOLD_PRIMITIVES) if k in v]
    if len(kinds) != 1:
        return None
    return "mold:mesh" if kinds[0] == "path" else f"mold:{kinds[0]}"


MoldSpec = Annotated[
    Union[
        Annotated[MeshMoldSpec, Tag("mold:mesh")],
        Annotated[SphereMoldSpec, Tag("mold:sphere")],
        Annotated[CylinderMoldSpec, Tag("mold:cylinder")],
        Annotated[PlaneMoldSpec, Tag("mold:plane")],
        Annotated[BoxMoldSpec, Tag("mold:box")],
        Annotated[LegMoldSpec, Tag("mold:leg")],
    ],
    Discriminator(_mold_tag, custom_error_type="mold_kind",
                  custom_error_message="must be a mapping with exactly one of 'path' (a mesh file), "
                                       "sphere, cylinder, plane, box, leg"),
]
"""A mold spec: :class:`MeshMoldSpec` or one primitive (``{sphere: {...}}``, ``{cylinder: ...}``,
``{plane: ...}``, ``{box: ...}``)."""


class _MoldHolder(_Strict):
    mold: MoldSpec


def validate_mold_spec(spec: Any) -> Any:
    """A raw mold spec (dict) as its typed model; a typed one is returned as is. Raises
    ValueError with ``mold.field: message`` lines (the same checks as a scene file's)."""
    if isinstance(spec, (MeshMoldSpec, SphereMoldSpec, CylinderMoldSpec, PlaneMoldSpec, BoxMoldSpec, LegMoldSpec)):
        return spec
    try:
        return _MoldHolder.model_validate({"mold": spec}).mold
    except ValidationError as exc:
        raise ValueError(format_validation_error(exc, "", None).replace("\n: ", "\n").lstrip(": ")) from None


# the scene fields a stage may change (the lattice, seams and start are the scene's own)
STAGE_FIELDS = ("constraints", "mold", "gravity", "solver")
# a stage's rest_scale: the garment from half to twice its design size along each direction
REST_SCALE_RANGE = (0.5, 2.0)


class Stage(_Strict):
    """One stage of a loading path (``stages:``): name; steps, its load steps (>= 1); set, scene
    fields (dotted paths as in ``--set``, under constraints, mold, gravity or solver) and the
    values they take from this stage on. The constraints' prescribed coordinates go linearly from
    where the previous stage left them to this stage's values over its steps; the other changes
    (mold.friction, gravity, a mold) apply from the stage's first step."""

    name: str = ""
    steps: Int = 1
    set: dict[str, Any] = Field(default_factory=dict)
    # the garment's size relative to its design (every panel's rest lengths), one number or
    # [warp, weft]; ramped from the previous stage's (1 before the first) over the steps;
    # absent: the previous stage's
    rest_scale: Any = None

    @field_validator("rest_scale", mode="before")
    @classmethod
    def _rest_scale(cls, v):
        if v is None:
            return v
        vals = [v] if isinstance(v, (int, float)) else list(v) if isinstance(v, (list, tuple)) else [None]
        if len(vals) not in (1, 2) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and
                                              math.isfinite(x) and
                                              REST_SCALE_RANGE[0] <= x <= REST_SCALE_RANGE[1] for x in vals):
            raise ValueError(f"must be a number or [warp, weft], each from {REST_SCALE_RANGE[0]} to "
                             f"{REST_SCALE_RANGE[1]} (the garment's size over its design; got {v!r})")
        return [float(x) for x in vals] if isinstance(v, (list, tuple)) else float(v)

    def scale(self, previous: tuple) -> tuple:
        """(s_warp, s_weft) this stage ramps to, from the previous stage's ``previous``."""
        if self.rest_scale is None:
            return tuple(previous)
        v = self.rest_scale
        return (float(v), float(v)) if isinstance(v, (int, float)) else (float(v[0]), float(v[-1]))

    @field_validator("steps")
    @classmethod
    def _steps(cls, v):
        if not 1 <= v <= 100_000:
            raise ValueError(f"must be from 1 to 100000 (got {v})")
        return v

    @field_validator("set")
    @classmethod
    def _paths(cls, v):
        for k in v:
            if str(k).split(".")[0] not in STAGE_FIELDS:
                raise ValueError(f"'{k}': a stage may change {', '.join(STAGE_FIELDS)} only")
        return v


class Scene(_Strict):
    """A complete, validated scene. ``source`` (not part of the file) is where it was read from;
    relative paths inside resolve against its folder."""

    name: str = "scene"
    fabric: Fabric
    constraints: list[Constraint] = Field(default_factory=list)
    initial: Initial = Field(default_factory=Initial)
    mold: MoldSpec | None = None
    gravity: Gravity | None = None
    shear: SpringTerm | None = None
    bending: SpringTerm | None = None
    seams: list[Seam] = Field(default_factory=list)
    panels: list[Panel] = Field(default_factory=list)
    solver: SolverSettings = Field(default_factory=SolverSettings)
    # compression engineering (clothsim.compression.spec): sensors, slices along a limb, classes
    probes: list[Probe] = Field(default_factory=list)
    profiles: list[Profile] = Field(default_factory=list)
    classes: Classes | None = None
    levels: Levels | None = None   # the measuring levels read on the body (compression/levelspec.py)
    # a loading path in stages (empty: one stage, the scene as it is)
    stages: list[Stage] = Field(default_factory=list)

    model_config = ConfigDict(extra="forbid")
    _source: Path | None = None
    # where the scene came from, for errors found after validation (``locate``): the file's label
    # as given, its YAML node tree and the --set overrides' labels by field path
    _label: str | None = None
    _yaml_root: Any = None
    _blame: dict | None = None

    def locate(self, message: str) -> str:
        """``message`` (``field.path: why``, as the model and the start-up raise them) prefixed
        with where that field was set: ``file:line`` of the scene file, or the ``--set`` that
        set it (as validation errors are). A message that names no field of the scene is
        returned as it is."""
        m = re.match(r"([A-Za-z_]\w*(?:\.\w+)*): ", message)
        if not m or m.group(1).split(".")[0] not in type(self).model_fields:
            return message
        loc = tuple(int(p) if p.isdigit() else p for p in m.group(1).split("."))
        culprit = _blamed(loc, self._blame, self._yaml_root)
        if culprit:
            return f"{culprit}: {message}"
        if self._label is None:
            return message
        line = _yaml_line(self._yaml_root, loc) if self._yaml_root is not None else None
        return f"{self._label}:{line}: {message}" if line else f"{self._label}: {message}"

    @model_validator(mode="after")
    def _panels_fit(self):
        """The fabric rectangle or panels; panel names are unique and every selector names an
        existing panel."""
        if not self.panels:
            for k in ("size", "divisions"):
                if getattr(self.fabric, k) is None:
                    raise ValueError(f"fabric.{k}: missing (the sheet needs it unless panels are given)")
        else:
            for k in ("size", "divisions"):
                if getattr(self.fabric, k) is not None:
                    raise ValueError(f"fabric.{k}: not used with panels (each panel has its outline and lattice)")
        names = [p.name for p in self.panels]
        for n, name in enumerate(names):
            if name in names[:n]:
                raise ValueError(f"panels.{n}.name: '{name}' is used twice")
        sels = [(f"constraints.{n}.nodes", c.nodes) for n, c in enumerate(self.constraints)]
        sels += [(f"seams.{n}.{k}", getattr(s, k)) for n, s in enumerate(self.seams) for k in ("a", "b")]
        for where, sel in sels:
            if isinstance(sel, NodeRange) and sel.panel is not None and sel.panel not in names:
                known = ", ".join(names) if names else "none: the scene has no panels"
                raise ValueError(f"{where}.panel: unknown panel '{sel.panel}' (known: {known})")
        return self

    @model_validator(mode="after")
    def _ranges_fit(self):
        """On the ``fabric`` sheet, each constraint's i/j ranges lie on its lattice (checked here,
        so a sweep refuses such a run before any runs; panel lattices are checked when built)."""
        if self.panels or self.fabric.divisions is None:
            return self
        from .selection import SelectionError, index_range

        nx, ny = self.fabric.divisions
        for n, c in enumerate(self.constraints):
            if isinstance(c.nodes, NodeRange) and c.nodes.side is None and c.nodes.edge is None:
                try:
                    index_range(c.nodes.i, nx, "i", "constraints")
                    index_range(c.nodes.j, ny, "j", "constraints")
                except SelectionError as exc:
                    raise ValueError(f"constraints.{n}.nodes: {exc}") from None
        return self

    @model_validator(mode="after")
    def _friction_method(self):
        """The paper's relaxation is frictionless: a scene with friction asks for Newton."""
        mu = getattr(self.mold, "friction", None) if self.mold is not None else None
        if mu and self.solver.method == "paper":
            raise ValueError(f"solver.method: 'paper' is frictionless (the paper's relaxation has no "
                             f"friction) but mold.friction is {mu:g}: use method newton or auto, or "
                             f"mold.friction: 0")
        return self

    @model_validator(mode="after")
    def _compression_names(self):
        check_compression(self.probes, self.profiles, self.classes)
        return self

    @model_validator(mode="after")
    def _seams_fit(self):
        """Each seam joins two node lines that are not the same (checked here for the ``fabric``
        sheet; panel seams are checked when the panels' lattices are built)."""
        if not self.seams or self.panels:
            return self
        from .selection import SelectionError, seam_pairs, seam_sides
        from .topology import Topology

        topology = Topology.rectangle(*self.fabric.divisions)
        for n, seam in enumerate(self.seams):
            try:
                a, b, _ = seam_sides(seam, topology)
                if a.size == b.size:
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
        return self.material_table(getattr(self.fabric, name), self.fabric.thickness, name)

    def material_table(self, m: MaterialSpec, thickness: float | None, name: str) -> Table:
        """The tension table [N/m] of a material spec (CSV resolved against the scene's folder,
        stress times ``thickness``); ``name`` is the field named in errors."""
        if m.preset is not None:
            from .presets import PRESETS
            p = PRESETS[m.preset]
            which = "warp" if name.endswith("warp") else "weft"
            return Table(np.asarray(p.strain, float), np.asarray(getattr(p, which), float) * (m.scale or 1.0))
        if m.csv is not None:
            path = self.resolve(m.csv)
            strain, value, kind = read_table_csv(path)
        else:
            strain = np.asarray(m.strain, float)
            kind = "stress" if m.stress is not None else "tension"
            value = np.asarray(m.stress if m.stress is not None else m.tension, float)
        if kind == "stress":
            if thickness is None:
                raise SceneError(f"fabric.thickness: needed because {name} is given as stress [Pa]")
            value = value * thickness
        value = value * (m.scale or 1.0)
        if value.size and value.max() > TENSION_MAX:
            field = name if "." in name else f"fabric.{name}"
            raise SceneError(f"{field}: tension reaches {fmt_beyond(value.max(), TENSION_MAX)} N/m (after thickness and scale); "
                             f"at most {TENSION_MAX:.0e} N/m")
        return Table(strain, value)

    def to_dict(self) -> dict:
        d = self.model_dump(mode="json", exclude_none=True)
        for key in ("probes", "profiles", "stages"):  # optional sections: absent unless used
            if not d.get(key):
                d.pop(key, None)
        return d

    def resolved(self) -> "Scene":
        """A copy whose file references (CSV tables, initial file, mold path) are absolute, so the
        scene can be written anywhere and repeated exactly."""
        d = self.to_dict()
        for panel in d.get("panels", []):
            if panel.get("pattern"):
                panel["pattern"]["file"] = str(self.resolve(panel["pattern"]["file"]))
        for holder in [d["fabric"]] + d.get("panels", []):
            for name in ("warp", "weft"):
                if (holder.get(name) or {}).get("csv"):
                    holder[name]["csv"] = str(self.resolve(holder[name]["csv"]))
        if d.get("initial", {}).get("file"):
            d["initial"]["file"] = str(self.resolve(d["initial"]["file"]))
        if d.get("mold") and d["mold"].get("path"):
            d["mold"]["path"] = str(self.resolve(d["mold"]["path"]))
        out = Scene.model_validate(d)
        out._source = self._source
        out._label, out._yaml_root, out._blame = self._label, self._yaml_root, self._blame
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


#: pydantic's branch tags of generic types (a key typed as ``size[0]`` is a field, not a tag)
_TAG = re.compile(r"(list|tuple|literal|dict|set|frozenset)\[")


def _is_tag(part) -> bool:
    """Whether a location part is pydantic's tag of a union's branch (``list[any]``,
    ``literal[...]``, ``function-after[_one(), Space]``, ``NodeRange``, a mold kind), not a field."""
    return isinstance(part, str) and (_TAG.match(part) is not None or part.startswith("function-")
                                      or part in ("NodeRange", "float", "int") or part in _MOLD_TAGS)


def _clean_loc(loc: tuple) -> tuple:
    """Drop pydantic's union/literal branch tags from a location."""
    return tuple(p for p in loc if not _is_tag(p))


def _winning_branches(errors: list[dict]) -> list[dict]:
    """A union's errors without the branches the input plainly is not: an error at a branch's own
    level (a list expected, a literal string expected) is dropped when another branch of the same
    union got further (an error inside it, or its own validator's message). ``{linspace: [1, 3,
    -2]}`` then reports the bad n alone, not also "Input should be a valid list"."""
    def branch(e):
        loc = tuple(e["loc"])
        i = next((k for k, p in enumerate(loc) if _is_tag(p)), None)
        return (None, None, False) if i is None else (loc[:i], loc[i], len(loc) > i + 1 or e["type"] == "value_error")

    info = [branch(e) for e in errors]
    keep = []
    for e, (base, tag, far) in zip(errors, info):
        if base is not None and not far and any(b == base and t != tag and f for b, t, f in info):
            continue
        keep.append(e)
    return keep


def format_validation_error(exc: ValidationError, source: str, root: yaml.Node | None,
                            blame: dict[str, str] | None = None) -> str:
    """One line per problem: ``file:line: field.path: message``. ``blame`` maps a field path
    (``solver.C``) to the label of what set it (``--set solver.C=0.5``): a problem at or under
    that path is reported against the label instead of a line of the file."""
    lines = []
    seen = set()
    for err in _winning_branches(exc.errors()):
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
        culprit = _blamed(loc, blame, root)
        line = _yaml_line(root, loc) if root is not None and culprit is None else None
        where = culprit or (f"{source}:{line}" if line else source)
        text = f"{where}: {field}: {msg}" if field else f"{where}: {msg}"
        if (field, msg) in seen:
            continue
        seen.add((field, msg))
        lines.append(text)
    # union errors produce one entry per branch; keep the most specific ones
    return "\n".join(lines)


def _in_file(root: yaml.Node | None, parts) -> bool:
    """Whether the scene file itself has a node at the path ``parts`` (keys, list indices)."""
    node = root
    for key in parts:
        nxt = None
        if isinstance(node, yaml.MappingNode):
            nxt = next((v for k, v in node.value if str(k.value) == str(key)), None)
        elif isinstance(node, yaml.SequenceNode) and str(key).isdigit() and int(key) < len(node.value):
            nxt = node.value[int(key)]
        if nxt is None:
            return False
        node = nxt
    return node is not None


def _blamed(loc: tuple, blame: dict[str, str] | None, root: yaml.Node | None = None) -> str | None:
    """The label of the override that caused a problem at loc, if any: the longest override path
    that is a prefix of loc (``--set solver.C=0``: solver.C); else one under loc (``--set
    fabric.size.0=-1``: the check of fabric.size); else one that shares the start of loc where the
    file has no such node (``--set gravity.g=1`` made gravity: its missing areal_density;
    ``--set solvr.C=3``: the unknown solvr). Problems of the file's own nodes keep the file's
    line."""
    best = None
    for path, label in (blame or {}).items():
        parts = path.split(".")
        c = 0
        while c < min(len(parts), len(loc)) and str(loc[c]) == parts[c]:
            c += 1
        if c == 0:
            continue
        if c == len(parts):
            rank = (2, c)
        elif c == len(loc):
            rank = (1, c)
        elif not _in_file(root, parts[:c]):
            rank = (0, c)
        else:
            continue
        if best is None or rank > best[0]:
            best = (rank, label)
    return best[1] if best else None


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
    for k, v, _ in parse_overrides(overrides):
        _set_path(data, k, v)
    return data


def parse_overrides(overrides: list[str] | dict[str, Any] | None) -> list[tuple[str, Any, str]]:
    """(field path, value, label) of each override; ``--set`` strings are parsed as YAML (aliases
    bounded as in scene files) and labelled ``--set path=value``."""
    if not overrides:
        return []
    if isinstance(overrides, dict):
        return [(k, v, f"{k}={v!r}") for k, v in overrides.items()]
    from .fileio import load_yaml

    parsed = []
    for o in overrides:
        if "=" not in o:
            raise SceneError(f"--set {o}: expected field.path=value")
        k, v = o.split("=", 1)
        parsed.append((k.strip(), load_yaml(v, f"--set {o}", SceneError)[0], f"--set {o}"))
    return parsed


def scene_from_dict(data: dict, source: str | Path | None = None, root: yaml.Node | None = None,
                    blame: dict[str, str] | None = None) -> Scene:
    """Validate a raw dict into a Scene; errors become SceneError with file:line: field: message
    (or ``--set ...: field: message`` for a field an override set, see format_validation_error)."""
    label = str(source) if source is not None else "<scene>"
    if not isinstance(data, dict):
        raise SceneError(f"{label}: a scene must be a mapping (got {type(data).__name__})")
    try:
        scene = Scene.model_validate(data)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, label, root, blame)) from None
    if source is not None:
        scene._source = Path(source).resolve()
        scene._label = label
    scene._yaml_root = root
    scene._blame = dict(blame) if blame else None
    if scene.stages:
        stage_scenes(scene)  # every stage's scene is valid before any work
    return scene


def read_yaml(path: str | Path, error: type[Exception] = SceneError) -> tuple[Any, yaml.Node | None]:
    """(data, node tree) of a YAML file; the tree gives line numbers for error messages. Failures
    raise ``error`` naming the file (and the line of a syntax error or of a byte that is not
    UTF-8). Refused before parsing: anything but a regular file, a file over 10 MB; before
    building any object: aliases expanding past a budget (a YAML bomb), see clothsim.fileio."""
    from .fileio import load_yaml, read_text

    path = Path(path)
    return load_yaml(read_text(path, error), str(path), error)


def load_scene(path: str | Path, overrides: list[str] | dict[str, Any] | None = None) -> Scene:
    """Read and validate a scene YAML file, applying ``--set`` style overrides."""
    path = Path(path)
    data, root = read_yaml(path)
    if data is None:
        raise SceneError(f"{path}: empty scene file")
    items = parse_overrides(overrides)
    if items and not isinstance(data, dict):
        raise SceneError(f"{path}: a scene must be a mapping (got {type(data).__name__})")
    data = copy.deepcopy(data)
    for k, v, _ in items:
        _set_path(data, k, v)
    return scene_from_dict(data, path, root, {k: label for k, _, label in items})


def stage_scenes(scene: Scene) -> list[tuple[Stage, Scene]]:
    """Each stage of ``scene.stages`` with the scene it solves: the scene's fields with every
    stage's ``set`` up to it applied (empty without stages). A value a field refuses is reported
    as ``file:line: stages.N.set: field: message``."""
    if not scene.stages:
        return []
    data = scene.to_dict()
    data.pop("stages", None)
    out = []
    for n, st in enumerate(scene.stages):
        try:
            for k, v in st.set.items():
                _set_path(data, k, copy.deepcopy(v))
            s = Scene.model_validate(copy.deepcopy(data))
        except (SceneError, ValidationError) as exc:
            why = format_validation_error(exc, "", None).lstrip(": ") if isinstance(exc, ValidationError) \
                else str(exc).replace("--set ", "")
            raise SceneError(scene.locate(f"stages.{n}.set: {why}")) from None
        s._source, s._label = scene._source, scene._label
        out.append((st, s))
    return out


def dump_scene(scene: Scene, path: str | Path) -> None:
    Path(path).write_text(scene.to_yaml(), encoding="utf-8")
