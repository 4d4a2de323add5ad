"""The scene field of a limb built from a size chart: ``mold: {leg: {...}}`` (the surface is
:mod:`clothsim.mold.leg`).

::

    mold:
      leg:
        center: [0.0, 0.0]          # the axis (x, y) [m]; the limb stands along +z
        floor: 0.0                  # z of the sole [m]: the levels' heights are above it
        anterior: [0, -1]           # the front's direction (x, y); medial: the inner side's
        medial: [1, 0]
        levels:                     # the chart's measuring levels, each a girth and a height
          B: {girth_cm: 22, height_cm: 12}
          C: {girth_cm: 36, height_cm: 33, aspect: 1.15, medial_flat: 0.05}
          D: {girth_cm: 34, height_cm: 42}
      friction: 0.4

Per level: girth_cm and height_cm (above the floor) in centimetres, as charts give them; the
section's shape (all optional): aspect (medio-lateral over antero-posterior width, 1 a circle),
medial_flat (the share by which the medial side is flattened, 0 to 0.5) and crest (a tibial
crest standing out anteriorly by this share of the radius, 0 to 0.3). Levels' heights must rise
in the order given. Imports nothing from clothsim but the pydantic base (``clothsim.config`` imports it).
"""

from __future__ import annotations

import math

from pydantic import Field, field_validator, model_validator

from .strict import Strict as _Strict

#: the measuring levels of a leg as the standards name them, from the ankle up (RAL-GZ 387/1;
#: docs/guide/levels.md: B the smallest girth above the ankle bone, B1 where the Achilles tendon
#: meets the calf muscle, C the calf's largest, D the smallest below the knee, E, F, G the knee
#: and the thigh)
LEG_LEVELS = ("B", "B1", "C", "D", "E", "F", "G")


def _finite(v, what="finite"):
    if not math.isfinite(v):
        raise ValueError(f"must be {what} (got {v})")
    return v


class LegLevel(_Strict):
    """One measuring level: girth_cm, height_cm (above the floor) and the section's shape."""

    girth_cm: float
    height_cm: float
    aspect: float = 1.0
    medial_flat: float = 0.0
    crest: float = 0.0

    @field_validator("girth_cm")
    @classmethod
    def _girth(cls, v):
        if not (math.isfinite(v) and 1.0 <= v <= 300.0):
            raise ValueError(f"must be from 1 to 300 cm (got {v})")
        return v

    @field_validator("height_cm")
    @classmethod
    def _height(cls, v):
        if not (math.isfinite(v) and 0.0 <= v <= 300.0):
            raise ValueError(f"must be from 0 to 300 cm (got {v})")
        return v

    @field_validator("aspect")
    @classmethod
    def _aspect(cls, v):
        if not (math.isfinite(v) and 0.3 <= v <= 3.0):
            raise ValueError(f"must be from 0.3 to 3 (got {v})")
        return v

    @field_validator("medial_flat")
    @classmethod
    def _flat(cls, v):
        if not (math.isfinite(v) and 0.0 <= v <= 0.5):
            raise ValueError(f"must be from 0 to 0.5 (got {v})")
        return v

    @field_validator("crest")
    @classmethod
    def _crest(cls, v):
        if not (math.isfinite(v) and 0.0 <= v <= 0.3):
            raise ValueError(f"must be from 0 to 0.3 (got {v})")
        return v


class LegParams(_Strict):
    """A limb from a size chart (docs/guide/levels.md): levels, the chart's measuring levels by
    name (girth_cm, height_cm above the floor, and optionally the section's aspect, medial_flat,
    crest); center (x, y) [m] its vertical axis; floor [m] the z of the sole; anterior and
    medial the front's and the inner side's directions (x, y); extend [m] the length over which
    it tends to a fixed section beyond its end levels; harmonics, the Fourier terms of a
    section."""

    levels: dict[str, LegLevel] = Field(min_length=2)
    center: tuple[float, float] = (0.0, 0.0)
    floor: float = 0.0
    anterior: tuple[float, float] = (0.0, -1.0)
    medial: tuple[float, float] = (1.0, 0.0)
    extend: float = 0.05
    harmonics: int = 16

    @field_validator("center", "anterior", "medial")
    @classmethod
    def _pair(cls, v):
        for x in v:
            _finite(x)
            if abs(x) > 1e6:
                raise ValueError(f"must be at most 1e6 in size (got {list(v)})")
        return v

    @field_validator("floor")
    @classmethod
    def _floor(cls, v):
        _finite(v)
        if abs(v) > 1e6:
            raise ValueError(f"must be at most 1e6 m in size (got {v})")
        return v

    @field_validator("extend")
    @classmethod
    def _extend(cls, v):
        if not (math.isfinite(v) and 0.001 <= v <= 1.0):
            raise ValueError(f"must be from 0.001 to 1 m (got {v})")
        return v

    @field_validator("harmonics")
    @classmethod
    def _harmonics(cls, v):
        if not 1 <= v <= 64:
            raise ValueError(f"must be from 1 to 64 (got {v})")
        return v

    @model_validator(mode="after")
    def _directions(self):
        a, m = self.anterior, self.medial
        na, nm = math.hypot(*a), math.hypot(*m)
        if na == 0 or nm == 0:
            raise ValueError("anterior, medial: must be non-zero directions")
        if abs(a[0] * m[0] + a[1] * m[1]) > 1e-6 * na * nm:
            raise ValueError(f"medial: must be perpendicular to anterior (got anterior {list(a)}, medial {list(m)})")
        names = list(self.levels)
        h = [self.levels[k].height_cm for k in names]
        for k in range(1, len(h)):
            if not h[k] > h[k - 1]:
                raise ValueError(f"levels.{names[k]}.height_cm: the levels' heights must rise in the order given "
                                 f"({names[k - 1]} at {h[k - 1]} cm, {names[k]} at {h[k]} cm)")
        return self
