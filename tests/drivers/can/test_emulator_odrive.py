"""ODrive CAN Simple firmware model: cyclic messages, axis state machine, inputs per mode, watchdog, errors."""

from __future__ import annotations

import math

import can
import pytest

from drivers.can.emulator.firmware import ODriveFirmware
from drivers.can.protocol import odrive as od
from drivers.can.protocol.odrive import AxisState, Cmd, ControlMode, InputMode, ODriveError

NODE = 4


def heartbeats(frames: list[can.Message]) -> list[od.Heartbeat]:
    return [od.decode_heartbeat(f.data) for f in frames if od.split_id(f.arbitration_id) == (NODE, Cmd.HEARTBEAT)]


def estimates(frames: list[can.Message]) -> list[od.EncoderEstimates]:
    wanted = (NODE, Cmd.GET_ENCODER_ESTIMATES)
    return [od.decode_encoder_estimates(f.data) for f in frames if od.split_id(f.arbitration_id) == wanted]


def test_boots_idle_and_sends_cyclic_messages_at_their_rates() -> None:
    fw = ODriveFirmware(NODE, heartbeat_period=0.1, encoder_period=0.01)
    fw.observe(math.pi, -2 * math.pi, 0.0)
    frames: list[can.Message] = []
    for k in range(1001):  # 1 s at 1 kHz
        frames += fw.tick(k * 0.001)
    hbs = heartbeats(frames)
    assert len(hbs) == 11 and len(estimates(frames)) == 101  # t = 0, 0.1, …, 1.0 and 0, 0.01, …, 1.0
    assert hbs[0] == (0, AxisState.IDLE, 0, True)
    assert estimates(frames)[0] == pytest.approx((0.5, -1.0))  # π rad = 0.5 rev
    assert not fw.enabled


def test_cyclic_off_and_rtr_getters() -> None:
    fw = ODriveFirmware(NODE, heartbeat_period=0.0, encoder_period=0.0)
    assert fw.tick(0.0) == [] and fw.tick(5.0) == []
    fw.temperature_mos, fw.temperature_rotor = 41.0, 37.0
    (frame,) = fw.handle(od.request(NODE, Cmd.GET_TEMPERATURE), 0.0)
    assert od.decode_temperature(frame.data) == (41.0, 37.0)
    (frame,) = fw.handle(od.request(NODE, Cmd.HEARTBEAT), 0.0)
    assert od.decode_heartbeat(frame.data).axis_state == AxisState.IDLE
    (frame,) = fw.handle(od.request(NODE, Cmd.GET_ERROR), 0.0)
    assert od.decode_error(frame.data) == (0, 0)


def test_closed_loop_position_mode_law_and_no_jump_on_arming() -> None:
    fw = ODriveFirmware(NODE, pos_gain=20.0, vel_gain=0.5, vel_limit=100.0, torque_limit=50.0)
    fw.observe(2 * math.pi * 0.3, 0.0, 0.0)  # shaft at 0.3 rev
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.0)
    assert fw.enabled and fw.input_pos == pytest.approx(0.3)
    assert fw.torque(2 * math.pi * 0.3, 0.0) == pytest.approx(0.0)  # arming holds where it is
    fw.handle(od.encode_set_input_pos(NODE, 0.5, 0.1, 0.2), 0.001)
    # vel_sp = 20 * (0.5 - 0.3) + 0.1 = 4.1 rev/s; torque = 0.5 * (4.1 - 1.0) + 0.2 = 1.75 Nm at 1 rev/s
    assert fw.torque(2 * math.pi * 0.3, 2 * math.pi * 1.0) == pytest.approx(1.75, abs=1e-6)
    fw.vel_limit = 2.0  # vel_sp clamps to 2 -> 0.5 * (2 - 1) + 0.2 = 0.7
    assert fw.torque(2 * math.pi * 0.3, 2 * math.pi * 1.0) == pytest.approx(0.7, abs=1e-6)


