"""Damiao firmware model: power-up, enable/command/disable, status nibble, faults, watchdog, registers, reboot."""

from __future__ import annotations

import can
import pytest

from drivers.can.emulator.firmware import DamiaoFirmware
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.flavours import DAMIAO, MitReply
from drivers.can.protocol.mit import MitRanges, quantize

DM4310 = MitRanges(12.5, 30.0, 10.0)
ESC, MST = 0x01, 0x11


def motor(**kw: int) -> DamiaoFirmware:
    return DamiaoFirmware(ESC, MST, DM4310, **kw)


def only_reply(frames: list[can.Message], ranges: MitRanges = DM4310) -> MitReply:
    assert len(frames) == 1
    assert frames[0].arbitration_id == MST
    return DAMIAO.decode_reply(frames[0], ranges, ESC, master_id=MST)


def send(fw: DamiaoFirmware, kind: str, now: float) -> MitReply:
    msg = DAMIAO.special(ESC, kind)  # type: ignore[arg-type]
    assert msg is not None
    return only_reply(fw.handle(msg, now))


def command(fw: DamiaoFirmware, now: float, p: float, v: float, kp: float, kd: float, t: float) -> MitReply:
    return only_reply(fw.handle(DAMIAO.command(ESC, p, v, kp, kd, t, DM4310), now))


def test_power_up_disabled_and_replies_with_status_0() -> None:
    fw = motor()
    fw.observe(0.3, 0.0, 0.0)
    assert not fw.enabled and fw.fault == 0
    reply = command(fw, 0.0, 1.0, 0.0, 50.0, 1.0, 0.0)  # ignored while disabled, but answered
    assert (reply.enabled, reply.fault) == (False, 0)
    assert reply.position == quantize(0.3, -12.5, 12.5, 16)
    assert fw.torque(0.3, 0.0) == 0.0
    assert reply.temperature_mos == 25.0 and reply.temperature_rotor == 25.0


def test_enable_command_reply_disable() -> None:
    fw = motor()
    fw.observe(0.2, 0.1, 0.0)
    assert send(fw, "enable", 0.0).enabled is True
    assert fw.torque(0.2, 0.1) == 0.0  # enabling starts limp, never from a stale command
    reply = command(fw, 0.001, 1.0, 0.0, 10.0, 0.5, 0.2)
    assert reply.enabled is True and reply.fault == 0
    cmd = fw.command  # what the drive decoded (quantised), e.g. kp = int(10 * 4095 / 500) * 500 / 4095
    assert cmd.kp == quantize(10.0, 0.0, 500.0, 12) and cmd.p == quantize(1.0, -12.5, 12.5, 16)
    expected = cmd.kp * (cmd.p - 0.2) + cmd.kd * (cmd.v - 0.1) + cmd.t
    assert fw.torque(0.2, 0.1) == pytest.approx(expected)
    # the reply after the law ran reports the applied torque, quantised
    assert command(fw, 0.002, 1.0, 0.0, 10.0, 0.5, 0.2).torque == pytest.approx(expected, abs=20 / 4095)
    assert send(fw, "disable", 0.003).enabled is False
    assert fw.torque(0.2, 0.1) == 0.0


def test_torque_clamped_to_tmax() -> None:
    fw = motor()
    send(fw, "enable", 0.0)
    command(fw, 0.0, 10.0, 0.0, 500.0, 0.0, 0.0)
    assert fw.torque(0.0, 0.0) == 10.0
    command(fw, 0.0, -10.0, 0.0, 500.0, 0.0, 0.0)
    assert fw.torque(0.0, 0.0) == -10.0


def test_zero_frame_sets_current_position_as_zero() -> None:
    fw = motor()
    fw.observe(1.234, 0.0, 0.0)
    reply = send(fw, "zero", 0.0)
    assert reply.position == quantize(0.0, -12.5, 12.5, 16)
    fw.observe(1.334, 0.0, 0.0)
    assert only_reply(fw.handle(reg.refresh_request(ESC), 0.0)).position == pytest.approx(0.1, abs=25 / 65535)


