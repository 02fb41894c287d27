"""The base every plugin's parameter model derives from.

Drivers and controllers declare their ``params`` as subclasses of :class:`Params`; the config loader validates
them with the same rules as the rest of the file (unknown keys are errors, types are strict where it matters).
Plugins import ``Params`` and ``Field`` from here so the validation library stays in the config room.
"""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["Field", "Params", "dynamic", "model_validator"]


class Params(BaseModel):
    """Strict, immutable parameter block: unknown keys are rejected, values cannot change after load."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


# ---- parameters that may change while the robot runs ---------------------------------------------------------
DYNAMIC = "dynamic"  # the schema mark: json_schema_extra={"dynamic": True}
MAX_PATH_PARTS = 8  # a parameter path is at most this many dotted parts


def dynamic(default: Any = ..., **kwargs: Any) -> Any:
    """A field that may change while its controller is active: the controller applies it between two cycles
    (``Controller.on_params``) without a step in its command. Everything below a dynamic field is dynamic."""
    return Field(default, json_schema_extra={DYNAMIC: True}, **kwargs)


def is_dynamic(model: type[BaseModel], path: str) -> bool:
    """Whether the parameter at dotted ``path`` is marked dynamic, itself or through a field above it."""
    return describe(model, path)[0]


def describe(model: type[BaseModel], path: str) -> tuple[bool, str]:
    """Whether the parameter at dotted ``path`` is dynamic, and the description of the nearest field that has one
    (a key of a mapping, e.g. a joint's tolerance, is described by its field)."""
    current: Any = model
    dynamic_, description = False, ""
    for part in path.split("."):
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            if typing.get_origin(current) is dict:  # a mapping's key: step to its value type
                current = typing.get_args(current)[-1]
            continue
        info = current.model_fields.get(part)
        if info is None:
            break
        extra = info.json_schema_extra
        dynamic_ = dynamic_ or (isinstance(extra, dict) and bool(extra.get(DYNAMIC)))
        description = info.description or description
        current = info.annotation
    return dynamic_, description


def flatten(params: BaseModel) -> dict[str, Any]:
    """Every parameter as ``dotted.path → value`` (JSON values; mappings of models are walked, lists are values)."""
    out: dict[str, Any] = {}

    def walk(value: Any, prefix: str) -> None:
        if isinstance(value, dict) and value and prefix:
            for key, item in value.items():
                walk(item, f"{prefix}.{key}")
        elif isinstance(value, dict) and not prefix:
            for key, item in value.items():
                walk(item, key)
        else:
            out[prefix] = value

    walk(params.model_dump(mode="json"), "")
    return out


def with_values(params: BaseModel, values: dict[str, Any]) -> BaseModel:
    """A new, validated ``params`` with ``values`` (``dotted.path → value``) set; ValueError names what is wrong.
    A path may name a key of a mapping that does not exist yet (a joint's tolerance), never a field the model
    lacks: validation refuses those, as it refuses unknown keys in a config."""
    data = params.model_dump(mode="json")
    for path, value in values.items():
        parts = path.split(".")
        if not all(parts) or len(parts) > MAX_PATH_PARTS:
            raise ValueError(f"{path!r} is not a parameter path (dotted names, at most {MAX_PATH_PARTS} parts)")
        node = data
        for part in parts[:-1]:
            child = node.get(part) if isinstance(node, dict) else None
            if child is None and isinstance(node, dict):
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ValueError(f"{path!r}: {part!r} holds a value, not parameters")
            node = child
        if not isinstance(node, dict):
            raise ValueError(f"{path!r} is not a parameter path")
        node[parts[-1]] = value
    return type(params).model_validate(data)
