"""The typestore: rosbags' Jazzy messages plus ``definitions``; CDR both ways and RIHS01 hashes of msgs and srvs.

Why rosbags: a pure-Python, well-kept CDR and REP-2016 implementation whose hashes match published vectors; what
it lacks (services, actions, controller_manager_msgs, control_msgs) is registered here from plain definitions, and
a service's hash is rosbags' own algorithm applied to the struct rosidl generates for it (request, response and
event message; an action's SendGoal and GetResult are services too), so there is one hashing code path.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from hild.api.ros2.definitions import ACTIONS, MESSAGES, SERVICES

EVENT_INFO = "service_msgs/msg/ServiceEventInfo"


class CdrError(ValueError):
    """A payload that is not a CDR encoding of the expected type."""


def _unmangle(node: Any) -> Any:
    """rosbags' msg parser files every referenced name under ``msg/``; a srv or action struct is not."""
    if isinstance(node, str):
        return node.replace("/srv/msg/", "/srv/").replace("/action/msg/", "/action/")
    if isinstance(node, tuple | list):
        return type(node)(_unmangle(item) for item in node)
    return node


def _parse(text: str, package: str) -> tuple[Any, Any]:
    """Constants and fields of one definition of ``package`` (where its unqualified type names live)."""
    ((_, definition),) = get_types_from_msg(text, f"{package}/msg/T").items()
    return _unmangle(definition)


def _base_store() -> Typestore:
    """rosbags' Jazzy store, with one correction: rosidl maps a .msg ``char`` to IDL ``uint8``, so every ``char``
    field is hashed as ``uint8`` (rosbags 0.11.9 hashes ``char``: then no service hash matches Jazzy, through
    ServiceEventInfo's ``char[16] client_gid``, nor does e.g. rmw_dds_common/msg/Gid). CDR is the same either way:
    one byte per element."""
    store = get_typestore(Stores.ROS2_JAZZY)  # a fresh store per call
    for name, (consts, fields) in list(store.fielddefs.items()):
        store.fielddefs[name] = (consts, [_char_as_uint8(field) for field in fields])
    return store


def _char_as_uint8(node: Any) -> Any:
    """Every ``char`` in a field definition as ``uint8``."""
    if node == "char":
        return "uint8"
    if isinstance(node, tuple):
        return tuple(_char_as_uint8(item) for item in node)
    return node


def _service_types(name: str, request: str, response: str) -> dict[str, tuple[Any, Any]]:
    """The four structs rosidl generates for a service (REP-2016: the service hash covers all of them)."""
    req, res, evt = f"{name}_Request", f"{name}_Response", f"{name}_Event"
    package = name.split("/")[0]
    return {
        req: _parse(request, package),
        res: _parse(response, package),
        evt: _parse(f"{EVENT_INFO} info\n{req}[<=1] request\n{res}[<=1] response\n", package),
        name: _parse(f"{req} request_message\n{res} response_message\n{evt} event_message\n", package),
    }


def _action_types(name: str, goal: str, result: str, feedback: str) -> dict[str, tuple[Any, Any]]:
    """What rosidl generates for an action: Goal/Result/Feedback, the SendGoal and GetResult services and the
    FeedbackMessage (the keys of rmw_zenoh carry the hashes of these three)."""
    uuid = "unique_identifier_msgs/UUID goal_id"
    package = name.split("/")[0]
    out = {
        f"{name}_Goal": _parse(goal, package),
        f"{name}_Result": _parse(result, package),
        f"{name}_Feedback": _parse(feedback, package),
        f"{name}_FeedbackMessage": _parse(f"{uuid}\n{name}_Feedback feedback\n", package),
    }
    out.update(
        _service_types(f"{name}_SendGoal", f"{uuid}\n{name}_Goal goal", "bool accepted\nbuiltin_interfaces/Time stamp")
    )
    out.update(_service_types(f"{name}_GetResult", uuid, f"int8 status\n{name}_Result result"))
    return out


@cache
def typestore(distro: str = "jazzy") -> Typestore:
    """rosbags' store for ``distro`` with hild's extra definitions registered (built once)."""
    if distro != "jazzy":
        raise ValueError(f"ROS 2 distro {distro!r} is not supported (jazzy only)")
    store = _base_store()
    extra: dict[str, tuple[Any, Any]] = {name: _parse(text, name.split("/")[0]) for name, (text, _) in MESSAGES.items()}
    for name, srv in SERVICES.items():
        extra.update(_service_types(name, srv.request, srv.response))
    for name, action in ACTIONS.items():
        extra.update(_action_types(name, action.goal, action.result, action.feedback))
    store.register(extra)
    return store


def service_store(name: str, request: str, response: str) -> Typestore:
    """A fresh store with one more service registered (tests check the algorithm on published vectors)."""
    store = _base_store()
    store.register(_service_types(name, request, response))
    return store


def action_store(name: str, goal: str, result: str, feedback: str) -> Typestore:
    """A fresh store with one more action registered (tests check the algorithm on published vectors)."""
    store = _base_store()
    store.register(_action_types(name, goal, result, feedback))
    return store


def type_hash(name: str, distro: str = "jazzy") -> str:
    """``RIHS01_<sha256>`` of a message or service type, e.g. ``sensor_msgs/msg/JointState``."""
    return typestore(distro).hash_rihs01(name)


def dds_name(name: str) -> str:
    """``pkg/msg/Name`` → ``pkg::msg::dds_::Name_``: the type chunk of rmw_zenoh's keys."""
    package, kind, short = name.split("/")
    return f"{package}::{kind}::dds_::{short}_"


def message(type_name: str, /, *, _distro: str = "jazzy", **fields: Any) -> Any:
    """A message object of type ``type_name`` (positional: a message may have a field called ``name``)."""
    return typestore(_distro).types[type_name](**fields)


def encode(msg: Any, name: str, distro: str = "jazzy") -> bytes:
    """CDR little-endian with its 4-byte encapsulation header (00 01 00 00), as rmw_zenoh sends it."""
    return bytes(typestore(distro).serialize_cdr(msg, name, little_endian=True))


def decode(raw: bytes, name: str, distro: str = "jazzy") -> Any:
    """A CDR payload of type ``name``; :class:`CdrError` for anything else (short, trailing garbage, bad header)."""
    if len(raw) < 4 or raw[0] != 0 or raw[1] not in (0, 1):
        raise CdrError(f"not a CDR payload: encapsulation header {raw[:4].hex() or 'missing'}")
    try:
        msg = typestore(distro).deserialize_cdr(raw, name)
    except Exception as exc:  # rosbags raises struct.error, IndexError, UnicodeDecodeError, AssertionError …
        raise CdrError(f"malformed CDR for {name}: {type(exc).__name__}: {exc}") from None
    return msg
