"""The MIT mini-cheetah frame family: bit packing and the firmware's truncating quantisation.

Damiao, T-Motor/CubeMars AK (MIT mode), MyActuator motion mode and Ben Katz's firmware all send the same 8-byte
command (p16|v12|kp12|kd12|t12, big-endian) and the same 5-byte state block (p16|v12|t12) inside their replies.
The conversion truncates like the firmware's C code, so 0 rad is not representable: decoded values, never raw
floats, are what both ends agree on.

`float_to_uint`/`encode_command`/`decode_state` are the reference: readable, used by the emulators and tests.
`command_encoder` and `state_scales` are the same arithmetic with the ranges resolved once per drive, for the host's
cycle (a 6-motor arm at 1 kHz encodes 6000 commands a second); tests check they agree bit for bit.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from drivers.can.protocol.errors import FrameError

POSITION_BITS = 16
VELOCITY_BITS = 12
GAIN_BITS = 12
TORQUE_BITS = 12
POSITION_STEPS = float((1 << POSITION_BITS) - 1)
"""2^bits − 1 as a float: `x * 65535` and `x * 65535.0` are the same IEEE operation, minus the int conversion."""
FIELD_STEPS = float((1 << VELOCITY_BITS) - 1)
"""The same for the 12-bit fields (velocity, gains and torque share the width)."""


@dataclass(frozen=True, slots=True)
class MitRanges:
    """Symmetric mapping ranges of one drive: ±p_max rad, ±v_max rad/s, ±t_max Nm; gains 0..kp_max, 0..kd_max."""

    p_max: float
    v_max: float
    t_max: float
    kp_max: float = 500.0
    kd_max: float = 5.0

    def __post_init__(self) -> None:
        for name in ("p_max", "v_max", "t_max", "kp_max", "kd_max"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MitRanges.{name} must be a finite positive number, got {value!r}")


class MitCommand(NamedTuple):
    """A decoded command: the drive computes τ = kp·(p − q) + kd·(v − q̇) + t."""

    p: float
    v: float
    kp: float
    kd: float
    t: float


def float_to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """The firmware's conversion: clamp to [lo, hi], scale to 0..2^bits−1 and truncate toward zero.

    Truncation (not rounding) is what the drives do, which is why a value is generally not reproduced exactly.
    A non-finite value is a programming error upstream and raises ValueError instead of producing a frame.
    """
    if not math.isfinite(x):
        if math.isnan(x):
            raise ValueError("cannot encode NaN")
        x = hi if x > 0 else lo
    x = lo if x < lo else hi if x > hi else x
    return int((x - lo) * ((1 << bits) - 1) / (hi - lo))


def uint_to_float(u: int, lo: float, hi: float, bits: int) -> float:
    """Inverse mapping of `float_to_uint`: u·(hi − lo)/(2^bits − 1) + lo."""
    return u * (hi - lo) / ((1 << bits) - 1) + lo


def quantize(x: float, lo: float, hi: float, bits: int) -> float:
    """The value the other end decodes after `x` travelled through the wire."""
    return uint_to_float(float_to_uint(x, lo, hi, bits), lo, hi, bits)


def encode_command(p: float, v: float, kp: float, kd: float, t: float, r: MitRanges) -> bytes:
    """The 8-byte MIT command: p16 | v12 | kp12 | kd12 | t12, most significant bit first."""
    packed = (
        float_to_uint(p, -r.p_max, r.p_max, POSITION_BITS) << 48
        | float_to_uint(v, -r.v_max, r.v_max, VELOCITY_BITS) << 36
        | float_to_uint(kp, 0.0, r.kp_max, GAIN_BITS) << 24
        | float_to_uint(kd, 0.0, r.kd_max, GAIN_BITS) << 12
        | float_to_uint(t, -r.t_max, r.t_max, TORQUE_BITS)
    )
    return packed.to_bytes(8, "big")


def decode_command(data: bytes | bytearray, r: MitRanges) -> MitCommand:
    """What the drive reads from an 8-byte MIT command."""
    if len(data) != 8:
        raise FrameError(f"MIT command needs 8 data bytes, got {len(data)}")
    packed = int.from_bytes(data, "big")
    return MitCommand(
        uint_to_float(packed >> 48, -r.p_max, r.p_max, POSITION_BITS),
        uint_to_float((packed >> 36) & 0xFFF, -r.v_max, r.v_max, VELOCITY_BITS),
        uint_to_float((packed >> 24) & 0xFFF, 0.0, r.kp_max, GAIN_BITS),
        uint_to_float((packed >> 12) & 0xFFF, 0.0, r.kd_max, GAIN_BITS),
        uint_to_float(packed & 0xFFF, -r.t_max, r.t_max, TORQUE_BITS),
    )


def encode_state(p: float, v: float, t: float, r: MitRanges) -> bytes:
    """The 5-byte state block of every MIT reply: p16 | v12 | t12."""
    packed = (
        float_to_uint(p, -r.p_max, r.p_max, POSITION_BITS) << 24
        | float_to_uint(v, -r.v_max, r.v_max, VELOCITY_BITS) << 12
        | float_to_uint(t, -r.t_max, r.t_max, TORQUE_BITS)
    )
    return packed.to_bytes(5, "big")


def decode_state(data5: bytes | bytearray, r: MitRanges) -> tuple[float, float, float]:
    """(position rad, velocity rad/s, torque Nm) from the 5-byte state block."""
    if len(data5) != 5:
        raise FrameError(f"MIT state block needs 5 bytes, got {len(data5)}")
    packed = int.from_bytes(data5, "big")
    return (
        uint_to_float(packed >> 24, -r.p_max, r.p_max, POSITION_BITS),
        uint_to_float((packed >> 12) & 0xFFF, -r.v_max, r.v_max, VELOCITY_BITS),
        uint_to_float(packed & 0xFFF, -r.t_max, r.t_max, TORQUE_BITS),
    )


CommandEncoder = Callable[[bytearray, float, float, float, float, float], None]
"""(buffer, p, v, kp, kd, t) → writes the 8-byte MIT command into buffer[0:8]."""

_PACK_COMMAND = struct.Struct(">Q").pack_into


def command_encoder(r: MitRanges) -> CommandEncoder:
    """`encode_command` for one drive, writing into a preallocated buffer: the host's per-cycle encoder.

    The bytes are those of `encode_command` for every input: the same clamps (±inf to the range ends), the same
    float operations in the same order (so the same truncation) and ValueError for NaN. Only the ranges are looked
    up once, here, instead of per field and frame.
    """
    p_lo, p_hi = -r.p_max, r.p_max
    v_lo, v_hi = -r.v_max, r.v_max
    t_lo, t_hi = -r.t_max, r.t_max
    p_span, v_span, t_span = p_hi - p_lo, v_hi - v_lo, t_hi - t_lo
    kp_hi, kd_hi = r.kp_max, r.kd_max  # gains map 0..max: x − 0.0 is x (−0.0 included), so it is left out
    p_steps, steps, pack = POSITION_STEPS, FIELD_STEPS, _PACK_COMMAND

    def encode(buffer: bytearray, p: float, v: float, kp: float, kd: float, t: float) -> None:
        # `not lo <= x <= hi` is the rare path: out of range, ±inf, or NaN (every comparison with NaN is false).
        if not p_lo <= p <= p_hi:
            p = _clamped(p, p_lo, p_hi)
        if not v_lo <= v <= v_hi:
            v = _clamped(v, v_lo, v_hi)
        if not 0.0 <= kp <= kp_hi:
            kp = _clamped(kp, 0.0, kp_hi)
        if not 0.0 <= kd <= kd_hi:
            kd = _clamped(kd, 0.0, kd_hi)
        if not t_lo <= t <= t_hi:
            t = _clamped(t, t_lo, t_hi)
        pack(
            buffer,
            0,
            int((p - p_lo) * p_steps / p_span) << 48
            | int((v - v_lo) * steps / v_span) << 36
            | int(kp * steps / kp_hi) << 24
            | int(kd * steps / kd_hi) << 12
            | int((t - t_lo) * steps / t_span),
        )

    return encode


def _clamped(x: float, lo: float, hi: float) -> float:
    if x != x:  # NaN
        raise ValueError("cannot encode NaN")
    return lo if x < lo else hi


def state_scales(r: MitRanges) -> tuple[float, float, float, float, float, float]:
    """(p_lo, p_span, v_lo, v_span, t_lo, t_span) for specialised state decoders.

    A field decodes as ``u * span / steps + lo`` with `POSITION_STEPS` or `FIELD_STEPS`: the operations of
    `uint_to_float` in its order, so the value is bit-identical to `decode_state`'s.
    """
    return -r.p_max, r.p_max - -r.p_max, -r.v_max, r.v_max - -r.v_max, -r.t_max, r.t_max - -r.t_max


_SPECIAL_PREFIX = b"\xff" * 7
ENABLE = _SPECIAL_PREFIX + b"\xfc"
DISABLE = _SPECIAL_PREFIX + b"\xfd"
SET_ZERO = _SPECIAL_PREFIX + b"\xfe"
CLEAR_ERROR = _SPECIAL_PREFIX + b"\xfb"
SPECIAL_FRAMES: dict[str, bytes] = {"enable": ENABLE, "disable": DISABLE, "zero": SET_ZERO, "clear": CLEAR_ERROR}


def special_kind(data: bytes | bytearray) -> str | None:
    """Which special frame `data` is ("enable", "disable", "zero", "clear"), or None for an ordinary command."""
    if len(data) != 8 or data[:7] != _SPECIAL_PREFIX:
        return None
    return _SPECIAL_BY_LAST_BYTE.get(data[7])


_SPECIAL_BY_LAST_BYTE = {frame[7]: kind for kind, frame in SPECIAL_FRAMES.items()}
