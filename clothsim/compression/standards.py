"""Compression classes as data, and the class of a measured pressure.

Each standard gives ranges of resting pressure at the ankle (mmHg). Between two classes a
pressure belongs to neither ("between classes I and II"); below the first it is "below class I".

Sources (checked for this table):

- RAL-GZ 387 (RAL Deutsches Institut fur Gutesicherung und Kennzeichnung, "Medizinische
  Kompressionsstrumpfe", the German quality mark used in Germany, Austria, Switzerland and the
  Netherlands): class I 18-21, II 23-32, III 34-46, IV 49 mmHg and more at the ankle
  (2.4-2.8, 3.1-4.3, 4.5-6.1, >= 6.5 kPa), as listed by the hosiery makers Ofa Bamberg
  (ofa-bamberg.com, "Compression therapy") and Credenhill (credenhill.co.uk, "How much
  compression?").
- UK Drug Tariff, Part IXA, Specification 40 (graduated compression hosiery, tested on the HATRA
  apparatus of BS 6612:1985): class 1 14-17, class 2 18-24, class 3 25-35 mmHg at the ankle, as
  listed by Credenhill (credenhill.co.uk, "How much compression?").

Users extend the table with ``classes.extra`` in a scene (see :class:`Standard`) or by
appending to :data:`STANDARDS`.
"""

from __future__ import annotations

import math

from pydantic import Field, model_validator

from ..strict import Strict as _Strict


class ClassBand(_Strict):
    """One class of a standard: pressures from ``min`` to ``max`` mmHg (``max`` None: and more)."""

    name: str = Field(min_length=1)
    min: float
    max: float | None = None


class Standard(_Strict):
    """A compression-class standard: its classes in rising order, where it is measured (``site``)
    and where its numbers come from (``source``)."""

    name: str = Field(min_length=1)
    site: str = "ankle"
    source: str = ""
    classes: list[ClassBand] = Field(min_length=1)

    @model_validator(mode="after")
    def _rising(self):
        prev = -math.inf
        for k, c in enumerate(self.classes):
            hi = math.inf if c.max is None else c.max
            if not (c.min >= prev and hi >= c.min):
                raise ValueError(f"classes.{k}: classes must rise and not overlap (min {c.min}, max {c.max})")
            if c.max is None and k != len(self.classes) - 1:
                raise ValueError(f"classes.{k}.max: only the last class may be open-ended")
            prev = hi
        return self


STANDARDS: list[Standard] = [
    Standard(
        name="RAL-GZ 387",
        site="ankle",
        source="RAL-GZ 387 (Germany): resting pressure at the ankle (B measuring point)",
        classes=[ClassBand(name="I", min=18, max=21), ClassBand(name="II", min=23, max=32),
                 ClassBand(name="III", min=34, max=46), ClassBand(name="IV", min=49, max=None)],
    ),
    Standard(
        name="UK Drug Tariff",
        site="ankle",
        source="UK Drug Tariff Part IXA, Specification 40 (BS 6612:1985 HATRA test): pressure at the ankle",
        classes=[ClassBand(name="1", min=14, max=17), ClassBand(name="2", min=18, max=24),
                 ClassBand(name="3", min=25, max=35)],
    ),
]


def standard(name: str, extra: list[Standard] | None = None) -> Standard:
    for s in [*(extra or []), *STANDARDS]:
        if s.name == name:
            return s
    raise KeyError(name)


def classify(mmhg: float, std: Standard) -> str:
    """The class of a pressure [mmHg] under ``std``: "class II", "below class I", "between
    classes I and II", "above class 3"; ranges are closed ([min, max]). A standard whose limits
    are all whole mmHg (both built-in ones) states its pressures to the whole mmHg, so the
    pressure is rounded to the whole mmHg (half up) first: 24.99 mmHg is UK class 3, not "between
    classes 2 and 3" (a gap of the table's rounding, not of the standard); RAL-GZ 387's 21-23 gap
    is a real one (22 mmHg is between classes I and II)."""
    if not math.isfinite(mmhg):
        return "undefined (pressure not finite)"
    cl = std.classes
    if all(float(x).is_integer() for c in cl for x in (c.min, c.max) if x is not None):
        mmhg = math.floor(mmhg + 0.5)
    if mmhg < cl[0].min:
        return f"below class {cl[0].name}"
    for k, c in enumerate(cl):
        hi = math.inf if c.max is None else c.max
        if c.min <= mmhg <= hi:
            return f"class {c.name}"
        if k + 1 < len(cl) and hi < mmhg < cl[k + 1].min:
            return f"between classes {c.name} and {cl[k + 1].name}"
    return f"above class {cl[-1].name}"


def classify_all(mmhg: float, names: list[str] | None = None, extra: list[Standard] | None = None) -> list[dict]:
    """[{standard, site, class, source}] for each named standard (default: every built-in one),
    then each extra one."""
    extra = list(extra or [])
    chosen = [standard(n, extra) for n in names] if names else list(STANDARDS)
    for s in extra:
        if s not in chosen:
            chosen.append(s)
    return [{"standard": s.name, "site": s.site, "class": classify(mmhg, s), "source": s.source} for s in chosen]
