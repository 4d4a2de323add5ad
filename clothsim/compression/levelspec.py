"""The scene field ``levels``: the standard's measuring levels on the body, read as the standards
read a stocking (:mod:`.levels`).

::

    levels:
      center: [-0.10, 0.03]      # a point (x, y) [m] inside the chosen leg's section at the ankle
      anterior: [0, -1]          # the front's direction (x, y); default -y (a scan turned by up: y)
      medial: [1, 0]             # the inner side's; default: towards x = 0 from center
      find: [B, C, D]            # levels found on the body's girths (default: these three)
      heights: {B1: 0.25}        # levels at given heights z [m] (also overrides a found one)
      radius: 0.025              # the side sensors' disc radius [m] (default 0.01)
      gradient: {C: [50, 80]}    # required pressure at a level, in per cent of B's: [min, max]

On a limb built from a size chart (``mold: {leg: ...}``) the chart's levels, axis and directions
are used and ``center``, ``anterior``, ``medial`` and ``find`` must be left out; ``heights`` adds
levels. Imports nothing from clothsim but the pydantic base.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, field_validator, model_validator

from ..strict import Strict as _Strict, finite_values, positive_finite

#: the levels :mod:`.levels` can find on a body's girths
FINDABLE = ("B", "C", "D")
#: the four sides a stocking's pressure is read on
SIDES = ("anterior", "posterior", "medial", "lateral")


class Levels(_Strict):
    """The measuring levels read on the body (docs/guide/levels.md): center (x, y) [m] a point
    inside the leg's section at the ankle (a scan), anterior and medial the front's and the
    inner side's directions (x, y), find the levels found on the girths (B, C, D), heights the
    levels at given heights z [m], radius [m] the side sensors' disc, gradient the required
    pressure per level in per cent of B's, [min, max]. On a leg from a size chart the chart
    gives the levels, axis and directions."""

    center: tuple[float, float] | None = None
    anterior: tuple[float, float] | None = None
    medial: tuple[float, float] | None = None
    find: list[Literal["B", "C", "D"]] | None = None
    heights: dict[str, float] = Field(default_factory=dict)
    radius: float = 0.01
    gradient: dict[str, tuple[float, float]] = Field(default_factory=dict)

    _pairs = field_validator("center", "anterior", "medial")(classmethod(lambda cls, v: v if v is None else finite_values(v)))
    _radius = field_validator("radius")(classmethod(lambda cls, v: positive_finite(v)))

    @field_validator("heights")
    @classmethod
    def _heights(cls, v):
        for k, h in v.items():
            if not (isinstance(h, (int, float)) and math.isfinite(h)):
                raise ValueError(f"{k}: must be a finite height [m] (got {h!r})")
        return v

    @field_validator("gradient")
    @classmethod
    def _gradient(cls, v):
        for k, (lo, hi) in v.items():
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise ValueError(f"{k}: must be [min, max] per cent of B, 0 <= min <= max (got {[lo, hi]})")
        return v

    @model_validator(mode="after")
    def _directions(self):
        for name in ("anterior", "medial"):
            d = getattr(self, name)
            if d is not None and math.hypot(*d) == 0:
                raise ValueError(f"{name}: must be a non-zero direction")
        return self


Side = Literal["anterior", "posterior", "medial", "lateral"]
