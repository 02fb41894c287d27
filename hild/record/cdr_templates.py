"""A message's CDR as a template: its constant part encoded once, the stamp and the numbers written in (and read
out) for a whole batch with numpy (docs/recording.md, "Files").

``encode`` in ``hild.api.ros2.types`` (rosbags' serializer) is the reference and costs ~12 µs a message; a 1 kHz
cycle makes 3–4 messages a row. A template is checked against ``encode`` when it is made, so one that differs from
the face's bytes never writes a file; reading, a template takes only messages whose every constant byte is its own
(anything else is decoded one by one).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import cache, cached_property
from typing import Any

import numpy as np

from hild.api.ros2.types import encode, message

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
# /hild/cycle's labelled layout: one MultiArrayDimension per field, in this order (size 1, or one per joint);
# ``wall`` rides along so that a row's wall time comes back bit-exact (the stamps are whole nanoseconds)
SCALARS = ("tick", "t", "wall", "period", "duration")
PER_JOINT = ("kp", "kd", "mode", "owner", "fresh", "fault", "tau_ext", "source")


class Cdr:
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
class Template:
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

    @cached_property
    def _constant(self) -> np.ndarray:
        """True where every message of this template has the template's byte (not a stamp, not a number)."""
        constant = np.ones(len(self.data), bool)
        if self.stamp is not None:
            constant[self.stamp : self.stamp + 8] = False
        for at, count in zip(self.runs, self.counts, strict=True):
            constant[at : at + 8 * count] = False
        return constant

    def parse(self, messages: list[bytes]) -> tuple[np.ndarray | None, list[np.ndarray]] | None:
        """The stamps (int64 ns, or None) and float64 runs of messages this template wrote — None unless every
        message has exactly its length and constant bytes (then ``decode`` reads them one by one)."""
        size = len(self.data)
        if not messages or any(len(raw) != size for raw in messages):
            return None
        buf = np.frombuffer(b"".join(messages), np.uint8).reshape(len(messages), size)
        template = np.frombuffer(self.data, np.uint8)
        if not (buf[:, self._constant] == template[self._constant]).all():
            return None
        stamps = None
        if self.stamp is not None:
            sec = buf[:, self.stamp : self.stamp + 4].copy().view("<i4")[:, 0].astype(np.int64)
            nanosec = buf[:, self.stamp + 4 : self.stamp + 8].copy().view("<u4")[:, 0].astype(np.int64)
            stamps = sec * 1_000_000_000 + nanosec
        runs = [buf[:, at : at + 8 * n].copy().view("<f8") for at, n in zip(self.runs, self.counts, strict=True)]
        return stamps, runs


def _checked(template: Template, probe: Any, type_name: str, stamp_ns: int | None, *values: np.ndarray) -> Template:
    """``template`` if it writes exactly what the face's encoder writes for ``probe``; a bug otherwise."""
    stamps = None if stamp_ns is None else np.array([stamp_ns], np.int64)
    mine = template.fill(stamps, *(v[None, :] for v in values))[0]
    if mine != encode(probe, type_name):
        raise AssertionError(f"the {type_name} template differs from the ROS 2 face's CDR")
    return template


@cache
def joint_state_template(names: tuple[str, ...], frame_id: str = "") -> Template:
    """``sensor_msgs/msg/JointState`` for ``names``: stamp, then position, velocity and effort."""
    cdr = Cdr()
    stamp = cdr.u32(0)
    cdr.u32(0)
    cdr.string(frame_id)
    cdr.u32(len(names))
    for name in names:
        cdr.string(name)
    n = len(names)
    runs = (cdr.float64s(n), cdr.float64s(n), cdr.float64s(n))
    template = Template(bytes(cdr.buf), stamp, runs, (n, n, n))
    probe = [np.arange(n, dtype=np.float64) * scale + 0.5 for scale in (1.0, -2.0, 3.0)]
    stamp_msg = message("builtin_interfaces/msg/Time", sec=7, nanosec=9)
    header = message("std_msgs/msg/Header", stamp=stamp_msg, frame_id=frame_id)
    msg = message(JOINT_STATE, header=header, name=list(names), position=probe[0], velocity=probe[1], effort=probe[2])
    return _checked(template, msg, JOINT_STATE, 7_000_000_009, *probe)


def cycle_layout(joints: int) -> tuple[tuple[str, int], ...]:
    """/hild/cycle's dimensions: (label, size) in order; each dimension's stride is its size, data_offset 0."""
    return tuple((label, 1) for label in SCALARS) + tuple((label, joints) for label in PER_JOINT)


@cache
def cycle_template(joints: int) -> Template:
    """``/hild/cycle``'s ``Float64MultiArray``: the labelled layout, then the data."""
    dims = cycle_layout(joints)
    cdr = Cdr()
    cdr.u32(len(dims))
    for label, size in dims:
        cdr.string(label)
        cdr.u32(size)
        cdr.u32(size)
    cdr.u32(0)  # data_offset
    width = len(SCALARS) + len(PER_JOINT) * joints
    data_at = cdr.float64s(width)
    template = Template(bytes(cdr.buf), None, (data_at,), (width,))
    dimensions = [message("std_msgs/msg/MultiArrayDimension", label=lb, size=n, stride=n) for lb, n in dims]
    layout = message("std_msgs/msg/MultiArrayLayout", dim=dimensions, data_offset=0)
    probe = np.arange(width, dtype=np.float64) - 1.25
    return _checked(template, message(FLOAT64_ARRAY, layout=layout, data=probe), FLOAT64_ARRAY, None, probe)
