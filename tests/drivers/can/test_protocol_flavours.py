"""Per-flavour framing: ids, special frames and replies against frames worked out by hand."""

from __future__ import annotations

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.protocol import FrameError
from drivers.can.protocol.flavours import DAMIAO, FLAVOURS, MYACTUATOR, TMOTOR, MitReply
from drivers.can.protocol.mit import MitRanges
from drivers.can.protocol.models import MODELS, ranges_for

DM4310 = MitRanges(12.5, 30.0, 10.0)
AK80_9 = MitRanges(12.5, 50.0, 18.0)
MOTION = MitRanges(12.5, 45.0, 24.0)


def frame(arb: int, data: bytes, **kw: bool) -> can.Message:
    return can.Message(arbitration_id=arb, data=data, is_extended_id=False, **kw)


def test_registry() -> None:
    assert FLAVOURS == {"damiao": DAMIAO, "tmotor": TMOTOR, "myactuator": MYACTUATOR}
    assert DAMIAO.reports_enabled and not TMOTOR.reports_enabled and not MYACTUATOR.reports_enabled


def test_ids() -> None:
    assert (DAMIAO.command_id(3), DAMIAO.reply_id(3, 0x13)) == (3, 0x13)
    assert (TMOTOR.command_id(2), TMOTOR.reply_id(2, 0)) == (2, 0)
    assert (MYACTUATOR.command_id(1), MYACTUATOR.reply_id(1, 0)) == (0x401, 0x501)


def test_command_frame_is_a_standard_frame_on_the_command_id() -> None:
    msg = MYACTUATOR.command(1, 1.0, -2.0, 50.0, 1.0, 0.5, DM4310)
    assert (msg.arbitration_id, msg.is_extended_id, msg.dlc) == (0x401, False, 8)
    assert bytes(msg.data) == bytes([0x8A, 0x3C, 0x77, 0x71, 0x99, 0x33, 0x38, 0x65])  # see test_protocol_mit


def test_special_frames_per_flavour() -> None:
    for kind, last in (("enable", 0xFC), ("disable", 0xFD), ("zero", 0xFE), ("clear", 0xFB)):
        msg = DAMIAO.special(5, kind)
        assert msg is not None and msg.arbitration_id == 5 and bytes(msg.data) == b"\xff" * 7 + bytes([last])
    assert TMOTOR.special(2, "clear") is None
    enable = TMOTOR.special(2, "enable")
    assert enable is not None and bytes(enable.data)[-1] == 0xFC
    # MyActuator: motion commands run the motor; "disable" is the native motor-off 0x80 on 0x140 + id
    assert MYACTUATOR.special(1, "enable") is None
    off = MYACTUATOR.special(1, "disable")
    assert off is not None and off.arbitration_id == 0x141 and bytes(off.data) == bytes([0x80, 0, 0, 0, 0, 0, 0, 0])
    assert MYACTUATOR.is_ack(frame(0x241, bytes([0x80] + [0] * 7)), 1)
    assert not MYACTUATOR.is_ack(frame(0x242, bytes(8)), 1)
    with pytest.raises(ValueError, match="unknown special"):
        DAMIAO.special(1, "reboot")  # type: ignore[arg-type]


def test_damiao_reply_by_hand() -> None:
    # esc_id 1, MST_ID 0x11, enabled (status 1): D0 = 1 << 4 | 1 = 0x11
    # p = v = t = 0 -> 0x7FFF, 0x7FF, 0x7FF -> 7F FF 7F F7 FF; T_MOS 30 = 0x1E, T_rotor 28 = 0x1C
    msg = DAMIAO.encode_reply(1, 0x11, 0.0, 0.0, 0.0, DM4310, enabled=True, fault=0, t_mos=30.0, t_rotor=28.0)
    assert msg.arbitration_id == 0x11
    assert bytes(msg.data) == bytes([0x11, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF, 0x1E, 0x1C])
    reply = DAMIAO.decode_reply(msg, DM4310, 1, master_id=0x11)
    assert reply == MitReply(
        1, 32767 * 25 / 65535 - 12.5, 2047 * 60 / 4095 - 30, 2047 * 20 / 4095 - 10, True, 0, 30.0, 28.0
    )


@pytest.mark.parametrize(
    ("status", "enabled", "fault"), [(0x0, False, 0), (0x1, True, 0), (0xD, False, 0xD), (0x8, False, 0x8)]
)
def test_damiao_status_nibble(status: int, enabled: bool, fault: int) -> None:
    data = bytes([status << 4 | 0x3, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF, 25, 25])
    reply = DAMIAO.decode_reply(frame(0x13, data), DM4310, 3)
    assert (reply.enabled, reply.fault) == (enabled, fault)


