"""The pydantic base of every file format's models (scene, compression fields, sweep): a field
the model does not know is refused ("unknown field"), never ignored; and the number checks
their validators share (one wording for every field). Imports nothing from clothsim, so every
schema module can build on it."""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False)


def finite_values(v):
    """``v`` (a tuple or list of numbers) if every one is finite, else ValueError
    "must be finite (got [...])"."""
    if any(not math.isfinite(x) for x in v):
        raise ValueError(f"must be finite (got {list(v)})")
    return v


def positive_finite(v):
    """``v`` if it is a positive finite number, else ValueError "must be positive and finite
    (got v)"."""
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"must be positive and finite (got {v})")
    return v
