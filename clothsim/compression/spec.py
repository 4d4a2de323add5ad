"""Scene fields for compression engineering: ``probes``, ``profiles`` and ``classes``.

::

    probes:                              # pressure sensors: discs on the mold
      - {name: ankle, point: [0.05, 0, 0.04], radius: 0.01}   # radius [m], default 0.01 (1 cm)
    profiles:                            # slices of the contact along an axis
      - {name: leg, axis: z, from: 0.01, to: 0.07, step: 0.005}
    classes: {probe: ankle}              # the class of the ankle probe under every known standard
    # classes: {probe: ankle, standards: [RAL-GZ 387], extra: [{name: mine, classes: [...]}]}

Units: metres; pressures in the outputs are Pa and mmHg (1 mmHg = 133.322 Pa). This module
imports only the leaves ``clothsim.strict`` and :mod:`.standards` (``clothsim.config`` imports it).
"""

from __future__ import annotations

import math
from typing import Literal, Union

from pydantic import ConfigDict, Field, field_validator, model_validator

from ..strict import Strict as _Strict, finite_values, positive_finite
from .standards import STANDARDS, ClassBand, Standard  # noqa: F401  (ClassBand re-exported)

#: a sensor's default radius [m]: the 1-2 cm discs used to measure garments on limbs
DEFAULT_PROBE_RADIUS = 0.01


class Probe(_Strict):
    """A pressure sensor: a disc of ``radius`` [m] on the mold, centred at the mold point closest
    to ``point`` [m]. It reads the total normal contact force on the sheet inside the disc divided
    by the disc's area (pi radius^2)."""

    name: str = Field(min_length=1)
    point: tuple[float, float, float] | None = None
    radius: float = DEFAULT_PROBE_RADIUS
    # instead of point: a measuring level (B, C, ... of the scene's levels or its leg's chart)
    # and a side of it; the point is then that side's surface point at the level (.levels)
    level: str | None = None
    side: Literal["anterior", "posterior", "medial", "lateral"] | None = None

    _point = field_validator("point")(classmethod(lambda cls, v: v if v is None else finite_values(v)))
    _radius = field_validator("radius")(classmethod(lambda cls, v: positive_finite(v)))

    @model_validator(mode="after")
    def _where(self):
        if self.point is None and (self.level is None or self.side is None):
            raise ValueError("give point [x, y, z], or level and side (e.g. {level: B, side: medial})")
        if self.point is not None and (self.level is not None or self.side is not None):
            raise ValueError("give point, or level and side, not both")
        return self


class Profile(_Strict):
    """Slices of the contact along ``axis`` ('x', 'y', 'z' or a direction vector): one slice at
    each height ``from``, ``from + step``, ... up to ``to`` [m] (height = axis . x). The gradient
    check reads the slices from ``from`` (the ankle end) to ``to``: the pressure falls steadily
    when no slice's mean rises by more than ``steady_tolerance_mmhg`` over the one before."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, serialize_by_alias=True)

    name: str = Field(min_length=1)
    axis: Union[Literal["x", "y", "z"], tuple[float, float, float]] = "z"
    start: float = Field(alias="from")
    to: float
    step: float
    steady_tolerance_mmhg: float = 0.1

    _step = field_validator("step")(classmethod(lambda cls, v: positive_finite(v)))

    @field_validator("axis")
    @classmethod
    def _axis(cls, v):
        if isinstance(v, tuple):
            finite_values(v)
            if math.hypot(*v) == 0.0:
                raise ValueError("must not be the zero vector")
        return v

    @model_validator(mode="after")
    def _range(self):
        if not (math.isfinite(self.start) and math.isfinite(self.to)) or self.to < self.start:
            raise ValueError(f"to: must be finite and not below from (from {self.start}, to {self.to})")
        if (self.to - self.start) / self.step > 10_000:
            raise ValueError(f"step: {self.step} m gives more than 10000 slices")
        return self

    def unit_axis(self) -> tuple[float, float, float]:
        if isinstance(self.axis, str):
            return {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}[self.axis]
        n = math.hypot(*self.axis)
        return tuple(a / n for a in self.axis)  # type: ignore[return-value]

    def heights(self) -> list[float]:
        """Slice heights [m]: from, from + step, ..., the last not beyond ``to`` (1e-9 slack)."""
        n = int(math.floor((self.to - self.start) / self.step + 1e-9))
        return [self.start + k * self.step for k in range(n + 1)]


class Classes(_Strict):
    """Report the class of probe ``probe`` under ``standards`` (names of built-in or ``extra``
    standards; default: every built-in one) and under the user's ``extra`` standards."""

    probe: str
    standards: list[str] | None = None
    extra: list[Standard] = Field(default_factory=list)


def check_compression(probes: list[Probe], profiles: list[Profile], classes: Classes | None) -> None:
    """Scene-level checks: unique names, a classes probe that exists, standards that exist.
    Raises ValueError("field.path: message") (the scene loader folds the path into its message)."""
    seen = set()
    for k, p in enumerate(probes):
        if p.name in seen:
            raise ValueError(f"probes.{k}.name: '{p.name}' is used twice")
        seen.add(p.name)
    pseen = set()
    for k, p in enumerate(profiles):
        if p.name in pseen:
            raise ValueError(f"profiles.{k}.name: '{p.name}' is used twice")
        pseen.add(p.name)
    if classes is not None:
        if classes.probe not in seen:
            raise ValueError(f"classes.probe: no probe named '{classes.probe}' (probes: {', '.join(sorted(seen)) or 'none'})")
        known = {s.name for s in STANDARDS} | {s.name for s in classes.extra}
        for k, name in enumerate(classes.standards or []):
            if name not in known:
                raise ValueError(f"classes.standards.{k}: unknown standard '{name}' (known: {', '.join(sorted(known))})")
