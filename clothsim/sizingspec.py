"""The scene field ``garment`` (panel scale, reduction, measuring levels, grading) as typed
models; :mod:`clothsim.sizing` applies it. Imports nothing from clothsim but the pydantic base,
so the scene layer can load it."""

from __future__ import annotations

import math

from pydantic import Field, field_validator, model_validator

from .strict import Strict as _Strict

#: reduction [%] a scene may give: -50 (a garment half as large again as the limb) to 90
REDUCTION_RANGE = (-50.0, 90.0)
#: a garment scale (width or length) from a fifth to five times the design
SCALE_RANGE = (0.2, 5.0)
AXES = {"x": 0, "y": 1, "z": 2}




def _number(v, name: str, lo: float, hi: float, unit: str = ""):
    if v is None:
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"must be a number from {lo:g} to {hi:g}{unit} ({name}; got {v!r})")
    return float(v)


class GarmentScale(_Strict):
    """The cut panels' scale: ``width`` (along the grain: the circumference) and ``length``
    (across it), each 1 for the design, from 0.2 to 5."""

    width: float = 1.0
    length: float = 1.0

    @field_validator("width", "length", mode="before")
    @classmethod
    def _range(cls, v):
        return _number(v, "the design is 1", *SCALE_RANGE)


class Level(_Strict):
    """A measuring level: ``name`` (B, C, ... as in RAL-GZ 387), ``height`` [m] on the body
    along ``garment.axis``, ``at`` [m] the pattern height above the hem it falls on (default
    ``height - garment.hem``), ``girth`` [m] the body's girth there (default: measured on the
    mold) and ``reduction`` [%] (default: ``garment.reduction``). A level given by its name
    alone (no height, no at) is the scene's measuring level of that name (a chart leg's or
    ``levels:``): its height and girth come from the body (clothsim.sizing.resolve_levels)."""

    name: str
    height: float | None = None
    at: float | None = None
    girth: float | None = None
    reduction: float | None = None

    @field_validator("height", "at", mode="before")
    @classmethod
    def _coord(cls, v):
        return _number(v, "metres", -1e3, 1e3, " m")

    @field_validator("girth", mode="before")
    @classmethod
    def _girth(cls, v):
        return _number(v, "the body's girth", 1e-4, 1e3, " m")

    @field_validator("reduction", mode="before")
    @classmethod
    def _red(cls, v):
        return _number(v, "percent", *REDUCTION_RANGE, " %")



class GradeRule(_Strict):
    """A level's grade rule: the circumference (``girth_cm``) and the height above the hem
    (``length_cm``) added per size step [cm]."""

    girth_cm: float = 0.0
    length_cm: float = 0.0

    @field_validator("girth_cm", "length_cm", mode="before")
    @classmethod
    def _cm(cls, v):
        return _number(v, "centimetres per size", -100.0, 100.0, " cm")


class Grading(_Strict):
    """A size set from a base pattern: ``sizes`` in order, the ``base`` size the outlines are
    drawn in, the ``size`` this scene cuts (default the base) and ``rules`` {level name:
    GradeRule} per size step."""

    sizes: list[str]
    base: str
    size: str | None = None
    rules: dict[str, GradeRule] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _names(self):
        if not self.sizes or len(set(self.sizes)) != len(self.sizes):
            raise ValueError(f"sizes: must be a list of distinct names (got {self.sizes})")
        for k in ("base", "size"):
            v = getattr(self, k)
            if v is not None and v not in self.sizes:
                raise ValueError(f"{k}: '{v}' is not one of the sizes ({', '.join(self.sizes)})")
        return self

    def steps(self) -> int:
        """Size steps from the base to the cut size (negative: smaller)."""
        return self.sizes.index(self.size or self.base) - self.sizes.index(self.base)


class GarmentSpec(_Strict):
    """The scene field ``garment`` (see the module docstring): ``scale``, ``reduction`` [%],
    ``levels``, ``hem`` [m] (the body height of the pattern's hem, for levels given by height),
    ``axis`` (the body's long axis, x, y or z), ``center`` [m] (a point on the limb's axis: which
    section of a mesh is the limb) and ``grading``."""

    scale: GarmentScale = Field(default_factory=GarmentScale)
    reduction: float | None = None
    levels: list[Level] = Field(default_factory=list)
    hem: float = 0.0
    axis: str = "z"
    center: tuple[float, float, float] | None = None
    grading: Grading | None = None

    @field_validator("reduction", mode="before")
    @classmethod
    def _red(cls, v):
        return _number(v, "percent", *REDUCTION_RANGE, " %")

    @field_validator("hem", mode="before")
    @classmethod
    def _hem(cls, v):
        return _number(v, "metres", -1e3, 1e3, " m")

    @field_validator("axis")
    @classmethod
    def _axis(cls, v):
        if v not in AXES:
            raise ValueError(f"must be x, y or z (got {v!r})")
        return v

    @model_validator(mode="after")
    def _consistent(self):
        names = [lv.name for lv in self.levels]
        for n, name in enumerate(names):
            if name in names[:n]:
                raise ValueError(f"levels.{n}.name: '{name}' is used twice")
        reduced = self.reduction is not None or any(lv.reduction is not None for lv in self.levels)
        if reduced and not self.levels:
            raise ValueError("reduction: needs levels (where the garment is measured against the body)")
        if reduced and self.scale.width != 1.0:
            raise ValueError("scale.width: a reduction sets the width at the levels: give a reduction or a "
                             "width scale, not both")
        if self.grading is not None:
            for name in self.grading.rules:
                if name not in names:
                    raise ValueError(f"grading.rules.{name}: no level named '{name}' (levels: "
                                     f"{', '.join(names) or 'none'})")
        return self

    def is_identity(self) -> bool:
        """True when nothing changes the design outlines."""
        graded = self.grading is not None and self.grading.steps() != 0
        reduced = self.reduction is not None or any(lv.reduction is not None for lv in self.levels)
        return not graded and not reduced and self.scale.width == 1.0 and self.scale.length == 1.0


class SizingError(ValueError):
    """A garment that cannot be sized as asked; the message starts with the ``garment.`` field."""


# ---------------------------------------------------------------------------------------------
# geometry
