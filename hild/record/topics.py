"""The episode files' topics and their messages: cycle rows as the ROS 2 face's CDR, and back (docs/recording.md).

A row becomes ``/joint_states`` (the reading), ``/hild/command`` (the final command), ``/<controller>/commands`` (a
controller's joints' final command, the cycles it commands one) and ``/hild/cycle`` (everything else, a labelled
``Float64MultiArray``); an event becomes one JSON line on ``/hild/events``. The bytes are the face's: ``encode`` in
``hild.api.ros2.types`` (rosbags' serializer) is the reference. Serializing 3–4 messages a row that way costs
~12 µs each, so a message's bytes are a template — its constant part (names, labels, lengths) encoded once — with
the stamp and the numbers written into it for a whole batch with numpy; every template is checked against
``encode`` when it is made, so a template that differs from the face's bytes never writes a file.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from hild.api.ros2.types import decode, encode, message, type_hash, typestore
from hild.crossing.cyclelog import CycleRows
from hild.record.bag_metadata import QOS_PROFILES
from hild.record.model import RecordedEvent

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
STRING = "std_msgs/msg/String"

JOINT_STATES = "/joint_states"
COMMAND = "/hild/command"
CYCLE = "/hild/cycle"
EVENTS = "/hild/events"
TOPIC_TYPES = {JOINT_STATES: JOINT_STATE, COMMAND: JOINT_STATE, CYCLE: FLOAT64_ARRAY, EVENTS: STRING}

# /hild/cycle's labelled layout: one MultiArrayDimension per field, in this order (size 1, or one per joint);
# ``wall`` rides along so that a row's wall time comes back bit-exact (the stamps are whole nanoseconds)
SCALARS = ("tick", "t", "wall", "period", "duration")
PER_JOINT = ("kp", "kd", "mode", "owner", "fresh", "fault", "tau_ext")
INT_FIELDS = {"tick": np.int64, "mode": np.int8, "owner": np.int16, "fault": np.int16, "fresh": np.bool_}


def controller_topic(controller: str) -> str:
    """``/<controller>/commands``; a character a ROS name cannot hold becomes ``_``."""
    name = "".join(c if c.isascii() and (c.isalnum() or c == "_") else "_" for c in controller) or "_"
    return f"/{'_' + name if name[0].isdigit() else name}/commands"


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


class _Cdr:
    """Little-endian CDR of a message's constant part, noting where the variable parts go (offsets from the
    buffer's start; alignment counts from after the 4-byte encapsulation header, as the face's encoder does)."""

    def __init__(self) -> None:
        self.buf = bytearray(b"\x00\x01\x00\x00")

    def _align(self, size: int) -> None:
        self.buf += bytes(-(len(self.buf) - 4) % size)

    def u32(self, value: int) -> int:
        self._align(4)
        at = len(self.buf)
        self.buf += struct.pack("<I", value)
        return at

    def string(self, text: str) -> None:
        raw = text.encode()
        self.u32(len(raw) + 1)
        self.buf += raw + b"\x00"

    def float64s(self, count: int) -> int:
        self.u32(count)
        if count:
            self._align(8)
        at = len(self.buf)
        self.buf += bytes(8 * count)
        return at


@dataclass(frozen=True)
class _Template:
    """A message's bytes with holes: a stamp (sec, nanosec) at ``stamp`` (or none) and float64 runs."""

    data: bytes
    stamp: int | None
    runs: tuple[int, ...]  # offsets of the float64 runs
    counts: tuple[int, ...]

    def fill(self, stamps: np.ndarray | None, *values: np.ndarray) -> list[bytes]:
        """One message per row: ``stamps`` int64 ns (k,), each of ``values`` (k, count) float64."""
        k = len(values[0]) if values else len(stamps)  # type: ignore[arg-type]
        size = len(self.data)
        buf = np.empty((k, size), np.uint8)
        buf[:] = np.frombuffer(self.data, np.uint8)
        if self.stamp is not None and stamps is not None:
            sec, nanosec = np.divmod(stamps, 1_000_000_000)
            if len(sec) and sec.max() > 2**31 - 1:
                raise ValueError("a wall time past 2038 does not fit builtin_interfaces/Time")
            buf[:, self.stamp : self.stamp + 4].view("<i4")[:, 0] = sec
            buf[:, self.stamp + 4 : self.stamp + 8].view("<u4")[:, 0] = nanosec
        for at, count, block in zip(self.runs, self.counts, values, strict=True):
            if count:
                buf[:, at : at + 8 * count].view("<f8")[:] = block
        flat = buf.tobytes()
        return [flat[i * size : (i + 1) * size] for i in range(k)]