def test_velocity_and_torque_modes_use_their_inputs() -> None:
    fw = ODriveFirmware(NODE, vel_gain=0.5, torque_limit=3.0)
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.0)
    fw.handle(od.encode_set_controller_mode(NODE, ControlMode.VELOCITY_CONTROL, InputMode.PASSTHROUGH), 0.0)
    fw.handle(od.encode_set_input_vel(NODE, 2.0, 0.25), 0.0)
    assert fw.torque(123.0, 0.0) == pytest.approx(0.5 * 2.0 + 0.25)  # position plays no part
    fw.handle(od.encode_set_controller_mode(NODE, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH), 0.0)
    fw.handle(od.encode_set_input_torque(NODE, -9.0), 0.0)
    assert fw.torque(0.0, 5.0) == -3.0  # clamped to torque_limit
    fw.handle(od.encode_set_input_pos(NODE, 10.0), 0.0)  # written, but torque mode ignores it
    assert fw.torque(0.0, 0.0) == 0.0  # Set_Input_Pos also wrote torque_ff = 0


def test_watchdog_disarms_with_bit_and_needs_clear_errors() -> None:
    fw = ODriveFirmware(NODE, watchdog_timeout=0.05, heartbeat_period=0.0, encoder_period=0.0)
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.0)
    fw.handle(od.encode_set_input_pos(NODE, 0.0), 0.04)
    fw.tick(0.089)
    assert fw.enabled
    fw.tick(0.091)
    assert not fw.enabled and fw.axis_error == ODriveError.WATCHDOG_TIMER_EXPIRED
    (frame,) = fw.handle(od.request(NODE, Cmd.GET_ERROR), 0.1)
    assert od.decode_error(frame.data) == (0x0100_0000, 0x0100_0000)
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.11)
    assert not fw.enabled  # closed loop needs no error
    (frame,) = fw.handle(od.request(NODE, Cmd.HEARTBEAT), 0.12)
    assert od.decode_heartbeat(frame.data)[:2] == (0x0100_0000, AxisState.IDLE)
    fw.handle(od.encode_clear_errors(NODE), 0.13)
    assert fw.axis_error == 0 and not fw.enabled  # clearing never re-arms
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.14)
    assert fw.enabled


def test_estop_injected_faults_calibration_and_reboot() -> None:
    fw = ODriveFirmware(NODE, keep_position_on_reboot=False)
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.0)
    fw.handle(od.encode_estop(NODE), 0.0)
    assert not fw.enabled and fw.axis_error & ODriveError.ESTOP_REQUESTED
    fw.handle(od.encode_clear_errors(NODE), 0.0)
    fw.handle(od.encode_set_axis_state(NODE, AxisState.FULL_CALIBRATION_SEQUENCE), 0.0)
    assert fw.axis_state == AxisState.IDLE and fw.procedure_result == od.ProcedureResult.SUCCESS
    fw.handle(od.encode_set_axis_state(NODE, AxisState.CLOSED_LOOP_CONTROL), 0.0)
    fw.inject_fault(ODriveError.DRV_FAULT)
    assert not fw.enabled and od.describe_errors(fw.fault) == "DRV_FAULT"
    fw.observe(2 * math.pi * 3.0, 0.0, 0.0)
    fw.handle(od.encode_reboot(NODE), 0.0)
    assert (fw.axis_state, fw.axis_error) == (AxisState.IDLE, 0)
    assert fw.pos_estimate == pytest.approx(0.0)  # incremental encoder: position restarts at zero
    assert heartbeats(fw.tick(0.0))  # announces itself right after boot
    fw.handle(od.encode_set_absolute_position(NODE, 1.5), 0.0)
    assert fw.pos_estimate == pytest.approx(1.5)


def test_frames_for_other_nodes_and_garbled_payloads() -> None:
    fw = ODriveFirmware(NODE)
    assert fw.accepts(od.encode_set_input_torque(NODE, 1.0))
    assert not fw.accepts(od.encode_set_input_torque(NODE + 1, 1.0))
    bad = can.Message(arbitration_id=od.arbitration_id(NODE, Cmd.SET_INPUT_POS), data=b"\x00\x01", is_extended_id=False)
    assert fw.handle(bad, 0.0) == []
    assert fw.counters["garbled"] == 1 and "Set_Input_Pos needs 8" in fw.last_error
    bad_mode = od.encode_set_controller_mode(NODE, 9, 1)
    assert fw.handle(bad_mode, 0.0) == [] and fw.counters["ignored"] == 1
