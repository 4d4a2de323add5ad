"""The scene schema: fabric and materials, panels and their placement, constraints, the start,
gravity, optional spring terms, seams, solver settings, stages and the ``Scene`` that holds them
(pydantic models; units SI: m, N, Pa, N/m)."""

from __future__ import annotations

import math
from typing import Literal, Union

from pydantic import Field, field_validator, model_validator

from ..defaults import SOLVER_DEFAULTS
from ..fileio import fmt_beyond
from ..material import TENSION_MAX, MaterialError, check_table, warn_implausible_strain
from ..panels import PanelError, check_outline
from ..presets import PRESETS
from ..strict import Strict as _Strict
from .fields import (COORD_MAX, DENSITY_MAX, G_MAX, SEAM_STIFFNESS_MAX, Int, LatticeIndex, _coords,
                     _direction, _finite, _positive)

SOLVER_METHODS = ("auto", "paper", "newton")
NODE_SETS = (
    "perimeter", "left", "right", "bottom", "top",
    "bottom_left", "bottom_right", "top_left", "top_right", "corners", "all", "outline",
)


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


IndexRange = tuple[LatticeIndex, LatticeIndex]


class NodeRange(_Strict):
    """Explicit inclusive index ranges; negative indices count from the end (-1 = last), and an
    index may be a share of the way across, ``"50%"`` (the nearest node: the middle wale on any
    lattice).

    With ``panels``: ``panel`` names the panel the selector reads (omitted: every panel);
    ``side`` a named set of that panel's lattice (left, right, ... as in constraints); ``edge``
    ``[v0, v1]`` the lattice nodes along the panel's outline from vertex v0 to vertex v1
    (counter-clockwise), ordered along it; a vertex is its index in the outline, or for a panel
    read from a pattern file the name of one of its notches (``notch1``, ``notch2``, ...)."""

    i: IndexRange | LatticeIndex | None = None
    j: IndexRange | LatticeIndex | None = None
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


def check_node_selector(v):
    """``v`` if it can be a node selector (a node set's name, or a mapping for :class:`NodeRange`),
    else ValueError naming the known sets."""
    if isinstance(v, str) and v not in NODE_SETS:
        raise ValueError(f"unknown node set '{v}' (known: {', '.join(NODE_SETS)}; or give {{i: [a, b], j: [c, d]}})")
    if not isinstance(v, (str, dict)) and not isinstance(v, NodeRange):
        raise ValueError(f"must be a node set name or {{i: [a, b], j: [c, d]}} (got {v!r})")
    return v


class NodeSelection(_Strict):
    """The base of a record that applies to some nodes: ``nodes``, a named set (perimeter, left,
    right, bottom, top, corners, bottom_left, ...) or index ranges ``{i: [a, b], j: [c, d]}``
    (:class:`NodeRange`)."""

    nodes: Union[Literal[NODE_SETS], NodeRange]  # type: ignore[valid-type]

    @field_validator("nodes", mode="before")
    @classmethod
    def _nodes(cls, v):
        return check_node_selector(v)


class Constraint(NodeSelection):
    """Nodes held on some axes (paper 3.2.3), optionally moved before relaxing.

    nodes: a named set (perimeter, left, right, bottom, top, corners, bottom_left, ...) or
    index ranges ``{i: [a, b], j: [c, d]}``. axes: the constrained axes, any of x, y, z.
    displacement [m]: added to the selected nodes. stretch: scale factor (or [sx, sy]) about the
    sheet centre in the sheet plane, applied to the selected nodes."""

    axes: str = "xyz"
    displacement: tuple[float, float, float] | None = None
    stretch: float | tuple[float, float] | None = None

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
    with exact tributary areas (see clothsim.panels). ``row_ends: outline`` puts each lattice row's
    end nodes where the outline crosses the row, so each row's rest length follows the outline
    continuously (default ``lattice``: whole cells, a staircase on a shaped outline)."""

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
    # "outline": each lattice row's end nodes stand where the outline crosses the row, so a row's
    # rest length is the outline's width there (clothsim.panels); "lattice": whole cells
    row_ends: Literal["lattice", "outline"] = "lattice"

    @field_validator("outline")
    @classmethod
    def _outline(cls, v):
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
    # load steps: the constraints' displacements (and stretches) and gravity are applied in this
    # many equal steps from the placed sheet and no load, each solved to equilibrium from the one
    # before (a path: with friction the answer depends on it; without, only the last step's
    # equilibrium counts)
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