def test_damiao_fault_names() -> None:
    assert DAMIAO.describe_fault(0xD) == "communication lost (CAN timeout)"
    assert DAMIAO.describe_fault(0xB) == "MOS over-temperature"
    assert DAMIAO.describe_fault(0) == "no fault"
    assert DAMIAO.describe_fault(0x7) == "unknown fault 0x7"
    assert TMOTOR.describe_fault(2) == "over-current"


def test_damiao_reply_fault_status_wins_over_enabled() -> None:
    msg = DAMIAO.encode_reply(2, 0x12, 0.0, 0.0, 0.0, DM4310, enabled=True, fault=0xD, t_mos=None, t_rotor=None)
    assert msg.data[0] == 0xD2
    assert DAMIAO.decode_reply(msg, DM4310, 2).fault == 0xD


@pytest.mark.parametrize(
    ("msg", "reason"),
    [
        (frame(0x11, bytes([0x11, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF, 30])), "DLC 8, got 7"),
        (frame(0x11, bytes([0x12, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF, 30, 30])), "nibble 0x2, expected 0x1"),
        (frame(0x11, bytes([0x71, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF, 30, 30])), "unknown status nibble 0x7"),
        (frame(0x12, bytes([0x11, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF, 30, 30])), "reply on id 0x12, expected 0x11"),
        (can.Message(arbitration_id=0x11, data=bytes(8), is_extended_id=True), "extended id"),
        (can.Message(arbitration_id=0x11, is_remote_frame=True, is_extended_id=False, dlc=8), "remote frame"),
        (can.Message(arbitration_id=0x11, is_error_frame=True), "error frame"),
    ],
)
def test_damiao_bad_replies(msg: can.Message, reason: str) -> None:
    with pytest.raises(FrameError, match=reason):
        DAMIAO.decode_reply(msg, DM4310, 1, master_id=0x11)


def test_tmotor_reply_by_hand_8_and_6_bytes() -> None:
    # id 2, AK80-9 (p ±12.5, v ±50, t ±18):
    # p =  1.5 : 14 * 65535 / 25  = 36699.6 -> 36699 = 0x8F5B
    # v = -3.0 : 47 * 4095 / 100  = 1924.65 -> 1924  = 0x784
    # t =  2.0 : 20 * 4095 / 36   = 2275.0  -> 2275  = 0x8E3
    # 8-byte: 02 8F 5B 78 48 E3 | temperature 40 = 0x28 | error 0
    long = TMOTOR.encode_reply(2, 0, 1.5, -3.0, 2.0, AK80_9, enabled=True, fault=0, t_mos=40.0, t_rotor=None)
    assert long.arbitration_id == 0
    assert bytes(long.data) == bytes([0x02, 0x8F, 0x5B, 0x78, 0x48, 0xE3, 0x28, 0x00])
    reply = TMOTOR.decode_reply(long, AK80_9, 2, master_id=0)
    assert reply.position == pytest.approx(36699 * 25 / 65535 - 12.5)
    assert reply.velocity == pytest.approx(1924 * 100 / 4095 - 50)
    assert reply.torque == pytest.approx(2275 * 36 / 4095 - 18)
    assert (reply.enabled, reply.fault, reply.temperature_mos, reply.temperature_rotor) == (None, 0, 40.0, None)

    short = TMOTOR.encode_reply(
        2, 0, 1.5, -3.0, 2.0, AK80_9, enabled=True, fault=3, t_mos=40.0, t_rotor=None, short=True
    )
    assert bytes(short.data) == bytes([0x02, 0x8F, 0x5B, 0x78, 0x48, 0xE3])
    reply6 = TMOTOR.decode_reply(short, AK80_9, 2)
    assert (reply6.position, reply6.fault, reply6.temperature_mos) == (reply.position, 0, None)


def test_tmotor_error_byte_and_id_in_byte_0() -> None:
    data = bytes([0x02, 0x8F, 0x5B, 0x78, 0x48, 0xE3, 0x50, 0x02])
    reply = TMOTOR.decode_reply(frame(0, data), AK80_9, 2)
    assert (reply.fault, reply.temperature_mos) == (2, 80.0)
    with pytest.raises(FrameError, match="names motor 2, expected 3"):
        TMOTOR.decode_reply(frame(0, data), AK80_9, 3)
    with pytest.raises(FrameError, match="DLC 6 or 8, got 7"):
        TMOTOR.decode_reply(frame(0, data[:7]), AK80_9, 2)


