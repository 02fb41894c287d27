"""ODrive CAN Simple (0.6) payloads against bytes worked out by hand."""

from __future__ import annotations

import struct
from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.can.protocol import FrameError
from drivers.can.protocol import odrive as od


def test_ids() -> None:
    # node 3, Set_Input_Pos 0x0C: 3 << 5 | 0x0C = 0x6C
    assert od.arbitration_id(3, od.Cmd.SET_INPUT_POS) == 0x6C
    assert od.split_id(0x6C) == (3, 0x0C)
    assert od.split_id(od.arbitration_id(0x3F, 0x1F)) == (0x3F, 0x1F)
    with pytest.raises(ValueError, match="node id"):
        od.arbitration_id(64, 1)


def test_heartbeat_by_hand() -> None:
    # error 0x01000000 LE = 00 00 00 01; state IDLE 1; result 0; trajectory done bit 48 -> byte 6 = 1
    msg = od.encode_heartbeat(3, od.Heartbeat(0x0100_0000, od.AxisState.IDLE, 0, True))
    assert msg.arbitration_id == 0x61
    assert bytes(msg.data) == bytes([0x00, 0x00, 0x00, 0x01, 0x01, 0x00, 0x01, 0x00])
    assert od.decode_heartbeat(msg.data) == (0x0100_0000, 1, 0, True)
    assert od.decode_heartbeat(bytes([0, 0, 0, 0, 8, 0, 0, 0])).trajectory_done is False
    with pytest.raises(FrameError, match="heartbeat needs 8 data bytes, got 7"):
        od.decode_heartbeat(bytes(7))


def test_set_input_pos_by_hand() -> None:
    # 1.0 rev = 0x3F800000 -> 00 00 80 3F; vel_ff 0.5 / 0.001 = 500 = 0x01F4 -> F4 01; torque -0.25 -> -250 = 0xFF06
    msg = od.encode_set_input_pos(3, 1.0, 0.5, -0.25)
    assert bytes(msg.data) == bytes([0x00, 0x00, 0x80, 0x3F, 0xF4, 0x01, 0x06, 0xFF])
    assert od.decode_set_input_pos(msg.data) == pytest.approx((1.0, 0.5, -0.25))
    # feed-forwards saturate at int16: 100 rev/s -> 32767
    assert od.decode_set_input_pos(od.encode_set_input_pos(0, 0.0, 100.0, -100.0).data)[1:] == pytest.approx(
        (32.767, -32.768)
    )


def test_other_payloads_by_hand() -> None:
    assert bytes(od.encode_set_axis_state(1, od.AxisState.CLOSED_LOOP_CONTROL).data) == bytes([8, 0, 0, 0])
    assert od.decode_set_axis_state(bytes([8, 0, 0, 0])) == 8
    # 0.25 rev = 0x3E800000, -2.0 rev/s = 0xC0000000
    est = od.encode_encoder_estimates(1, 0.25, -2.0)
    assert est.arbitration_id == 0x29 and bytes(est.data) == bytes([0, 0, 0x80, 0x3E, 0, 0, 0, 0xC0])
    assert od.decode_encoder_estimates(est.data) == (0.25, -2.0)
    mode = od.encode_set_controller_mode(1, od.ControlMode.POSITION_CONTROL, od.InputMode.PASSTHROUGH)
    assert bytes(mode.data) == bytes([3, 0, 0, 0, 1, 0, 0, 0])
    assert bytes(od.encode_set_input_torque(1, -2.0).data) == bytes([0, 0, 0, 0xC0])
    assert od.decode_set_input_vel(od.encode_set_input_vel(1, 2.0, 0.25).data) == (2.0, 0.25)
    assert bytes(od.encode_clear_errors(1).data) == b"\x00" and od.decode_clear_errors(b"") is False
    assert od.decode_reboot(od.encode_reboot(1).data) == od.RebootAction.REBOOT
    assert od.decode_temperature(od.encode_temperature(1, 40.0, 35.5).data) == (40.0, 35.5)
    assert od.decode_error(od.encode_error(1, 0x40, 0x0100_0000).data) == (0x40, 0x0100_0000)
    rtr = od.request(1, od.Cmd.GET_ENCODER_ESTIMATES)
    assert rtr.is_remote_frame and rtr.arbitration_id == 0x29 and not rtr.is_extended_id


def test_describe_errors() -> None:
    assert od.describe_errors(0) == "no error"
    assert od.describe_errors(0x0100_0000) == "WATCHDOG_TIMER_EXPIRED"
    assert od.describe_errors(0x0100_0000 | 0x2 | 0x8000_0000) == "SYSTEM_LEVEL|WATCHDOG_TIMER_EXPIRED|0x80000000"


# ---- in-place packers for the host's cycle: the bytes (and errors) of the encode_* functions -------------------

any_float = st.floats()  # NaN, ±inf and magnitudes beyond float32 included
near_ff = st.floats(-40.0, 40.0)  # around the ±32.767 saturation of the int16 feed-forwards


def outcome(fn: Callable[[], bytes]) -> bytes | type[BaseException]:
    try:
        return fn()
    except (ValueError, OverflowError, struct.error) as exc:
        return type(exc)


def packed(pack: Callable[..., None], size: int, *values: float) -> bytes:
    buffer = bytearray(b"\xaa" * size)  # stale bytes from an earlier cycle must all be overwritten
    pack(buffer, *values)
    return bytes(buffer)


@given(position=any_float, vel_ff=any_float | near_ff, torque_ff=any_float | near_ff)
def test_pack_set_input_pos_matches_encode(position: float, vel_ff: float, torque_ff: float) -> None:
    want = outcome(lambda: bytes(od.encode_set_input_pos(3, position, vel_ff, torque_ff).data))
    assert outcome(lambda: packed(od.pack_set_input_pos, 8, position, vel_ff, torque_ff)) == want


@given(velocity=any_float, torque_ff=any_float)
def test_pack_set_input_vel_and_torque_match_encode(velocity: float, torque_ff: float) -> None:
    want = outcome(lambda: bytes(od.encode_set_input_vel(3, velocity, torque_ff).data))
    assert outcome(lambda: packed(od.pack_set_input_vel, 8, velocity, torque_ff)) == want
    want = outcome(lambda: bytes(od.encode_set_input_torque(3, torque_ff).data))
    assert outcome(lambda: packed(od.pack_set_input_torque, 4, torque_ff)) == want


def test_empty_frame_is_the_frame_encode_would_build() -> None:
    built = od.encode_set_input_pos(5, 1.0, 0.5, -0.25)
    frame = od.empty_frame(5, od.Cmd.SET_INPUT_POS, 8)
    od.pack_set_input_pos(frame.data, 1.0, 0.5, -0.25)
    assert frame.equals(built, timestamp_delta=None)
    torque = od.empty_frame(5, od.Cmd.SET_INPUT_TORQUE, 4)
    assert (torque.arbitration_id, torque.dlc, torque.is_extended_id, torque.is_remote_frame) == (0xAE, 4, False, False)
