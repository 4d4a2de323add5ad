"""The typed mold specs of a scene (``mold:``): a mesh file or one primitive (sphere, cylinder,
plane, box), each with an optional Coulomb friction coefficient, and the union ``MoldSpec`` that
picks the branch from the keys a spec holds."""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, Discriminator, StrictBool, Tag, field_validator, model_validator

from ..legspec import LegParams
from ..strict import Strict as _Strict
from .fields import COORD_MAX, MOLD_PRIMITIVES, _coords, _finite3, _nonzero3, _positive, _short
from .schema import NodeSelection

# the largest Coulomb coefficient a scene may give (measured fabric-skin values lie about 0.2-0.7)
FRICTION_MAX = 10.0


def _check_mu(v):
    if v is not None and not (math.isfinite(v) and 0.0 <= v <= FRICTION_MAX):
        raise ValueError(f"must be a number from 0 to {FRICTION_MAX:g} (got {_short(v)})")
    return v


class FrictionRegion(NodeSelection):
    """A part of the garment whose Coulomb coefficient against the mold is not ``mold.friction``
    (a silicone grip band, a slippery lining): nodes, a selector as in ``constraints``; friction,
    its mu (0 to FRICTION_MAX). Where regions overlap the later one holds."""

    friction: float

    @field_validator("friction")
    @classmethod
    def _mu(cls, v):
        return _check_mu(v)


class _MoldFriction(_Strict):
    """friction: the Coulomb coefficient mu between the fabric and the mold (>= 0; one value for
    static and kinetic friction; omitted or 0: frictionless contact); friction_regions: parts of
    the garment with their own mu (:class:`FrictionRegion`). A scene with any mu > 0 is solved in
    load steps by Newton (``solver.load_steps``; see docs/method/friction.md)."""

    friction: float | None = None
    friction_regions: list[FrictionRegion] | None = None

    @field_validator("friction")
    @classmethod
    def _mu(cls, v):
        return _check_mu(v)

    @property
    def regions(self) -> list[FrictionRegion]:
        """The friction regions (none when the field is omitted)."""
        return list(self.friction_regions or [])


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
``{plane: ...}``, ``{box: ...}``, ``{leg: ...}``)."""


class _MoldHolder(_Strict):
    mold: MoldSpec

