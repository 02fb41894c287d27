"""hild's JSON parameter values as rcl_interfaces/ParameterValue, and back.

A hild parameter is a JSON value at a dotted path. ROS has ten types: booleans, integers, doubles and strings, and
arrays of each (and bytes). A JSON value maps to the one of them it is; what ROS cannot hold (a mapping, a list
mixing kinds or holding lists) has no ROS type: :func:`ros_type` says so with None, and callers show its JSON text.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from hild.api.ros2 import types

PARAMETER_VALUE = "rcl_interfaces/msg/ParameterValue"
# rcl_interfaces/msg/ParameterType
NOT_SET, BOOL, INTEGER, DOUBLE, STRING, BYTE_ARRAY, BOOL_ARRAY, INTEGER_ARRAY, DOUBLE_ARRAY, STRING_ARRAY = range(10)
TYPE_NAMES = ("not set", "bool", "integer", "double", "string", "byte array", "bool array", "integer array",
              "double array", "string array")  # fmt: skip
FIELDS = {
    BOOL: "bool_value",
    INTEGER: "integer_value",
    DOUBLE: "double_value",
    STRING: "string_value",
    BYTE_ARRAY: "byte_array_value",
    BOOL_ARRAY: "bool_array_value",
    INTEGER_ARRAY: "integer_array_value",
    DOUBLE_ARRAY: "double_array_value",
    STRING_ARRAY: "string_array_value",
}
INT64 = (-(2**63), 2**63 - 1)


def _scalar_type(value: Any) -> int | None:
    if isinstance(value, bool):  # before int: a bool is an int in Python
        return BOOL
    if isinstance(value, int):
        return INTEGER if INT64[0] <= value <= INT64[1] else None
    if isinstance(value, float):
        return DOUBLE
    if isinstance(value, str):
        return STRING
    return None


def ros_type(value: Any) -> int | None:
    """The ROS type of a JSON value, or None when ROS has none for it. ``null`` is NOT_SET; an empty list a
    string array (ROS cannot tell which array it is); integers mixed with floats a double array."""
    if value is None:
        return NOT_SET
    scalar = _scalar_type(value)
    if scalar is not None:
        return scalar
    if not isinstance(value, list):
        return None
    kinds = {_scalar_type(item) for item in value}
    if not value or kinds == {STRING}:
        return STRING_ARRAY
    if kinds == {BOOL}:
        return BOOL_ARRAY
    if kinds == {INTEGER}:
        return INTEGER_ARRAY
    if kinds <= {INTEGER, DOUBLE}:
        return DOUBLE_ARRAY
    return None


def to_ros(value: Any) -> Any:
    """A ParameterValue holding ``value``; one ROS has no type for is its JSON text, as a string."""
    kind = ros_type(value)
    if kind is None:
        kind, value = STRING, json.dumps(value, separators=(",", ":"))
    if kind == DOUBLE_ARRAY:
        value = np.asarray(value, dtype=np.float64)
    elif kind == INTEGER_ARRAY:
        value = np.asarray(value, dtype=np.int64)
    elif kind == BOOL_ARRAY:
        value = np.asarray(value, dtype=bool)
    fields: dict[str, Any] = {"type": kind}
    if kind != NOT_SET:
        fields[FIELDS[kind]] = value
    return message_with_defaults(fields)


def message_with_defaults(fields: dict[str, Any]) -> Any:
    """A ParameterValue with every field not given at its zero (rosbags wants them all)."""
    defaults: dict[str, Any] = {
        "type": NOT_SET,
        "bool_value": False,
        "integer_value": 0,
        "double_value": 0.0,
        "string_value": "",
        "byte_array_value": np.zeros(0, dtype=np.uint8),
        "bool_array_value": np.zeros(0, dtype=bool),
        "integer_array_value": np.zeros(0, dtype=np.int64),
        "double_array_value": np.zeros(0, dtype=np.float64),
        "string_array_value": [],
    }
    return types.message(PARAMETER_VALUE, **{**defaults, **fields})


def from_ros(value: Any) -> Any:
    """The JSON value a ParameterValue holds; ValueError (the reason, for the reply) for one hild cannot take."""
    kind = int(value.type)
    if kind == NOT_SET:
        raise ValueError("a parameter cannot be unset (type not set): hild's parameters always have a value")
    if kind == BYTE_ARRAY:
        raise ValueError("hild has no byte array parameters")
    if kind not in FIELDS:
        raise ValueError(f"unknown parameter type {kind}")
    raw = getattr(value, FIELDS[kind])
    if kind in (BOOL_ARRAY, INTEGER_ARRAY, DOUBLE_ARRAY):
        return np.asarray(raw).tolist()
    if kind == STRING_ARRAY:
        return [str(item) for item in raw]
    if kind == BOOL:
        return bool(raw)
    if kind == INTEGER:
        return int(raw)
    if kind == DOUBLE:
        return float(raw)
    return str(raw)


def type_name(kind: int) -> str:
    return TYPE_NAMES[kind] if 0 <= kind < len(TYPE_NAMES) else f"type {kind}"