def _checked(template: _Template, probe: Any, type_name: str, stamp_ns: int | None, *values: np.ndarray) -> _Template:
    """``template`` if it writes exactly what the face's encoder writes for ``probe``; a bug otherwise."""
    stamps = None if stamp_ns is None else np.array([stamp_ns], np.int64)
    mine = template.fill(stamps, *(v[None, :] for v in values))[0]
    if mine != encode(probe, type_name):
        raise AssertionError(f"the {type_name} template differs from the ROS 2 face's CDR")
    return template


@cache
def joint_state_template(names: tuple[str, ...], frame_id: str = "") -> _Template:
    """``sensor_msgs/msg/JointState`` for ``names``: stamp, then position, velocity and effort."""
    cdr = _Cdr()
    stamp = cdr.u32(0)
    cdr.u32(0)
    cdr.string(frame_id)
    cdr.u32(len(names))
    for name in names:
        cdr.string(name)
    n = len(names)
    runs = (cdr.float64s(n), cdr.float64s(n), cdr.float64s(n))
    template = _Template(bytes(cdr.buf), stamp, runs, (n, n, n))
    probe = [np.arange(n, dtype=np.float64) * scale + 0.5 for scale in (1.0, -2.0, 3.0)]
    stamp_msg = message("builtin_interfaces/msg/Time", sec=7, nanosec=9)
    header = message("std_msgs/msg/Header", stamp=stamp_msg, frame_id=frame_id)
    msg = message(JOINT_STATE, header=header, name=list(names), position=probe[0], velocity=probe[1], effort=probe[2])
    return _checked(template, msg, JOINT_STATE, 7_000_000_009, *probe)


@cache
def cycle_template(joints: int) -> _Template:
    """``/hild/cycle``'s ``Float64MultiArray``: the labelled layout, then the data."""
    dims = [(label, 1) for label in SCALARS] + [(label, joints) for label in PER_JOINT]
    cdr = _Cdr()
    cdr.u32(len(dims))
    for label, size in dims:
        cdr.string(label)
        cdr.u32(size)
        cdr.u32(size)
    cdr.u32(0)  # data_offset
    width = len(SCALARS) + len(PER_JOINT) * joints
    data_at = cdr.float64s(width)
    template = _Template(bytes(cdr.buf), None, (data_at,), (width,))
    layout = message("std_msgs/msg/MultiArrayLayout", dim=_dimensions(joints), data_offset=0)
    probe = np.arange(width, dtype=np.float64) - 1.25
    return _checked(template, message(FLOAT64_ARRAY, layout=layout, data=probe), FLOAT64_ARRAY, None, probe)


def _dimensions(joints: int) -> list[Any]:
    sizes = [(label, 1) for label in SCALARS] + [(label, joints) for label in PER_JOINT]
    return [message("std_msgs/msg/MultiArrayDimension", label=lb, size=s, stride=s) for lb, s in sizes]


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
    states = joint_state_template(joints)
    controllers: dict[str, tuple[np.ndarray, list[bytes]]] = {}
    for code, name in controller_codes.items():
        mask = rows.owner == code
        if not mask.any():
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
        joint_states=states.fill(stamps, rows.measured_position, rows.measured_velocity, rows.measured_effort),
        command=states.fill(stamps, rows.position, rows.velocity, rows.effort),
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
    for line in decode(raw, STRING).data.splitlines():
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
    decoded = [decode(raw, JOINT_STATE) for raw in messages]
    names = tuple(decoded[0].name)
    if any(tuple(m.name) != names for m in decoded):
        raise ValueError("JointState messages name different joints")
    stamps = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in decoded], np.int64)
    fields = ("position", "velocity", "effort")
    values = {f: np.stack([getattr(m, f) for m in decoded]).astype(np.float64) for f in fields}
    return DecodedJointStates(names, stamps, **values)


def decode_cycles(messages: list[bytes], joints: int) -> dict[str, np.ndarray]:
    """/hild/cycle's fields by label, typed like ``CycleRows`` (a field found nowhere is a ValueError)."""
    decoded = [decode(raw, FLOAT64_ARRAY) for raw in messages]
    width = len(SCALARS) + len(PER_JOINT) * joints
    data = np.stack([m.data for m in decoded]) if decoded else np.zeros((0, width))
    layouts = [(tuple((d.label, d.size) for d in msg.layout.dim), msg.layout.data_offset) for msg in decoded]
    out: dict[str, np.ndarray] = {name: np.empty((len(decoded),)) for name in SCALARS}
    out |= {name: np.empty((len(decoded), joints)) for name in PER_JOINT}
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
        if name not in where or where[name].stop - where[name].start != expected:
            raise ValueError(f"/hild/cycle has no field {name!r} of {expected} values: layout {dims}")
    return where
