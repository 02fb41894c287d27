"""ODrive's message table: every row encodes, packs and decodes consistently, whatever its layout.

The byte layouts themselves are pinned by the literal vectors in test_codec_vectors.py and the hand-worked frames in
test_protocol_odrive.py; here every message of the table is driven through its derived functions.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.can.protocol import FrameError
from drivers.can.protocol import odrive as od

TABLE = [m for m in vars(od).values() if isinstance(m, od.Message)]


def field_values(message: od.Message) -> st.SearchStrategy[tuple[Any, ...]]:
    """Values that survive the wire exactly: float32 numbers, in-range integers, multiples of a fixed-point scale."""
    codes = [c for c in message.layout.format if c not in "<x"]
    strategies = []
    for name, code in zip(message.fields, codes, strict=True):
        conversion = message.wire.get(name)
        if isinstance(conversion, od.FixedPoint):
            scale = conversion.scale
            strategies.append(st.integers(conversion.lo, conversion.hi).map(lambda n, scale=scale: n * scale))
        elif isinstance(conversion, od.LowBit) or code == "?":
            strategies.append(st.booleans())
        elif code == "f":
            strategies.append(st.floats(width=32, allow_nan=False))
        else:
            bits = {"B": 8, "I": 32}[code]
            strategies.append(st.integers(0, (1 << bits) - 1))
    return st.tuples(*strategies)


def test_the_table_covers_every_message_once() -> None:
    assert len({m.cmd for m in TABLE}) == len({m.name for m in TABLE}) == len(TABLE) == 15
    assert all(m.size <= 8 and len(m.fields) == len(m.layout.unpack(bytes(m.size))) for m in TABLE)


@pytest.mark.parametrize("message", TABLE, ids=lambda m: m.name)
@given(data=st.data(), node=st.integers(0, od.MAX_NODE))
def test_every_message_round_trips(message: od.Message, data: st.DataObject, node: int) -> None:
    values = data.draw(field_values(message))
    frame = message.encode(node, *values)
    assert (frame.arbitration_id, frame.dlc, frame.is_extended_id, frame.is_remote_frame) == (
        node << 5 | message.cmd,
        message.size,
        False,
        False,
    )
    decoded = message.decode(frame.data)
    if len(values) == 1:
        decoded = (decoded,)  # a one-field message decodes to the bare value
    assert tuple(decoded) == values
    buffer = bytearray(b"\xaa" * message.size)  # the cycle refills stale bytes in place
    message.pack(buffer, *values)
    assert bytes(buffer) == bytes(frame.data)


@pytest.mark.parametrize("message", TABLE, ids=lambda m: m.name)
def test_every_message_refuses_a_wrong_length(message: od.Message) -> None:
    with pytest.raises(FrameError, match=f"odrive {message.name} "):
        message.decode(bytes(message.size + 1))


def test_defaults_fill_trailing_fields_and_empty_payloads() -> None:
    assert od.SET_INPUT_POS.encode(1, 2.0).data == od.SET_INPUT_POS.encode(1, 2.0, 0.0, 0.0).data
    assert od.SET_INPUT_VEL.encode(1, 2.0).data == od.SET_INPUT_VEL.encode(1, 2.0, 0.0).data
    assert (od.CLEAR_ERRORS.decode(b""), od.REBOOT.decode(b"")) == (False, od.RebootAction.REBOOT)
    with pytest.raises(FrameError, match="needs 8 data bytes, got 0"):
        od.HEARTBEAT.decode(b"")
    with pytest.raises(TypeError, match="Set_Input_Pos takes 3 values"):
        od.SET_INPUT_POS.encode(1)


def test_fixed_point_rounds_and_saturates() -> None:
    ff = od.FEED_FORWARD
    assert [ff.to_wire(x) for x in (0.0004, 0.0005, 0.0015, -0.0006, 40.0, -40.0)] == [0, 0, 2, -1, 32767, -32768]
    with pytest.raises(ValueError):
        ff.to_wire(float("nan"))


def outcome(pack: Callable[[], bytes]) -> bytes | type[BaseException]:
    try:
        return pack()
    except (ValueError, OverflowError, struct.error) as exc:
        return type(exc)


near_ff = st.floats() | st.floats(-40.0, 40.0)  # NaN, ±inf and beyond float32, or around the ±32.767 saturation


@given(position=st.floats(), vel_ff=near_ff, torque_ff=near_ff)
def test_the_cycles_inline_fixed_point_is_fixed_point_to_wire(position: float, vel_ff: float, torque_ff: float) -> None:
    """Set_Input_Pos converts its feed-forwards inline (no call per field): the bytes and errors of `to_wire`."""
    message, ff = od.SET_INPUT_POS, od.FEED_FORWARD
    buffer = bytearray(message.size)

    def inline() -> bytes:
        message.pack(buffer, position, vel_ff, torque_ff)
        return bytes(buffer)

    def general() -> bytes:
        return message.layout.pack(position, ff.to_wire(vel_ff), ff.to_wire(torque_ff))

    assert outcome(inline) == outcome(general)