def test_fault_latches_refuses_enable_and_clears_to_disabled() -> None:
    fw = motor()
    send(fw, "enable", 0.0)
    command(fw, 0.0, 1.0, 0.0, 10.0, 0.5, 0.0)
    fw.inject_fault(0xA)
    assert not fw.enabled and fw.torque(0.0, 0.0) == 0.0
    assert send(fw, "enable", 0.1).fault == 0xA  # enable refused while latched
    assert not fw.enabled
    assert (reply := send(fw, "disable", 0.2)).fault == 0xA and reply.enabled is False  # disable keeps the latch
    cleared = send(fw, "clear", 0.3)
    assert (cleared.fault, cleared.enabled) == (0, False)
    assert send(fw, "enable", 0.4).enabled is True
    assert DAMIAO.describe_fault(0xA) == "over-current"
    with pytest.raises(ValueError, match="fault codes"):
        fw.inject_fault(0x3)


def test_watchdog_latches_lost_comm_and_never_reenables_itself() -> None:
    fw = motor(timeout_counts=200)  # 200 × 50 µs = 10 ms
    assert fw.timeout == pytest.approx(0.010)
    send(fw, "enable", 0.0)
    command(fw, 0.005, 1.0, 0.0, 10.0, 0.5, 0.0)
    fw.tick(0.0149)
    assert fw.enabled  # 9.9 ms since the last command
    fw.tick(0.0151)
    assert not fw.enabled and fw.fault == 0xD
    # commands keep arriving: the drive answers 0xD and stays off
    reply = command(fw, 0.016, 1.0, 0.0, 10.0, 0.5, 0.0)
    assert (reply.enabled, reply.fault) == (False, 0xD)
    assert fw.torque(0.0, 0.0) == 0.0
    # enable alone does nothing; clear then enable does
    assert send(fw, "enable", 0.017).fault == 0xD
    send(fw, "clear", 0.018)
    assert send(fw, "enable", 0.019).enabled is True
    assert fw.command.kp == 0.0  # comes back limp


def test_watchdog_expiry_is_seen_by_a_late_command_before_it_feeds() -> None:
    fw = motor(timeout_counts=20)  # 1 ms
    send(fw, "enable", 0.0)
    reply = command(fw, 0.005, 1.0, 0.0, 10.0, 0.5, 0.0)  # 5 ms of silence, no tick in between
    assert reply.fault == 0xD and not fw.enabled


def test_the_drive_keeps_the_longest_silence_its_watchdog_saw_since_enable() -> None:
    fw = motor(timeout_counts=200)  # 10 ms
    send(fw, "enable", 0.0)
    command(fw, 0.002, 1.0, 0.0, 10.0, 0.5, 0.0)
    fw.tick(0.006)
    command(fw, 0.009, 1.0, 0.0, 10.0, 0.5, 0.0)  # 7 ms after the last one: the longest so far
    command(fw, 0.010, 1.0, 0.0, 10.0, 0.5, 0.0)
    assert fw.longest_command_gap == pytest.approx(0.007)
    fw.tick(0.0211)  # the silence that fires the watchdog is kept too
    assert fw.fault == 0xD and fw.longest_command_gap == pytest.approx(0.0111)
    send(fw, "clear", 0.022)
    send(fw, "enable", 0.023)
    assert fw.longest_command_gap == 0.0  # since this enable


def test_watchdog_off_when_timeout_is_zero_and_idle_when_disabled() -> None:
    fw = motor()
    send(fw, "enable", 0.0)
    fw.tick(100.0)
    assert fw.enabled
    fw2 = motor(timeout_counts=20)
    fw2.tick(100.0)
    assert fw2.fault == 0  # a disabled drive does not time out


def test_register_read_write_pmax_vmax_tmax() -> None:
    fw = motor()
    for rid, value in ((reg.PMAX, 12.5), (reg.VMAX, 30.0), (reg.TMAX, 10.0), (reg.CTRL_MODE, 1), (reg.MST_ID, MST)):
        (reply,) = fw.handle(reg.read_request(ESC, rid), 0.0)
        assert reply.arbitration_id == MST
        assert reg.decode_register_reply(reply) == (ESC, rid, value)
    (ack,) = fw.handle(reg.write_request(ESC, reg.VMAX, 45.0), 0.0)
    assert ack.data[2] == reg.OP_WRITE and reg.decode_register_reply(ack) == (ESC, reg.VMAX, 45.0)
    assert fw.ranges == MitRanges(12.5, 45.0, 10.0)
    fw.observe(0.0, 20.0, 0.0)
    # feedback now scales velocity over ±45: 20 rad/s -> int(65 * 4095 / 90) = 2957 -> 20.0 - a fraction of an LSB
    reply = only_reply(fw.handle(reg.refresh_request(ESC), 0.0), MitRanges(12.5, 45.0, 10.0))
    assert reply.velocity == pytest.approx(2957 * 90 / 4095 - 45)
    (timeout_ack,) = fw.handle(reg.write_request(ESC, reg.TIMEOUT, 40), 0.0)
    assert reg.decode_register_reply(timeout_ack)[2] == 40 and fw.timeout == pytest.approx(0.002)