def test_myactuator_reply_by_hand() -> None:
    # id 1 on 0x501, p ±12.5, v ±45, t ±24:
    # p = -1.0 : 11.5 * 65535 / 25 = 30146.1  -> 30146 = 0x75C2
    # v =  0.5 : 45.5 * 4095 / 90  = 2070.25  -> 2070  = 0x816
    # t = -2.0 : 22 * 4095 / 48    = 1876.875 -> 1876  = 0x754
    msg = MYACTUATOR.encode_reply(1, 0, -1.0, 0.5, -2.0, MOTION, enabled=True, fault=0, t_mos=None, t_rotor=None)
    assert msg.arbitration_id == 0x501
    assert bytes(msg.data) == bytes([0x01, 0x75, 0xC2, 0x81, 0x67, 0x54, 0x00, 0x00])
    reply = MYACTUATOR.decode_reply(msg, MOTION, 1)
    assert reply.position == pytest.approx(30146 * 25 / 65535 - 12.5)
    assert (reply.enabled, reply.fault, reply.temperature_mos) == (None, 0, None)
    with pytest.raises(FrameError, match="reply on id 0x501, expected 0x502"):
        MYACTUATOR.decode_reply(msg, MOTION, 2)
    with pytest.raises(FrameError, match="names motor 9, expected 1"):
        MYACTUATOR.decode_reply(frame(0x501, bytes([9]) + bytes(msg.data[1:])), MOTION, 1)


def test_models_and_overrides() -> None:
    assert ranges_for("damiao", "DM8009") == MitRanges(12.5, 45.0, 54.0)
    assert ranges_for("tmotor", "AK80-64", {"v_max": 9}) == MitRanges(12.5, 9.0, 144.0)
    assert set(MODELS) == set(FLAVOURS)
    with pytest.raises(ValueError, match="unknown damiao model 'DM9999'"):
        ranges_for("damiao", "DM9999")
    with pytest.raises(ValueError, match="unknown MIT flavour"):
        ranges_for("cybergear", "x")
    with pytest.raises(ValueError, match="unknown range fields"):
        ranges_for("damiao", "DM4310", {"q_max": 1.0})


@given(
    arb=st.integers(0, 0x7FF),
    data=st.binary(min_size=0, max_size=8),
    flavour=st.sampled_from(sorted(FLAVOURS)),
    motor=st.integers(1, 16),
)
def test_random_frames_decode_or_raise_frame_error(arb: int, data: bytes, flavour: str, motor: int) -> None:
    try:
        reply = FLAVOURS[flavour].decode_reply(frame(arb, data), DM4310, motor)
    except FrameError:
        return
    assert -12.5 <= reply.position <= 12.5 and -10.0 <= reply.torque <= 10.0


# ---- the host's specialised decoders: the values of decode_reply, bit for bit ------------------------------------

range_value = st.floats(1e-3, 1e4)
ranges = st.builds(MitRanges, p_max=range_value, v_max=range_value, t_max=range_value)
REPLY_LENGTHS = {"damiao": [8], "tmotor": [6, 8], "myactuator": [8]}


@st.composite
def reply_case(draw: st.DrawFn) -> tuple[str, MitRanges, int, bytes]:
    """A reply as the host routes it (right id and DLC); D0 usually names the motor, sometimes not."""
    flavour = draw(st.sampled_from(sorted(FLAVOURS)))
    motor = draw(st.integers(1, 32))
    data = bytearray(draw(st.binary(min_size=8, max_size=8)))[: draw(st.sampled_from(REPLY_LENGTHS[flavour]))]
    if draw(st.booleans()):
        data[0] = (data[0] & 0xF0 | motor & 0xF) if flavour == "damiao" else motor
    return flavour, draw(ranges), motor, bytes(data)


@given(case=reply_case())
@settings(max_examples=500)
def test_reply_decoder_matches_decode_reply(case: tuple[str, MitRanges, int, bytes]) -> None:
    name, r, motor, data = case
    flavour = FLAVOURS[name]
    msg = frame(flavour.reply_id(motor, 0x11), data)
    try:
        want: MitReply | str = flavour.decode_reply(msg, r, motor, master_id=0x11)
    except FrameError as exc:
        want = str(exc)
    try:
        got: MitReply | str = MitReply(motor, *flavour.reply_decoder(r, motor)(bytearray(data)))
    except FrameError as exc:
        got = str(exc)
    assert got == want  # same floats (==, not approx), same None/bool/int fields, or the same reason


@pytest.mark.parametrize("status", [0x0, 0x1, *DAMIAO.fault_names])
def test_damiao_decoder_on_every_status_and_a_full_sweep_of_one_field(status: int) -> None:
    decode = DAMIAO.reply_decoder(DM4310, 0x13)
    for u in range(0, 1 << 16, 7):
        data = bytes([status << 4 | 0x3]) + (u << 24 | (u & 0xFFF) << 12 | u >> 4).to_bytes(5, "big") + b"\x1e\x50"
        assert MitReply(0x13, *decode(data)) == DAMIAO.decode_reply(frame(0x11, data), DM4310, 0x13)
