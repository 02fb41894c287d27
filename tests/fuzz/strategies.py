"""Hypothesis strategies for bad input: raw payload bytes for any endpoint, and near-misses per endpoint.

Payloads are built as Python structures that may hold :class:`Raw` tokens (text pasted verbatim: ``NaN``,
``1e999``, a 5000-digit integer, a lone surrogate escape) and serialized by :func:`to_json`, so one strategy covers
well-formed JSON, non-standard JSON and everything in between. The per-endpoint strategies start from a valid body
and inject at least one defect, so every example they draw is invalid by construction: the daemon must refuse or
drop it, and nothing may move.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from hypothesis import strategies as st

from hild.controllers.trajectory_goals import GOAL_KEYS, MOVE_KEYS, POINT_KEYS
from tests.fuzz.daemon import CONTROLLERS, JOINTS, SOFT_MARGIN, UPPER, VELOCITY


@dataclass(frozen=True)
class Raw:
    """JSON text inserted as is (it may be invalid JSON on purpose)."""

    text: str


def to_json(obj: Any, ensure_ascii: bool = True) -> str:
    """Like json.dumps, but floats may be NaN/Infinity (non-standard tokens) and Raw tokens are pasted verbatim."""
    if isinstance(obj, Raw):
        return obj.text
    if isinstance(obj, bool) or obj is None:
        return json.dumps(obj)
    if isinstance(obj, float):
        if math.isnan(obj):
            return "NaN"
        if math.isinf(obj):
            return "Infinity" if obj > 0 else "-Infinity"
        return repr(obj)
    if isinstance(obj, int):
        return str(obj)
    if isinstance(obj, str):
        return json.dumps(obj, ensure_ascii=ensure_ascii)
    if isinstance(obj, list):
        return "[" + ",".join(to_json(v, ensure_ascii) for v in obj) + "]"
    if isinstance(obj, dict):
        items = (f"{to_json(str(k), ensure_ascii)}:{to_json(v, ensure_ascii)}" for k, v in obj.items())
        return "{" + ",".join(items) + "}"
    raise TypeError(type(obj).__name__)


def encoded(obj: Any, ensure_ascii: bool = True) -> bytes:
    return to_json(obj, ensure_ascii).encode("utf-8", "surrogatepass")  # a lone surrogate makes invalid UTF-8


# ---- vocabulary ------------------------------------------------------------------------------------------------
FIELD_NAMES = (
    "positions", "velocities", "accelerations", "effort", "time_from_start", "trajectory", "joint_names", "points",
    "path_tolerance", "goal_tolerance", "goal_time_tolerance", "duration", "goal_id", "values", "activate",
    "deactivate", "strict", "joint", "confirm", "joints", "name", "position", "velocity", "sec", "nanosec",
)  # fmt: skip
NAMES = (*JOINTS, *CONTROLLERS, "jsb", "nope", "", " ", "a/b", "*", "$", "..", "ä", "名前")
RAW_TOKENS = (
    "NaN", "-NaN", "Infinity", "-Infinity", "inf", "nan", "1e999", "-1e400", "1" * 400, "-" + "9" * 5000,
    "1E+2", "-0", "0.0000001e-400", '"\\ud800"', '"\\udfff\\ud800"', '"\\u0000"', "true", "null",
)  # fmt: skip
NOT_JSON = (
    b"", b" ", b"\x00", b"\xff\xfe\xfd", b"\xef\xbb\xbf{}", b"{}{}", b"{} x", b"[1,]", b"{'a': 1}", b"{a: 1}",
    b'{"a":1,}', b"01", b"+1", b".5", b"0x10", b"\"unterminated", b"[" * 3, b"}", b"null", b"true", b"[]", b"{}",
    b'"\xed\xa0\x80"', b"\xc0\x80",
)  # fmt: skip

names = st.sampled_from(FIELD_NAMES) | st.sampled_from(NAMES) | st.text(max_size=12)
huge_ints = st.integers(min_value=10**20, max_value=10**300) | st.integers(min_value=-(10**300), max_value=-(10**20))
scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | huge_ints
    | st.floats()  # NaN and ±inf included: serialized as the non-standard tokens
    | st.sampled_from(["NaN", "nan", "inf", "-Infinity", "1e999", "0.1", ""])  # the same, as strings
    | st.text(max_size=20)
    | st.sampled_from(RAW_TOKENS).map(Raw)
)
json_values = st.recursive(
    scalars,
    lambda children: st.lists(children, max_size=5) | st.dictionaries(names, children, max_size=5),
    max_leaves=25,
)


def nesting(depth: int, kind: str, balanced: bool) -> bytes:
    opener, closer = {"list": (b"[", b"]"), "object": (b'{"a":', b"}")}[kind]
    inner = b"0"
    return opener * depth + inner + closer * (depth if balanced else depth // 2)


deep = st.builds(nesting, st.integers(1, 10_000) | st.just(10_000), st.sampled_from(["list", "object"]), st.booleans())

raw_payloads = st.one_of(
    st.builds(encoded, json_values, st.booleans()),
    st.binary(max_size=64),
    st.sampled_from(NOT_JSON),
    st.text(max_size=40).map(lambda t: t.encode("utf-8", "surrogatepass")),
    deep,
)


# ---- near-misses per endpoint ----------------------------------------------------------------------------------
def _in_limits(limit: float) -> st.SearchStrategy[float]:
    return st.floats(-limit, limit, allow_nan=False)


def _beyond(limit: float) -> st.SearchStrategy[Any]:
    """A finite number (or int) outside ±limit."""
    magnitude = st.floats(limit * 1.01, 1e300) | st.integers(int(limit) + 1, 10**300).map(float)
    return st.tuples(magnitude, st.booleans()).map(lambda mv: -mv[0] if mv[1] else mv[0])


not_a_number = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=8),
    st.sampled_from(["0.1", "NaN", "1e999"]),
    st.lists(st.floats(allow_nan=False), max_size=2),
    st.dictionaries(names, st.integers(), max_size=2),
    st.sampled_from(["NaN", "Infinity", "-Infinity", "1e999", "-1e999", "1" * 400, "1" * 5000]).map(Raw),
)
SOFT = UPPER - SOFT_MARGIN


def _vector(n: int, limit: float) -> st.SearchStrategy[list[Any]]:
    return st.lists(_in_limits(limit), min_size=n, max_size=n)


@st.composite
def _spoil_vector(draw: st.DrawFn, values: list[Any], bad_element: st.SearchStrategy[Any]) -> Any:
    """``values`` made invalid: a wrong length, a bad element, or not a list at all."""
    kind = draw(st.sampled_from(["length", "element", "type"]))
    if kind == "length":
        n = draw(st.sampled_from([0, 1, 3, 4, 7, 1000]))
        return draw(st.lists(_in_limits(0.5), min_size=n, max_size=n))
    if kind == "element":
        out = list(values)
        out[draw(st.integers(0, len(out) - 1))] = draw(bad_element)
        return out
    return draw(st.one_of(st.none(), st.text(max_size=5), st.floats(), st.dictionaries(names, st.integers())))


@st.composite
def _spoil_keys(draw: st.DrawFn, body: dict[str, Any], required: str, allowed: set[str]) -> Any:
    """``body`` made invalid by its keys: an unknown one, the required one missing, or not an object."""
    kind = draw(st.sampled_from(["unknown", "missing", "not_object"]))
    if kind == "unknown":
        key = draw(names.filter(lambda k: k not in allowed))
        return {**body, key: draw(json_values)}
    if kind == "missing":
        return {k: v for k, v in body.items() if k != required}
    return draw(st.one_of(st.just(list(body.values())), st.text(max_size=5), st.integers(), st.none()))


@st.composite
def bad_commands(draw: st.DrawFn) -> bytes:
    """forward_command ``{"values": [e, f]}`` with one defect; out-of-limit values count as defects here."""
    values = draw(_vector(2, SOFT))
    kind = draw(st.sampled_from(["values", "values", "out_of_limits", "keys"]))
    if kind == "values":
        body: Any = {"values": draw(_spoil_vector(values, not_a_number))}
    elif kind == "out_of_limits":
        values[draw(st.integers(0, 1))] = draw(_beyond(UPPER))
        body = {"values": values}
    else:
        body = draw(_spoil_keys({"values": values}, "values", {"values"}))
    return encoded(body, draw(st.booleans()))


@st.composite
def bad_targets(draw: st.DrawFn) -> bytes:
    """servo ``{"positions": [c, d], "velocities"?: [...]}`` with one defect (out-of-limit targets are clamped,
    so they are not defects; ``"velocities": null`` means none)."""
    body: dict[str, Any] = {"positions": draw(_vector(2, SOFT))}
    if draw(st.booleans()):
        body["velocities"] = draw(_vector(2, VELOCITY / 2))
    field = draw(st.sampled_from(["positions", "velocities", "keys"]))
    if field == "keys":
        spoiled: Any = draw(_spoil_keys(body, "positions", {"positions", "velocities"}))
    else:
        spoiled = dict(body)
        base = body.get(field) or draw(_vector(2, 0.5))
        value = draw(_spoil_vector(base, not_a_number))
        if field == "velocities" and value is None:
            value = draw(st.text(max_size=3))
        spoiled[field] = value
    return encoded(spoiled, draw(st.booleans()))


GOAL_JOINTS = list(CONTROLLERS["joint_trajectory"])


@st.composite
def _points(draw: st.DrawFn, timed: bool) -> list[dict[str, Any]]:
    n = draw(st.integers(1, 6))
    points: list[dict[str, Any]] = []
    t = 0.0
    for _ in range(n):
        point: dict[str, Any] = {"positions": draw(_vector(2, SOFT))}
        if timed:
            t += draw(st.floats(0.5, 3.0))
            point["time_from_start"] = t
        points.append(point)
    return points


def _bad_joint_names() -> st.SearchStrategy[Any]:
    return st.one_of(
        st.just(["a", "z"]),
        st.just(["a", "a"]),
        st.just(["a"]),  # partial: not allowed by this controller
        st.just([]),
        st.just(["b", "a", "c"]),
        st.lists(st.sampled_from(NAMES).filter(lambda n: n not in GOAL_JOINTS), min_size=1, max_size=3),
        st.one_of(st.none(), st.text(max_size=3), st.integers(), st.lists(st.integers(), min_size=1, max_size=2)),
    )


def _bad_tolerance() -> st.SearchStrategy[Any]:
    bad_value = st.one_of(
        st.floats(-1e9, -1e-6).filter(lambda v: v != -1.0),
        not_a_number.filter(lambda v: v is not None),
    )
    entry = st.fixed_dictionaries({"name": st.sampled_from(GOAL_JOINTS), "position": bad_value})
    return st.one_of(
        st.lists(entry, min_size=1, max_size=2),
        st.just([{"position": 0.1}]),
        st.just([{"name": "z", "position": 0.1}]),
        st.just([{"name": "a", "jerk": 0.1}]),
        st.just([7]),
        st.one_of(st.text(max_size=3), st.integers(), st.dictionaries(names, st.integers(), min_size=1, max_size=2)),
    )


def _bad_time() -> st.SearchStrategy[Any]:
    return st.one_of(
        not_a_number,
        st.just({"sec": "1"}),
        st.just({"sec": 1, "extra": 2}),
        st.just({"nanosec": True}),
    )


@st.composite
def bad_goals(draw: st.DrawFn) -> bytes:
    """A move_to or trajectory goal with one defect (see docs/protocol.md for the rules they break)."""
    if draw(st.booleans()):
        body: dict[str, Any] = {"positions": draw(_vector(2, SOFT))}
        if draw(st.booleans()):
            body["duration"] = draw(st.floats(0.5, 5.0))
        defect = draw(st.sampled_from(["positions", "beyond", "velocities", "duration", "names", "keys", "tol"]))
        if defect == "positions":
            body["positions"] = draw(_spoil_vector(body["positions"], not_a_number))
        elif defect == "beyond":
            body["positions"][draw(st.integers(0, 1))] = draw(_beyond(SOFT))
        elif defect == "velocities":
            over = draw(_beyond(VELOCITY * 1.05))
            body["velocities"] = draw(st.one_of(st.just([over, 0.0]), _spoil_vector([0.0, 0.0], not_a_number)))
        elif defect == "duration":
            present = not_a_number.filter(lambda v: v is not None)  # "duration": null means none given
            body["duration"] = draw(st.one_of(st.floats(max_value=0.0), present, st.just(Raw("1e999"))))
        elif defect == "names":
            body["joint_names"] = draw(_bad_joint_names())
        elif defect == "keys":
            body = draw(_spoil_keys(body, "positions", MOVE_KEYS | GOAL_KEYS))
        else:
            body[draw(st.sampled_from(["path_tolerance", "goal_tolerance"]))] = draw(_bad_tolerance())
        return encoded(body, draw(st.booleans()))

    timed = draw(st.booleans())
    points = draw(_points(timed))
    trajectory: dict[str, Any] = {"joint_names": list(GOAL_JOINTS), "points": points}
    goal: dict[str, Any] = {"trajectory": trajectory}
    defects = ["empty", "point_type", "point_key", "positions", "beyond", "names", "traj_key", "goal_key", "tol"]
    defects += ["goal_time", "some_velocities", "no_positions"]
    if timed:
        defects += ["time", "negative", "not_increasing", "mixed", "single_zero"]
    else:
        defects += ["accelerations"]
    defect = draw(st.sampled_from(defects))
    k = draw(st.integers(0, len(points) - 1))
    if defect == "empty":
        trajectory["points"] = draw(st.sampled_from([[], None, {}, "points"]))
    elif defect == "point_type":
        points[k] = draw(st.one_of(st.none(), st.integers(), st.text(max_size=3), st.lists(st.integers(), max_size=2)))
    elif defect == "point_key":
        points[k][draw(names.filter(lambda n: n not in POINT_KEYS))] = draw(json_values)
    elif defect == "positions":
        points[k]["positions"] = draw(_spoil_vector(points[k]["positions"], not_a_number))
    elif defect == "beyond":
        points[k]["positions"][draw(st.integers(0, 1))] = draw(_beyond(SOFT))
    elif defect == "names":
        trajectory["joint_names"] = draw(_bad_joint_names())
    elif defect == "traj_key":
        trajectory[draw(names.filter(lambda n: n not in {"joint_names", "points"}))] = draw(json_values)
    elif defect == "goal_key":
        goal[draw(names.filter(lambda n: n not in GOAL_KEYS))] = draw(json_values)
    elif defect == "tol":
        goal[draw(st.sampled_from(["path_tolerance", "goal_tolerance"]))] = draw(_bad_tolerance())
    elif defect == "goal_time":
        goal["goal_time_tolerance"] = draw(st.one_of(st.floats(max_value=-1e-9), not_a_number))
    elif defect == "some_velocities":
        if len(points) < 2:
            points.append({**points[0]})
        points[0]["velocities"] = [0.0, 0.0]
    elif defect == "no_positions":
        del points[k]["positions"]
    elif defect == "time":
        points[k]["time_from_start"] = draw(_bad_time())
    elif defect == "negative":
        points[0]["time_from_start"] = draw(st.floats(-1e6, -1e-6))
    elif defect == "not_increasing":
        if len(points) < 2:
            points.append({**points[0]})
        k = draw(st.integers(1, len(points) - 1))
        points[k]["time_from_start"] = points[k - 1]["time_from_start"] - draw(st.floats(0.0, 0.4))
    elif defect == "mixed":
        if len(points) < 2:
            points.append({**points[0], "time_from_start": points[0]["time_from_start"] + 1.0})
        del points[draw(st.integers(0, len(points) - 1))]["time_from_start"]
    elif defect == "single_zero":
        trajectory["points"] = [{"positions": points[0]["positions"], "time_from_start": 0.0}]
    else:  # accelerations on an untimed trajectory
        for point in points:
            point["accelerations"] = [0.0, 0.0]
    return encoded(goal, draw(st.booleans()))


@st.composite
def bad_goal_ids(draw: st.DrawFn) -> bytes:
    """cancel/result bodies: no goal was ever accepted, so every id is unknown; plus shape defects."""
    goal_id = draw(st.one_of(st.text(max_size=40), st.uuids().map(lambda u: u.hex)))
    body = draw(
        st.one_of(
            st.just({"goal_id": goal_id}),
            st.builds(lambda v: {"goal_id": v}, not_a_number.filter(lambda v: not isinstance(v, str))),
            _spoil_keys({"goal_id": goal_id}, "goal_id", {"goal_id"}),
        )
    )
    return encoded(body, draw(st.booleans()))


SERVICE_FIELDS: dict[str, tuple[str, ...]] = {
    "status": (),
    "list_controllers": (),
    "list_interfaces": (),
    "list_hardware": (),
    "switch_controllers": ("activate", "deactivate", "strict"),
    "estop": (),
    "reset": (),
    "set_zero": ("joint", "confirm"),
    "home": ("joint",),
    "enable": ("joints",),
    "set_hardware_state": ("name", "state"),
    "list_controller_types": (),
    "load_controller": ("name", "type", "params", "fallback_controllers", "chain_to", "by"),
    "configure_controller": ("name",),
    "cleanup_controller": ("name",),
    "unload_controller": ("name",),
    "reload_controller": ("name",),
    "list_parameters": ("controller",),
    "get_parameters": ("controller", "names"),
    "set_parameters": ("controller", "values", "by"),
    "tuned_config": (),
    "teach": ("on", "joints", "by"),
    "record": ("action", "task", "fps", "note"),
    "blackbox": ("seconds",),
}


@st.composite
def service_requests(draw: st.DrawFn, service: str) -> bytes:
    """Anything for a service: raw garbage, random JSON, or its own fields with wrong values."""
    fields = SERVICE_FIELDS[service]
    structured = st.dictionaries(
        st.sampled_from(fields) if fields else names,
        st.one_of(
            json_values,
            st.lists(st.sampled_from(NAMES) | st.text(max_size=5) | st.integers(), max_size=4),
            st.lists(st.just("fwd"), min_size=300, max_size=300),
        ),
        min_size=1,
        max_size=3,
    ).map(encoded)
    return draw(st.one_of(raw_payloads, structured))