def test_register_frames_for_other_ids_unknown_and_read_only() -> None:
    fw = motor()
    assert not fw.accepts(reg.read_request(ESC + 1, reg.PMAX))
    assert fw.handle(reg.read_request(ESC, 99), 0.0) == []
    assert fw.handle(reg.write_request(ESC, reg.SW_VER, 1), 0.0) == []
    assert fw.handle(reg.write_request(ESC, reg.CTRL_MODE, 7), 0.0) == []
    assert fw.handle(reg.write_request(ESC, reg.PMAX, -1.0), 0.0) == []
    assert fw.counters["ignored"] == 4
    assert fw.ranges == DM4310


def test_other_control_mode_ignores_mit_commands() -> None:
    fw = motor()
    send(fw, "enable", 0.0)
    fw.handle(reg.write_request(ESC, reg.CTRL_MODE, reg.CTRL_MODE_VEL), 0.0)
    assert fw.handle(DAMIAO.command(ESC, 1.0, 0.0, 10.0, 0.5, 0.0, DM4310), 0.0) == []
    assert fw.command.kp == 0.0


def test_reboot_comes_back_disabled_with_stored_registers_and_position_kept_or_wrapped() -> None:
    fw = motor()
    fw.observe(7.0, 0.0, 0.0)
    send(fw, "enable", 0.0)
    fw.handle(reg.write_request(ESC, reg.TIMEOUT, 100), 0.0)
    fw.handle(reg.write_request(ESC, reg.VMAX, 45.0), 0.0)
    fw.handle(reg.store_request(ESC), 0.0)
    fw.handle(reg.write_request(ESC, reg.TIMEOUT, 5), 0.0)  # RAM only
    fw.inject_fault(0xE)
    fw.reboot()
    assert (fw.enabled, fw.fault) == (False, 0)
    assert fw.registers[reg.TIMEOUT] == 100 and fw.ranges.v_max == 45.0
    assert fw.reported_position == 7.0
    fw.multi_turn_lost_on_reboot = True
    fw.reboot()
    assert fw.reported_position == pytest.approx(7.0 - 2 * 3.141592653589793)


def test_esc_id_change_takes_effect_and_is_flagged() -> None:
    fw = motor()
    fw.handle(reg.write_request(ESC, reg.ESC_ID, 5), 0.0)
    assert fw.ids_changed_in_ram and fw.motor_id == 5
    assert fw.accepts(DAMIAO.command(5, 0, 0, 0, 0, 0, DM4310))
    assert not fw.accepts(DAMIAO.command(ESC, 0, 0, 0, 0, 0, DM4310))


def test_thermal_model_heats_and_over_temperature_latches_0xb_or_0xc() -> None:
    fw = motor()
    send(fw, "enable", 0.0)
    command(fw, 0.0, 0.0, 0.0, 0.0, 0.0, 10.0)  # t_ff at TMAX, 3× rated torque -> rise 9 × 40 °C in steady state
    fw.torque(0.0, 0.0)
    fw.observe(0.0, 0.0, 1.0)
    assert 25.0 < fw.temperature_rotor < fw.temperature_mos  # the power stage heats faster
    for _ in range(200):
        fw.torque(0.0, 0.0)
        fw.observe(0.0, 0.0, 1.0)
    assert fw.fault in (0xB, 0xC) and not fw.enabled


def test_garbled_frames_counted_never_raised() -> None:
    fw = motor()
    short = can.Message(arbitration_id=ESC, data=b"\xff\xff\xfc", is_extended_id=False)
    assert fw.handle(short, 0.0) == []
    bad_register = can.Message(arbitration_id=0x7FF, data=bytes([ESC, 0, 0x33]), is_extended_id=False)
    assert fw.handle(bad_register, 0.0) == []
    assert fw.counters["garbled"] == 2 and "DLC 8" in fw.last_error
