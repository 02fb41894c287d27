"""The base every plugin's parameter model derives from.

Drivers and controllers declare their ``params`` as subclasses of :class:`Params`; the config loader validates
them with the same rules as the rest of the file (unknown keys are errors, types are strict where it matters).
Plugins import ``Params`` and ``Field`` from here so the validation library stays in the config room.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["Field", "Params", "model_validator"]


class Params(BaseModel):
    """Strict, immutable parameter block: unknown keys are rejected, values cannot change after load."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)
