"""T-Motor AK and MyActuator firmware models: enable → command → reply → disable, faults and watchdogs."""

from __future__ import annotations

import struct

import can
import pytest

from drivers.can.emulator.firmware import MyActuatorFirmware, TMotorFirmware
from drivers.can.protocol.flavours import MYACTUATOR, TMOTOR
from drivers.can.protocol.mit import MitRanges, quantize

AK80_9 = MitRanges(12.5, 50.0, 18.0)
MOTION = MitRanges(12.5, 45.0, 24.0)


def tm_special(fw: TMotorFirmware, kind: str, now: float) -> list[can.Message]:
    msg = TMOTOR.special(fw.motor_id, kind)  # type: ignore[arg-type]
    assert msg is not None
    return fw.handle(msg, now)


def test_tmotor_enable_command_reply_disable() -> None:
    fw = TMotorFirmware(2, AK80_9)
    fw.observe(-0.5, 0.0, 0.0)
    assert not fw.enabled
    (reply_frame,) = tm_special(fw, "enable", 0.0)
    assert reply_frame.arbitration_id == 0 and reply_frame.dlc == 8 and reply_frame.data[0] == 2
    assert fw.enabled
    (frame,) = fw.handle(TMOTOR.command(2, 0.5, 0.0, 10.0, 1.0, 0.0, AK80_9), 0.001)
    cmd = fw.command
    assert fw.torque(-0.5, 0.0) == pytest.approx(cmd.kp * (cmd.p + 0.5) + cmd.kd * cmd.v + cmd.t)
    (frame,) = fw.handle(TMOTOR.command(2, 0.5, 0.0, 10.0, 1.0, 0.0, AK80_9), 0.002)
    reply = TMOTOR.decode_reply(frame, AK80_9, 2, master_id=0)
    assert reply.position == quantize(-0.5, -12.5, 12.5, 16)
    assert reply.torque == pytest.approx(fw.applied_torque, abs=36 / 4095)
    assert (reply.fault, reply.temperature_mos) == (0, 25.0)
    tm_special(fw, "disable", 0.003)
    assert not fw.enabled and fw.torque(-0.5, 0.0) == 0.0


def test_tmotor_six_byte_variant() -> None:
    fw = TMotorFirmware(3, AK80_9, short_replies=True)
    (frame,) = tm_special(fw, "enable", 0.0)
    assert frame.dlc == 6
    assert TMOTOR.decode_reply(frame, AK80_9, 3).temperature_mos is None


def test_tmotor_has_no_clear_frame_so_ff_fb_is_an_ordinary_command() -> None:
    fw = TMotorFirmware(2, AK80_9)
    tm_special(fw, "enable", 0.0)
    fw.handle(can.Message(arbitration_id=2, data=b"\xff" * 7 + b"\xfb", is_extended_id=False), 0.0)
    # p = +12.5, kp = 500: the drive would pull hard toward the range end — which is why hosts must not send it
    assert fw.command.kp == 500.0 and fw.command.p == 12.5


def test_tmotor_fault_in_error_byte_latches_until_reboot() -> None:
    fw = TMotorFirmware(2, AK80_9)
    tm_special(fw, "enable", 0.0)
    fw.inject_fault(2)
    (frame,) = tm_special(fw, "enable", 0.1)
    assert TMOTOR.decode_reply(frame, AK80_9, 2).fault == 2 and not fw.enabled
    fw.reboot()
    (frame,) = tm_special(fw, "enable", 0.2)
    assert TMOTOR.decode_reply(frame, AK80_9, 2).fault == 0 and fw.enabled


def test_tmotor_watchdog_zeroes_command_but_stays_in_motor_mode() -> None:
    fw = TMotorFirmware(2, AK80_9, timeout=0.05)
    tm_special(fw, "enable", 0.0)
    fw.handle(TMOTOR.command(2, 1.0, 0.0, 20.0, 1.0, 2.0, AK80_9), 0.01)
    fw.tick(0.059)
    assert fw.torque(0.0, 0.0) != 0.0
    fw.tick(0.061)
    assert fw.enabled and fw.torque(0.3, 0.2) == 0.0


def test_myactuator_motion_command_runs_and_replies_on_0x500() -> None:
    fw = MyActuatorFirmware(1, MOTION)
    fw.observe(0.25, 0.0, 0.0)
    assert not fw.enabled and fw.torque(0.25, 0.0) == 0.0
    (frame,) = fw.handle(MYACTUATOR.command(1, 1.0, 0.0, 10.0, 1.0, 0.0, MOTION), 0.0)
    assert frame.arbitration_id == 0x501 and fw.enabled
    reply = MYACTUATOR.decode_reply(frame, MOTION, 1)
    assert reply.position == quantize(0.25, -12.5, 12.5, 16) and reply.enabled is None
    cmd = fw.command
    assert fw.torque(0.25, 0.0) == pytest.approx(cmd.kp * (cmd.p - 0.25) + cmd.kd * cmd.v + cmd.t)
    off = MYACTUATOR.special(1, "disable")
    assert off is not None
    (ack,) = fw.handle(off, 0.001)
    assert MYACTUATOR.is_ack(ack, 1) and ack.data[0] == 0x80
    assert not fw.enabled and fw.torque(0.25, 0.0) == 0.0


def test_myactuator_status_timeout_and_fault() -> None:
    fw = MyActuatorFirmware(1, MOTION)
    native = 0x141
    set_timeout = can.Message(
        arbitration_id=native, data=bytes([0xB3, 0, 0, 0]) + struct.pack("<I", 20), is_extended_id=False
    )
    fw.handle(set_timeout, 0.0)
    assert fw.timeout == pytest.approx(0.020)
    fw.handle(MYACTUATOR.command(1, 1.0, 0.0, 10.0, 1.0, 0.0, MOTION), 0.0)
    fw.tick(0.021)
    assert not fw.enabled  # output cut when commands stop …
    fw.handle(MYACTUATOR.command(1, 1.0, 0.0, 10.0, 1.0, 0.0, MOTION), 0.03)
    assert fw.enabled  # … and runs again once they flow
    fw.inject_fault(0x0010)  # over-current
    fw.handle(MYACTUATOR.command(1, 1.0, 0.0, 10.0, 1.0, 0.0, MOTION), 0.04)
    assert not fw.enabled
    (status,) = fw.handle(can.Message(arbitration_id=native, data=bytes([0x9A] + [0] * 7), is_extended_id=False), 0.05)
    code, temperature, _, brake, voltage, errors = struct.unpack("<BbBBHH", status.data)
    assert (status.arbitration_id, code, temperature, brake, voltage, errors) == (0x241, 0x9A, 25, 0, 480, 0x0010)
    fw.handle(can.Message(arbitration_id=native, data=bytes([0x76] + [0] * 7), is_extended_id=False), 0.06)
    assert fw.fault == 0 and not fw.enabled
