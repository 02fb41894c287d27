"""The episode files' topics and their messages: cycle rows as the ROS 2 face's CDR, and back (docs/recording.md).

A row becomes ``/joint_states`` (the reading), ``/hild/command`` (the final command),
``/<controller>/joint_commands`` (a controller's joints' final command, the cycles it commands one) and
``/hild/cycle`` (everything else, a labelled ``Float64MultiArray``); an event becomes one JSON line on
``/hild/events``. The bytes are the face's (``hild.api.ros2.types.encode``), written and read a batch at a time
through ``cdr_templates``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from hild.api.ros2.types import decode, encode, message, type_hash, typestore
from hild.crossing.cyclelog import OWNER_NONE, CycleRows
from hild.record.bag_metadata import QOS_PROFILES
from hild.record.cdr_templates import (
    FLOAT64_ARRAY,
    JOINT_STATE,
    PER_JOINT,
    SCALARS,
    cycle_layout,
    cycle_template,
    joint_state_template,
)
from hild.record.model import RecordedEvent

STRING = "std_msgs/msg/String"

JOINT_STATES = "/joint_states"
COMMAND = "/hild/command"
CYCLE = "/hild/cycle"
EVENTS = "/hild/events"
TOPIC_TYPES = {JOINT_STATES: JOINT_STATE, COMMAND: JOINT_STATE, CYCLE: FLOAT64_ARRAY, EVENTS: STRING}

# /joint_states' frame, the face's (hild.api.ros2.face.JOINT_STATES_FRAME: joint_state_broadcaster's default), so a
# recorded reading is the bytes the face publishes; commands have none
JOINT_STATES_FRAME = "base_link"
INT_FIELDS = {
    "tick": np.int64,
    "mode": np.int8,
    "owner": np.int16,
    "fault": np.int16,
    "fresh": np.bool_,
    "source": np.int8,
}
# /hild/cycle fields an older hild did not write, and what a reader takes for them: -1, "not recorded" (files from
# before provenance carry no source)
OPTIONAL_FIELDS = {"source": -1.0}


def controller_topic(controller: str) -> str:
    """``/<controller>/joint_commands`` (not ``commands``: forward_command
    controllers subscribe to ``/<name>/commands`` as ``Float64MultiArray`` on the ROS 2 face, and a ``ros2 bag play``
    must not publish another type there); a character a ROS name cannot hold becomes ``_``."""
    name = "".join(c if c.isascii() and (c.isalnum() or c == "_") else "_" for c in controller) or "_"
    return f"/{'_' + name if name[0].isdigit() else name}/joint_commands"


@cache
def schema_text(type_name: str) -> bytes:
    """The full ``ros2msg`` definition (dependencies after ``===`` lines), the text rosbag2 stores."""
    text, _ = typestore().generate_msgdef(type_name, ros_version=2)
    return text.encode()


@cache
def channel_metadata(type_name: str) -> dict[str, str]:
    """A channel's metadata as rosbag2 Jazzy's MCAP storage writes it."""
    return {"offered_qos_profiles": QOS_PROFILES, "topic_type_hash": type_hash(type_name)}


def stamps_ns(wall: np.ndarray) -> np.ndarray:
    """Wall times (float s since the epoch) as int64 ns, each the nearest: split into whole seconds and the
    fraction (both exact), so no rounding of ``wall * 1e9`` (which is ±128 ns at today's epoch) creeps in."""
    if len(wall) and not (np.all(np.isfinite(wall)) and wall.min() >= 0):
        raise ValueError("wall times must be finite and not before the epoch")
    seconds = np.floor(wall)
    return seconds.astype(np.int64) * 1_000_000_000 + np.rint((wall - seconds) * 1e9).astype(np.int64)


def wall_ns(wall: float) -> int:
    return int(stamps_ns(np.array([wall]))[0])


def cycle_values(rows: CycleRows) -> np.ndarray:
    """(k, 5 + 7n) float64: /hild/cycle's data for each row (every int and bool is exact in a float64)."""
    columns = [getattr(rows, name).astype(np.float64)[:, None] for name in SCALARS]
    columns += [getattr(rows, name).astype(np.float64) for name in PER_JOINT]
    return np.concatenate(columns, axis=1)


@dataclass(frozen=True)
class EncodedRows:
    """A batch of rows as message bytes, row-aligned: ``controllers`` maps a topic to (row indices, bytes)."""

    log_times: np.ndarray  # int64 ns
    joint_states: list[bytes]
    command: list[bytes]
    cycle: list[bytes]
    controllers: dict[str, tuple[np.ndarray, list[bytes]]]


def encode_rows(rows: CycleRows, joints: tuple[str, ...], controller_codes: dict[int, str]) -> EncodedRows:
    """Every topic's messages for ``rows`` (a code not in ``controller_codes`` has no topic of its own: its rows
    still carry it in /hild/cycle's ``owner``)."""
    if rows.position.shape[1:] != (len(joints),):
        raise ValueError(f"rows have {rows.position.shape[1:]} joints, the episode {len(joints)}")
    stamps = stamps_ns(rows.wall)
    commands = joint_state_template(joints)
    controllers: dict[str, tuple[np.ndarray, list[bytes]]] = {}
    for code, name in controller_codes.items():
        mask = rows.owner == code
        if code == OWNER_NONE or not mask.any():
            continue
        which = np.flatnonzero(mask.any(axis=1))
        out: list[bytes] = [b""] * len(which)
        patterns, inverse = np.unique(mask[which], axis=0, return_inverse=True)
        for p, pattern in enumerate(patterns):
            pick = np.flatnonzero(inverse.reshape(-1) == p)
            at, cols = which[pick], np.flatnonzero(pattern)
            filled = joint_state_template(tuple(joints[c] for c in cols)).fill(
                stamps[at], *(getattr(rows, f)[np.ix_(at, cols)] for f in ("position", "velocity", "effort"))
            )
            for i, data in zip(pick, filled, strict=True):
                out[i] = data
        controllers[controller_topic(name)] = (which, out)
    return EncodedRows(
        log_times=stamps,
        joint_states=joint_state_template(joints, JOINT_STATES_FRAME).fill(
            stamps, rows.measured_position, rows.measured_velocity, rows.measured_effort
        ),
        command=commands.fill(stamps, rows.position, rows.velocity, rows.effort),
        cycle=cycle_template(len(joints)).fill(None, cycle_values(rows)),
        controllers=controllers,
    )


def encode_event(event: RecordedEvent) -> bytes:
    """``/hild/events``: the event as one JSON line (an unknown cycle time, NaN, as ``null``)."""
    t = None if math.isnan(event.t) else event.t
    line = json.dumps({"wall": event.wall, "t": t, "kind": event.kind, "data": event.data}, separators=(",", ":"))
    return encode(message(STRING, data=line), STRING)


def decode_events(raw: bytes) -> list[RecordedEvent]:
    out = []
    for line in decode(raw, STRING).data.split("\n"):
        if line.strip():
            item = json.loads(line)
            t = math.nan if item.get("t") is None else float(item["t"])
            out.append(RecordedEvent(float(item["wall"]), t, str(item["kind"]), item.get("data") or {}))
    return out


@dataclass(frozen=True)
class DecodedJointStates:
    names: tuple[str, ...]
    stamps: np.ndarray  # int64 ns (k,)
    position: np.ndarray  # (k, n)
    velocity: np.ndarray
    effort: np.ndarray


def decode_joint_states(messages: list[bytes]) -> DecodedJointStates | None:
    """JointStates of one joint list (None for none); a message naming other joints is a ValueError."""
    if not messages:
        return None
    first = decode(messages[0], JOINT_STATE)
    names = tuple(first.name)
    parsed = joint_state_template(names, first.header.frame_id).parse(messages)
    if parsed is not None:  # every message hild's template for these joints: the same numbers decode would give
        stamps, (position, velocity, effort) = parsed
        assert stamps is not None
        return DecodedJointStates(names, stamps, position, velocity, effort)
    decoded = [decode(raw, JOINT_STATE) for raw in messages]
    if any(tuple(m.name) != names for m in decoded):
        raise ValueError("JointState messages name different joints")
    stamps = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in decoded], np.int64)
    fields = ("position", "velocity", "effort")
    values = {f: np.stack([getattr(m, f) for m in decoded]).astype(np.float64) for f in fields}
    return DecodedJointStates(names, stamps, **values)


