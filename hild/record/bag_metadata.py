"""rosbag2's ``metadata.yaml`` (version 9, as Jazzy writes it), so ``ros2 bag info`` and rosbags open the directory.

Written by hand rather than with a YAML library (PyYAML lives in ``hild/config``): the structure is fixed and every
value is a number, a name hild chose, or a string emitted double-quoted with every non-ASCII character escaped.
The layout follows yaml-cpp's block style as rosbag2 emits it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

VERSION = 9  # rosbag2 Jazzy's metadata version
DISTRO = "jazzy"
_PLAIN = re.compile(r"[A-Za-z_/][A-Za-z0-9_/.\-]*")  # whole text only (fullmatch: `$` would let a final "\n" by)
_RESERVED = {"true", "false", "yes", "no", "on", "off", "null", "y", "n"}

# The offered QoS of every topic: the face's publishers' (hild.api.ros2.wire.DEFAULT_QOS: reliable, volatile,
# keep-last 10), with deadline, lifespan and lease "infinite" (RMW_DURATION_INFINITE) as Jazzy's rmw
# implementations report them; version 9 writes the policies' names, not numbers.
_INFINITE = {"sec": 9223372036, "nsec": 854775807}
QOS_FIELDS: dict[str, Any] = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
    "deadline": _INFINITE,
    "lifespan": _INFINITE,
    "liveliness": "automatic",
    "liveliness_lease_duration": _INFINITE,
    "avoid_ros_namespace_conventions": False,
}


@dataclass(frozen=True)
class TopicCount:
    name: str
    type: str
    type_hash: str
    message_count: int


def bag_metadata(file_name: str, topics: list[TopicCount], start_ns: int, end_ns: int) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of a one-file MCAP bag (no compression: MCAP chunks do that)."""
    count = sum(t.message_count for t in topics)
    start, duration = (start_ns, end_ns - start_ns) if count else (0, 0)
    return {
        "version": VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t.name,
                    "type": t.type,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": [QOS_FIELDS],
                    "type_description_hash": t.type_hash,
                },
                "message_count": t.message_count,
            }
            for t in topics
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [
            {
                "path": file_name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": None,
        "ros_distro": DISTRO,
    }


def metadata_yaml(information: dict[str, Any]) -> str:
    """The ``metadata.yaml`` text."""
    return dump({"rosbag2_bagfile_information": information})


def dump(node: Any) -> str:
    """Block-style YAML of dicts, lists, ints, bools, None and strings."""
    return "\n".join(_lines(node, 0)) + "\n"


def _scalar(value: Any) -> str:
    if value is None:
        return "~"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        plain = _PLAIN.fullmatch(value) and value.lower() not in _RESERVED
        return value if plain else _quoted(value)
    raise TypeError(f"cannot write {type(value).__name__} to metadata.yaml")


def _quoted(text: str) -> str:
    """A YAML double-quoted scalar: printable ASCII as is, everything else escaped (``\\uXXXX``, ``\\UXXXXXXXX``)."""
    out = []
    for char in text:
        code = ord(char)
        if 0x20 <= code < 0x7F and char not in '"\\':
            out.append(char)
        else:
            out.append(f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")
    return '"' + "".join(out) + '"'


def _lines(node: Any, indent: int) -> list[str]:
    pad = " " * indent
    out: list[str] = []
    if isinstance(node, dict):
        for name, value in node.items():
            key = _scalar(str(name))
            if isinstance(value, dict | list) and value:
                out.append(f"{pad}{key}:")
                out += _lines(value, indent + 2)
            else:
                empty = "{}" if isinstance(value, dict) else "[]"
                out.append(f"{pad}{key}: {empty if isinstance(value, dict | list) else _scalar(value)}")
        return out
    for item in node:  # a list: "- " then the item's first line, the rest two deeper
        inner = _lines(item, indent + 2) if isinstance(item, dict | list) else [f"{pad}  {_scalar(item)}"]
        out.append(f"{pad}- {inner[0].lstrip()}")
        out += inner[1:]
    return out


# An MCAP channel's ``offered_qos_profiles``: the same list as YAML text (rosbag2's serialize_rclcpp_qos_vector,
# yaml-cpp's Dump: no trailing newline)
QOS_PROFILES = dump([QOS_FIELDS]).rstrip("\n")
