"""The vendor facts a host driver reads from a flavour object instead of asking for a vendor by name.

The expected frames are the ones the driver built for each vendor by name before the facts moved to the flavours.
"""

from __future__ import annotations

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.protocol import FrameError
from drivers.can.protocol.flavours import DAMIAO, FLAVOURS, MYACTUATOR, TMOTOR, MitReply
from drivers.can.protocol.mit import MitRanges, decode_state

AK80_9 = MitRanges(12.5, 50.0, 18.0)
MOTION = MitRanges(12.5, 45.0, 24.0)


def make(arbitration_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False, is_fd=True)


def test_what_each_flavour_says_about_itself() -> None:
    facts = {
        name: (f.motor_ids, f.reply_lengths, f.motor_key_mask, f.own_reply_ids, f.registers, f.polls_status)
        for name, f in FLAVOURS.items()
    }
    assert facts == {
        "damiao": (range(1, 0x7FF), (8,), 0x0F, True, True, False),
        "tmotor": (range(0, 0x100), (6, 8), 0xFF, False, False, False),
        "myactuator": (range(1, 33), (8,), 0xFF, False, False, True),
    }
    assert DAMIAO.reserved_ids == {0x7FF: "Damiao's register channel"}
    assert MYACTUATOR.native_ids(3) == (0x143, 0x243) and DAMIAO.native_ids(3) == TMOTOR.native_ids(3) == ()


def test_feedback_request_before_anything_is_enabled() -> None:
    # Damiao: the register channel's refresh, a classic frame whatever the bus
    refresh = DAMIAO.feedback_request(3, MitRanges(12.5, 30.0, 10.0), make)
    assert (refresh.arbitration_id, bytes(refresh.data).hex(), refresh.is_fd) == (0x7FF, "0300cc0000000000", False)
    # the others: a zero-gain MIT frame on the command id, built with the bus's own flags
    for flavour, ranges, command_id in ((TMOTOR, AK80_9, 0x7), (MYACTUATOR, MOTION, 0x407)):
        msg = flavour.feedback_request(7, ranges, make)
        assert (msg.arbitration_id, bytes(msg.data).hex(), msg.is_fd) == (command_id, "7fff7ff0000007ff", True)


def test_myactuator_status_poll() -> None:
    assert MYACTUATOR.status_request(4) == (0x144, bytes([0x9A, 0, 0, 0, 0, 0, 0, 0]))
    assert MYACTUATOR.status_reply_id(4) == 0x244
    # D1 temperature int8 (−3 °C), D6–D7 error flags little-endian (over-current | over-temperature)
    assert MYACTUATOR.decode_status(bytes([0x9A, 0xFD, 0, 1, 0xE0, 0x01, 0x10, 0x10])) == (-3.0, 0x1010)
    assert MYACTUATOR.decode_status(bytes([0x80, 0, 0, 0, 0, 0, 0, 0])) is None  # motor-off acknowledged
    with pytest.raises(FrameError, match="DLC 8, got 7"):
        MYACTUATOR.decode_status(bytes(7))
    for flavour in (DAMIAO, TMOTOR):
        with pytest.raises(NotImplementedError):
            flavour.status_request(4)


def test_fault_wording() -> None:
    assert DAMIAO.explain_fault(0xD) == "damiao fault 0xd: communication lost (CAN timeout)"
    assert TMOTOR.explain_fault(2) == "tmotor fault 0x2: over-current"
    assert MYACTUATOR.explain_fault(0x0010) == "myactuator error flags 0x0010: over-current"
    assert MYACTUATOR.explain_fault(0x1002 | 0x4000) == (
        "myactuator error flags 0x5002: stall, over-temperature, unknown flags 0x4000"
    )


# ---- the one decoder: its arithmetic against the readable reference of mit.py ----------------------------------

range_value = st.floats(1e-3, 1e4)
ranges = st.builds(MitRanges, p_max=range_value, v_max=range_value, t_max=range_value)


@given(
    name=st.sampled_from(sorted(FLAVOURS)),
    r=ranges,
    motor=st.integers(1, 32),
    status=st.sampled_from([0x0, 0x1, *DAMIAO.fault_names]),
    body=st.binary(min_size=7, max_size=7),
    short=st.booleans(),
)
@settings(max_examples=400)
def test_reply_decoder_computes_decode_state(
    name: str, r: MitRanges, motor: int, status: int, body: bytes, short: bool
) -> None:
    flavour = FLAVOURS[name]
    d0 = status << 4 | motor & 0xF if flavour is DAMIAO else motor
    data = bytes([d0]) + body
    if short and 6 in flavour.reply_lengths:
        data = data[:6]
    fields = flavour.reply_decoder(r, motor)(data)
    assert fields[:3] == decode_state(data[1:6], r)  # ==: the same floats, bit for bit
    tail = data[6:]
    if flavour is DAMIAO:
        assert fields[3:] == ((status == 1), status if status > 1 else 0, float(tail[0]), float(tail[1]))
    elif flavour is TMOTOR:
        assert fields[3:] == ((None, tail[1], float(tail[0]), None) if tail else (None, 0, None, None))
    else:
        assert fields[3:] == (None, 0, None, None)


def test_decode_reply_is_the_checks_plus_the_decoder() -> None:
    msg = TMOTOR.encode_reply(2, 0, 1.5, -3.0, 2.0, AK80_9, enabled=True, fault=4, t_mos=33.0, t_rotor=None)
    assert TMOTOR.decode_reply(msg, AK80_9, 2) == MitReply(2, *TMOTOR.reply_decoder(AK80_9, 2)(msg.data))
    with pytest.raises(FrameError, match="tmotor: reply names motor 2, expected 3"):
        TMOTOR.reply_decoder(AK80_9, 3)(msg.data)