def decode_cycles(messages: list[bytes], joints: int) -> dict[str, np.ndarray]:
    """/hild/cycle's fields by label, typed like ``CycleRows`` (a field found nowhere is a ValueError)."""
    parsed = cycle_template(joints).parse(messages)
    if parsed is not None:  # hild's layout, in its order
        data = parsed[1][0]
        where = _segments(cycle_layout(joints), 0, joints)
        out = {name: data[:, at] if name in PER_JOINT else data[:, at.start] for name, at in where.items()}
        return {name: values.astype(INT_FIELDS.get(name, np.float64)) for name, values in out.items()}
    decoded = [decode(raw, FLOAT64_ARRAY) for raw in messages]
    width = len(SCALARS) + len(PER_JOINT) * joints
    data = np.stack([m.data for m in decoded]) if decoded else np.zeros((0, width))
    layouts = [(tuple((d.label, d.size) for d in msg.layout.dim), msg.layout.data_offset) for msg in decoded]
    out = {name: np.empty((len(decoded),)) for name in SCALARS}
    out |= {name: np.full((len(decoded), joints), OPTIONAL_FIELDS.get(name, np.nan)) for name in PER_JOINT}
    for layout in set(layouts):  # one, in any file hild wrote
        rows = np.array([other == layout for other in layouts])
        for name, at in _segments(*layout, joints).items():
            out[name][rows] = data[rows, at] if name in PER_JOINT else data[rows, at.start]
    return {name: values.astype(INT_FIELDS.get(name, np.float64)) for name, values in out.items()}


def _segments(dims: tuple[tuple[str, int], ...], offset: int, joints: int) -> dict[str, slice]:
    where, at = {}, offset
    for label, size in dims:
        where[label] = slice(at, at + size)
        at += size
    for name in (*SCALARS, *PER_JOINT):
        expected = joints if name in PER_JOINT else 1
        if name not in where and name in OPTIONAL_FIELDS:
            continue
        if name not in where or where[name].stop - where[name].start != expected:
            raise ValueError(f"/hild/cycle has no field {name!r} of {expected} values: layout {dims}")
    return where
