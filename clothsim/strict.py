"""The pydantic base of every file format's models (scene, compression fields, sweep): a field
the model does not know is refused ("unknown field"), never ignored. Imports nothing from
clothsim, so every schema module can build on it."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=False)
