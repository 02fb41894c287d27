"""mit_can against the firmware emulators on in-process virtual buses, in lockstep (no sleeps, deterministic).

Each test builds a driver with its own virtual channel and an Emulator on the same channel; a cycle is
``write → emulator.service(t + dt) → read``. Lifecycle hooks that wait for replies get the emulator through the
driver's ``serve_while_waiting``.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from drivers.can.emulator import DamiaoFirmware, Emulator, MotorPlant, MyActuatorFirmware, TMotorFirmware
from drivers.can.emulator.base import MotorFirmware
from drivers.can.mit_driver import FAULT_DISABLED, MitCanDriver
from drivers.can.params import MitCanParams
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.mit import MitRanges, quantize
from drivers.can.protocol.models import MODELS
from hild.config import load_config
from hild.cycle.engine import Engine
from hild.hardware import HardwareContext, HardwareError
from tests.conftest import joint
from tests.drivers.can.lockstep import LockstepRig, rig_factory

DM4310 = MODELS["damiao"]["DM4310"]
AK80_9 = MODELS["tmotor"]["AK80-9"]
MOTION = MODELS["myactuator"]["motion_mode"]
RATE = 1000.0
DT = 1.0 / RATE


def p_lsb(r: MitRanges) -> float:
    return 2 * r.p_max / 65535


class Rig(LockstepRig):
    """One mit_can driver and its emulated motors on a private virtual channel, stepped in lockstep."""

    def __init__(
        self,
        flavour: str,
        firmwares: dict[str, MotorFirmware],
        motors: dict[str, dict[str, Any]],
        *,
        positions: list[float] | None = None,
        **params: Any,
    ) -> None:
        super().__init__("mit", tuple(firmwares), RATE, wait_step=1e-4)
        raw = {
            "bus": {"interface": "virtual", "channel": self.channel},
            "flavour": flavour,
            "motors": motors,
            "reply_timeout_ms": 50,
            **params,
        }
        n = len(firmwares)
        self.attach(
            MitCanDriver(self.context("arm"), MitCanParams.model_validate(raw)),
            list(firmwares.values()),
            MotorPlant(n, inertia=0.05, damping=0.05, positions=positions or [0.0] * n),
        )

    def hold(self, kp: float = 20.0, kd: float = 1.0) -> None:
        super().hold(kp, kd)


rigs = rig_factory(Rig)


def damiao_rig(rigs: Any, n: int = 2, **params: Any) -> Rig:
    firmwares = {f"j{i}": DamiaoFirmware(i + 1, 0x11 + i, DM4310) for i in range(n)}
    motors = {f"j{i}": {"id": i + 1, "reply_id": 0x11 + i, "model": "DM4310"} for i in range(n)}
    return rigs("damiao", firmwares, motors, positions=[0.3 * (i + 1) for i in range(n)], **params)


# ---- Damiao start-up -----------------------------------------------------------------------------------------


def test_damiao_startup_reads_positions_before_enabling(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=3, timeout_ms=50)
    rig.driver.on_configure()
    assert not any(fw.enabled for fw in rig.firmwares)  # nothing enabled by configure
    rig.driver.read(0.0, DT, rig.state)
    np.testing.assert_allclose(rig.state.position, [0.3, 0.6, 0.9], atol=p_lsb(DM4310))
    assert rig.state.fresh.all() and not rig.state.fault.any()
    assert all(fw.registers[reg.TIMEOUT] == 1000 for fw in rig.firmwares)  # 50 ms in 50 µs counts
    rig.driver.on_activate()
    assert all(fw.enabled for fw in rig.firmwares)
    rig.hold()
    rig.cycle(200)
    np.testing.assert_allclose(rig.state.position, [0.3, 0.6, 0.9], atol=2e-3)  # hold where it started
    assert rig.state.fresh.all() and not rig.state.fault.any()
    assert all(fw.fault == 0 for fw in rig.firmwares)  # the watchdog was fed every cycle


def test_damiao_range_mismatch_refuses_to_start_naming_motor_and_values(rigs: Any) -> None:
    wrong = MitRanges(12.5, 45.0, 10.0)  # VMAX 45 on the motor, the config says DM4310 (30)
    firmwares = {"j0": DamiaoFirmware(1, 0x11, DM4310), "j1": DamiaoFirmware(2, 0x12, wrong)}
    motors = {
        "j0": {"id": 1, "reply_id": 0x11, "model": "DM4310"},
        "j1": {"id": 2, "reply_id": 0x12, "model": "DM4310"},
    }
    rig = rigs("damiao", firmwares, motors)
    with pytest.raises(HardwareError, match=r"j1 \(id 0x2\): VMAX is 45 on the motor but 30 in the config"):
        rig.driver.on_configure()
    assert rig.driver.link.bus is None  # the bus is released again
    assert not any(fw.enabled for fw in rig.firmwares)


def test_damiao_range_override_in_config_matches_the_motor(rigs: Any) -> None:
    firmwares = {"j0": DamiaoFirmware(1, 0x11, MitRanges(12.5, 45.0, 10.0))}
    motors = {"j0": {"id": 1, "reply_id": 0x11, "model": "DM4310", "ranges": {"v_max": 45.0}}}
    rig = rigs("damiao", firmwares, motors)
    rig.start()
    assert rig.firmwares[0].enabled


def test_damiao_not_in_mit_mode_is_refused(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1)
    rig.firmwares[0].registers[reg.CTRL_MODE] = reg.CTRL_MODE_POS_VEL
    with pytest.raises(HardwareError, match=r"CTRL_MODE is 2, not MIT"):
        rig.driver.on_configure()


def test_motors_that_do_not_answer_are_listed(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=3)
    rig.firmwares[0].silent = True
    rig.firmwares[2].silent = True
    with pytest.raises(HardwareError, match=r"did not answer register reads: j0 \(id 0x1, reply 0x11\), j2 \(id 0x3"):
        rig.driver.on_configure()


def test_tmotor_silent_motor_is_listed_at_startup(rigs: Any) -> None:
    firmwares = {"a": TMotorFirmware(1, AK80_9), "b": TMotorFirmware(2, AK80_9)}
    rig = rigs("tmotor", firmwares, {"a": {"id": 1, "model": "AK80-9"}, "b": {"id": 2, "model": "AK80-9"}})
    firmwares["b"].silent = True
    with pytest.raises(HardwareError, match=r"motors did not answer on virtual:mit-\w+: b \(id 0x2, reply 0x0\)"):
        rig.driver.on_configure()


# ---- the cycle -------------------------------------------------------------------------------------------------


def test_command_frames_carry_the_quantised_command(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.start()
    c = rig.command
    c.position[:] = [0.1, -0.25]
    c.velocity[:] = [0.2, -1.5]
    c.kp[:] = [30.0, 12.3]
    c.kd[:] = [1.0, 0.77]
    c.effort[:] = [0.5, -2.2]
    rig.cycle()
    r = DM4310
    for k, fw in enumerate(rig.firmwares):
        got = fw.command
        assert got.p == quantize(c.position[k], -r.p_max, r.p_max, 16)
        assert got.v == quantize(c.velocity[k], -r.v_max, r.v_max, 12)
        assert got.kp == quantize(c.kp[k], 0.0, r.kp_max, 12)
        assert got.kd == quantize(c.kd[k], 0.0, r.kd_max, 12)
        assert got.t == quantize(c.effort[k], -r.t_max, r.t_max, 12)


def test_out_of_range_commands_saturate_at_the_range(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1)
    rig.start()
    rig.command.position[:] = 20.0
    rig.command.effort[:] = -99.0
    rig.command.kp[:] = 900.0
    rig.cycle()
    got = rig.firmwares[0].command
    assert (got.p, got.t, got.kp) == (12.5, -10.0, 500.0)


def test_missing_reply_reports_stale_for_that_motor_only(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.start()
    rig.hold()
    rig.cycle(5)
    assert rig.state.fresh.all()
    last = rig.state.position.copy()
    rig.firmwares[1].silent = True
    rig.cycle()
    assert rig.state.fresh.tolist() == [True, False]
    assert rig.state.position[1] == last[1]  # the last known value, marked not fresh
    rig.firmwares[1].silent = False
    rig.cycle()
    assert rig.state.fresh.all()


def test_newest_reply_per_motor_wins(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1)
    rig.start()
    rig.hold()
    rig.cycle()
    flavour = rig.driver.flavour
    for p in (0.5, 0.7):
        rig.inject(flavour.encode_reply(1, 0x11, p, 0.0, 0.0, DM4310, enabled=True, fault=0, t_mos=30, t_rotor=40))
    rig.driver.read(rig.t, DT, rig.state)
    assert rig.state.position[0] == pytest.approx(0.7, abs=p_lsb(DM4310))
    assert rig.state.temperature[0] == 40.0  # the hotter of MOS and rotor


@pytest.mark.parametrize("code", [0x5, 0x8, 0x9, 0xA, 0xB, 0xC, 0xE])
def test_damiao_status_nibble_faults_become_fault_codes(rigs: Any, code: int) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.start()
    rig.hold()
    rig.cycle(3)
    rig.firmwares[0].inject_fault(code)
    rig.cycle()
    assert rig.state.fault.tolist() == [code, 0]
    assert rig.driver.describe_fault(code).startswith(f"damiao fault {code:#x}: ")
    assert rig.driver.describe_fault(code) != f"damiao fault {code:#x}: unknown fault 0x{code:X}"


def test_damiao_watchdog_fires_when_commands_stop(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1, timeout_ms=10)
    rig.start()
    rig.hold()
    rig.cycle(5)
    for _ in range(20):  # the host stops writing; only the emulator's time goes on
        rig.now += DT
        rig.emulator.service(rig.now)
    rig.cycle()
    assert rig.state.fault[0] == 0xD
    assert "communication lost" in rig.driver.describe_fault(0xD)


def test_reboot_is_a_fault_and_reset_never_re_enables(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.start()
    rig.hold()
    rig.cycle(3)
    rig.firmwares[1].reboot()
    rig.cycle()
    assert rig.state.fault.tolist() == [0, FAULT_DISABLED]
    assert "enable it explicitly" in rig.driver.describe_fault(FAULT_DISABLED)
    rig.driver.clear_faults()  # operator reset
    rig.cycle(20)
    assert not rig.firmwares[1].enabled
    assert rig.state.fault.tolist() == [0, FAULT_DISABLED]
    assert rig.driver.enable("j1") == ["j1"]  # the explicit operator command
    rig.cycle()
    assert rig.firmwares[1].enabled and rig.state.fault.tolist() == [0, 0]


def test_comm_lost_is_cleared_by_reset_but_the_motor_stays_disabled(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1)
    rig.start()
    rig.hold()
    rig.cycle()
    rig.firmwares[0].inject_fault(0xD)
    rig.cycle()
    assert rig.state.fault[0] == 0xD
    with pytest.raises(HardwareError, match="reset first"):
        rig.driver.enable("j0")
    rig.driver.clear_faults()
    rig.cycle(3)
    fw = rig.firmwares[0]
    assert fw.fault == 0 and not fw.enabled  # cleared (FB), not re-enabled
    assert rig.state.fault[0] == FAULT_DISABLED


def test_fault_at_startup_is_reported_and_that_motor_not_enabled(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.firmwares[0].inject_fault(0xD)  # latched from an earlier session
    rig.start()
    assert not rig.firmwares[0].enabled and rig.firmwares[1].enabled
    assert rig.state.fault.tolist() == [0xD, 0]
    assert any("j0: not enabled" in msg for _, msg in rig.events)


def test_garbage_frames_are_counted_by_kind_and_reported_rate_limited(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2, event_interval=0.5)
    rig.start()
    rig.hold()
    rig.cycle()
    good = rig.driver.flavour.encode_reply(1, 0x11, 0.3, 0.0, 0.0, DM4310, enabled=True, fault=0, t_mos=1, t_rotor=1)

    def variant(**changes: Any) -> can.Message:
        fields = {"arbitration_id": good.arbitration_id, "data": bytes(good.data), "is_extended_id": False}
        fields.update(changes)
        return can.Message(**fields)

    garbage = [
        variant(arbitration_id=0x123),  # nobody's id
        variant(data=bytes(good.data[:5])),  # wrong DLC
        variant(data=bytes([0x13]) + bytes(good.data[1:])),  # status ok, motor nibble 3: not on this reply id
        variant(data=bytes([0x31]) + bytes(good.data[1:])),  # status nibble 3 does not exist: corrupted
        variant(is_extended_id=True),
        variant(is_remote_frame=True, data=b""),
    ]
    for _ in range(3):
        for msg in garbage:
            rig.inject(msg)
        rig.cycle()
        assert rig.state.fresh.all()  # the motors' own replies still count
    totals = rig.driver.bad_frames.totals
    assert totals == {
        "unknown id": 3,
        "wrong length": 3,
        "unexpected motor id": 3,
        "corrupted": 3,
        "unexpected frame type": 6,
    }
    warnings = [msg for level, msg in rig.events if level == "warning" and "ignored CAN frames" in msg]
    assert len(warnings) == 1  # three cycles within event_interval: one summary
    assert "1 unknown id (last id 0x123)" in warnings[0]
    rig.cycle(500)  # the interval passes: the held-back counts come out in one more event
    warnings = [msg for level, msg in rig.events if level == "warning" and "ignored CAN frames" in msg]
    assert len(warnings) == 2 and "2 unknown id" in warnings[1]


def test_bus_off_is_reported_by_health_and_reset_reopens(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1)
    rig.start()
    rig.hold()
    rig.cycle()
    assert rig.driver.health() is None
    rig.inject(can.Message(arbitration_id=0x040, is_error_frame=True, data=bytes(8)))
    rig.cycle()
    assert rig.driver.health() == "bus off"
    old_bus = rig.driver.link.bus
    rig.driver.clear_faults()
    assert rig.driver.health() is None and rig.driver.link.bus is not old_bus
    rig.cycle(2)
    assert rig.state.fresh.all()  # traffic flows on the reopened bus


def test_bus_recovery_none_only_clears_the_latch(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=1, bus_recovery="none")
    rig.start()
    bus = rig.driver.link.bus
    rig.inject(can.Message(arbitration_id=0x040, is_error_frame=True, data=bytes(8)))
    rig.hold()
    rig.cycle()
    assert rig.driver.health() == "bus off"
    rig.driver.clear_faults()
    assert rig.driver.health() is None and rig.driver.link.bus is bus


def test_full_send_queue_surfaces_through_health(rigs: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    rig = damiao_rig(rigs, n=2, send_failure_cycles=3)
    rig.start()
    rig.hold()
    rig.cycle()

    def full(msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("Failed to transmit: No buffer space available", 105)

    monkeypatch.setattr(rig.driver.link.bus, "send", full)
    rig.cycle(2)
    assert rig.driver.health() is None  # a short burst is tolerated (the stale check covers the motors)
    rig.cycle()
    assert rig.driver.health() == "send buffer full for 3 cycles (6 frames lost)"
    assert rig.driver.statistics["send_failures"] == 6


def test_set_zero_rezeroes_at_rest_and_keeps_the_motor_enabled(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.start()
    rig.hold(kp=50.0, kd=2.0)
    rig.cycle(5)
    assert all(fw.zero_offset == 0.0 for fw in rig.firmwares)
    rig.driver.set_zero("j1")  # between two cycles, as the engine applies operator requests
    fw = rig.firmwares[1]
    rig.driver.write(rig.t, DT, rig.command)  # this command still holds at the old-frame reading (0.6) ...
    rig.emulator.service(rig.now + DT)
    assert fw.enabled and fw.zero_offset == pytest.approx(0.6, abs=1e-3)
    assert fw.command.kp == 0.0 and fw.command.kd == 0.0  # ... so the motor got a zero-gain frame instead
    rig.now += DT
    rig.t += DT
    rig.driver.read(rig.t, DT, rig.state)
    assert abs(rig.state.position[1]) < 1e-3  # reads zero here now
    assert rig.state.fault.tolist() == [0, 0]  # the disabled replies in between are not a fault
    rig.hold(kp=50.0, kd=2.0)  # hold continues in the new frame
    rig.cycle(100)
    assert fw.enabled and abs(rig.plant.positions[1] - 0.6) < 1e-3  # the arm did not move
    assert fw.command.kp == quantize(50.0, 0.0, 500.0, 12)
    assert rig.firmwares[0].enabled and rig.firmwares[0].zero_offset == 0.0
    with pytest.raises(HardwareError, match="drives no joint 'j9'"):
        rig.driver.set_zero("j9")


def test_set_zero_whose_enable_is_not_sent_leaves_a_disabled_fault(rigs: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    rig = damiao_rig(rigs, n=1)
    rig.start()
    rig.hold()
    rig.cycle()
    real_send, calls = rig.driver.link.send, []

    def third_fails(msg: can.Message) -> bool:
        calls.append(msg)
        return len(calls) != 3 and real_send(msg)

    monkeypatch.setattr(rig.driver.link, "send", third_fails)
    with pytest.raises(HardwareError, match="set-zero interrupted after 2 of its frames"):
        rig.driver.set_zero("j0")
    monkeypatch.undo()
    rig.cycle(3)
    assert not rig.firmwares[0].enabled and rig.firmwares[0].zero_offset != 0.0
    assert rig.state.fault[0] == FAULT_DISABLED  # visible, and not re-enabled by anyone but the operator


def test_deactivate_disables_or_holds(rigs: Any) -> None:
    rig = damiao_rig(rigs, n=2)
    rig.start()
    rig.driver.on_deactivate()
    assert not any(fw.enabled for fw in rig.firmwares)
    held = damiao_rig(rigs, n=1, on_deactivate="hold")
    held.start()
    held.driver.on_deactivate()
    assert held.firmwares[0].enabled


# ---- T-Motor and MyActuator ----------------------------------------------------------------------------------


@pytest.mark.parametrize("short", [False, True])
def test_tmotor_replies_six_and_eight_bytes(rigs: Any, short: bool) -> None:
    fw = TMotorFirmware(3, AK80_9, short_replies=short)
    rig = rigs("tmotor", {"a": fw}, {"a": {"id": 3, "model": "AK80-9"}}, positions=[-0.4])
    rig.driver.on_configure()
    assert not fw.enabled  # the zero-gain status request does not switch it on
    rig.driver.read(0.0, DT, rig.state)
    assert rig.state.position[0] == pytest.approx(-0.4, abs=p_lsb(AK80_9))
    rig.driver.on_activate()
    assert fw.enabled
    rig.hold()
    rig.cycle(3)
    assert rig.state.fresh.all()
    if short:
        assert np.isnan(rig.state.temperature[0])
    else:
        assert rig.state.temperature[0] == pytest.approx(25.0, abs=1.0)
        fw.inject_fault(2)
        rig.cycle()
        assert rig.state.fault[0] == 2
        assert rig.driver.describe_fault(2) == "tmotor fault 0x2: over-current"


def test_tmotor_has_no_clear_frame_and_says_so(rigs: Any) -> None:
    fw = TMotorFirmware(1, AK80_9)
    rig = rigs("tmotor", {"a": fw}, {"a": {"id": 1, "model": "AK80-9"}})
    rig.start()
    fw.inject_fault(1)
    rig.hold()
    rig.cycle()
    rig.driver.clear_faults()
    assert any("no clear-error frame" in msg for _, msg in rig.events)
    rig.cycle()
    assert rig.state.fault[0] == 1  # still reported by the drive: the joint stays faulted


def test_myactuator_motion_mode_ids_status_poll_and_no_zero(rigs: Any) -> None:
    firmwares = {"a": MyActuatorFirmware(1, MOTION), "b": MyActuatorFirmware(2, MOTION)}
    motors = {"a": {"id": 1, "model": "motion_mode"}, "b": {"id": 2, "model": "motion_mode"}}
    rig = rigs("myactuator", firmwares, motors, positions=[0.2, -0.2], status_poll_ms=10)
    rig.start()
    np.testing.assert_allclose(rig.state.position, [0.2, -0.2], atol=p_lsb(MOTION))
    rig.hold()
    rig.cycle(20)
    assert rig.state.fresh.all() and not rig.state.fault.any()
    assert not np.isnan(rig.state.temperature).any()  # from the status polls
    firmwares["b"].inject_fault(0x0010)
    rig.cycle(10)  # one status poll per motor within 10 ms
    assert rig.state.fault.tolist() == [0, 0x0010]
    assert rig.driver.describe_fault(0x0010) == "myactuator error flags 0x0010: over-current"
    with pytest.raises(HardwareError, match="no set-zero frame"):
        rig.driver.set_zero("a")
    rig.driver.on_deactivate()
    rig.emulator.service(rig.now + DT)  # nothing to wait for: motion replies do not say "disabled"
    assert not any(fw.enabled for fw in firmwares.values())  # native motor-off
    assert rig.driver.bad_frames.total == 0  # the motor-off acknowledgements are not garbage


# ---- config review -------------------------------------------------------------------------------------------


def review(joints: list[str], **raw: Any) -> list[str]:
    base = {"bus": {"interface": "virtual", "channel": "x"}, "flavour": "damiao"}
    params = MitCanParams.model_validate({**base, **raw})
    return [f"{f.level}: {f.message}" for f in MitCanDriver.review(params, joints, RATE)]


def test_review_accepts_a_good_config() -> None:
    motors = {"a": {"id": 1, "reply_id": 0x11, "model": "DM8009"}, "b": {"id": 2, "reply_id": 0x12, "model": "DM4340"}}
    assert review(["a", "b"], motors=motors) == []


def test_review_reports_every_reason() -> None:
    motors = {
        "a": {"id": 1, "reply_id": 0x02, "model": "DM4310"},  # reply id = b's command id
        "b": {"id": 2, "model": "DM9999"},  # unknown model
        "c": {"id": 1, "reply_id": 0x10, "model": "DM4310"},  # duplicate command id
        "d": {"id": 0x11, "reply_id": 0x10, "model": "DM4310"},  # same reply id and low nibble as c
        "e": {"id": 5, "model": "DM4310"},  # no such joint
    }
    found = review(["a", "b", "c", "d", "f"], motors=motors, timeout_ms=1.0)
    assert "error: no motor configured for joints ['f']" in found
    assert "error: motors configured for joints this component does not drive: ['e']" in found
    assert any(f.startswith("error: b: unknown damiao model 'DM9999'; known: [") for f in found)
    assert "error: c: motor id 0x1 is also used by a" in found
    assert "error: a: reply id 0x2 collides with the command id of b" not in found  # b was not wired (bad model)
    assert any(f.startswith("error: d: shares reply id 0x10 with c") for f in found)
    assert "error: timeout_ms 1 is below two cycles (2 ms)" in found


def test_review_reply_collision_and_flavour_specific_keys() -> None:
    motors = {"a": {"id": 1, "reply_id": 0x02, "model": "DM4310"}, "b": {"id": 2, "model": "DM4310"}}
    assert "error: a: reply id 0x2 collides with the command id of b" in review(["a", "b"], motors=motors)
    tm = {"a": {"id": 1, "model": "AK80-9", "reply_id": 5}}
    found = review(["a"], flavour="tmotor", motors=tm, timeout_ms=50, status_poll_ms=10)
    assert "error: a: reply_id applies to damiao only (tmotor derives it from the id)" in found
    assert "error: timeout_ms: tmotor has no CAN timeout register (damiao only)" in found
    assert "error: status_poll_ms: applies to myactuator only (tmotor replies carry the status)" in found
    # T-Motor replies on the master id: a motor whose id equals it collides
    assert "error: a: reply id 0x0 collides with the command id of a" in review(
        ["a"], flavour="tmotor", motors={"a": {"id": 0, "model": "AK80-9"}}
    )


def test_review_warns_about_a_disabled_watchdog_and_hold() -> None:
    motors = {"a": {"id": 1, "reply_id": 0x11, "model": "DM4310"}}
    assert review(["a"], motors=motors, timeout_ms=0) == [
        "warning: timeout_ms 0 disables the Damiao watchdog: a dead host leaves motors running"
    ]
    assert review(["a"], motors=motors, on_deactivate="hold") == [
        "warning: on_deactivate: hold lasts only until the Damiao watchdog disables the motors"
    ]


def test_bus_usage_counts_frames_and_lists_every_id() -> None:
    base = {"bus": {"interface": "virtual", "channel": "x"}}
    dm = MitCanParams.model_validate(
        {**base, "flavour": "damiao", "motors": {"a": {"id": 1, "reply_id": 0x11, "model": "DM4310"}}}
    )
    (usage,) = MitCanDriver.bus_usage(dm, ["a"], RATE)
    assert (usage.bus, usage.bits_per_second, usage.capacity, usage.ids) == ("virtual:x", 270_000, 1e6, {1, 0x11})
    ma = MitCanParams.model_validate(
        {**base, "flavour": "myactuator", "motors": {"a": {"id": 3, "model": "motion_mode"}}, "status_poll_ms": 10}
    )
    (usage,) = MitCanDriver.bus_usage(ma, ["a"], RATE)
    assert usage.bits_per_second == 270_000 + 2 * 100 * 135  # status request and reply at 100 Hz
    assert usage.ids == {0x403, 0x503, 0x143, 0x243}


def test_driver_refuses_bad_params_at_construction() -> None:
    context = HardwareContext("x", ("a",), Path("."), RATE, "sim", lambda level, msg: None)
    params = MitCanParams.model_validate(
        {
            "bus": {"interface": "virtual", "channel": "x"},
            "flavour": "damiao",
            "motors": {"b": {"id": 1, "model": "DM4310"}},
        }
    )
    with pytest.raises(HardwareError, match=r"no motor configured for joints \['a'\]"):
        MitCanDriver(context, params)


# ---- several buses in one engine ------------------------------------------------------------------------------


class TwoBusRobot:
    """Two mit_can components (Damiao on one virtual bus, T-Motor on another) run by the engine in lockstep."""

    def __init__(self, write_config: Any) -> None:
        left, right = f"left-{uuid.uuid4().hex[:8]}", f"right-{uuid.uuid4().hex[:8]}"

        def hw(channel: str, flavour: str, motors: dict[str, Any]) -> dict[str, Any]:
            return {
                "driver": "mit_can",
                "params": {
                    "bus": {"interface": "virtual", "channel": channel},
                    "flavour": flavour,
                    "motors": motors,
                    "reply_timeout_ms": 50,
                },
                "joints": {j: {} for j in motors},
            }

        config = {
            "robot": {"name": "canarm"},
            "update_rate": 500,
            "clock": {"source": "sim", "real_time_factor": 0},
            "hardware": {
                "left": hw(
                    left,
                    "damiao",
                    {
                        "a": {"id": 1, "reply_id": 0x11, "model": "DM4310"},
                        "b": {"id": 2, "reply_id": 0x12, "model": "DM4310"},
                    },
                ),
                "right": hw(right, "tmotor", {"c": {"id": 1, "model": "AK80-9"}}),
            },
            "joints": {j: joint() for j in "abc"},
            "controllers": {
                "fwd": {"type": "forward_command", "params": {"joints": ["a", "b", "c"], "command_timeout": 0.5}}
            },
        }
        self.engine = Engine(load_config(write_config(config)))
        self.left_fw = [DamiaoFirmware(1, 0x11, DM4310), DamiaoFirmware(2, 0x12, DM4310)]
        self.right_fw = [TMotorFirmware(1, AK80_9)]
        self.buses = [can.Bus(interface="virtual", channel=ch) for ch in (left, right)]
        self.emulators = [
            Emulator(self.buses[0], self.left_fw, MotorPlant(2, inertia=0.05, damping=0.05, positions=[0.2, -0.3])),
            Emulator(self.buses[1], self.right_fw, MotorPlant(1, inertia=0.05, damping=0.05, positions=[0.4])),
        ]
        self.now = 0.0
        for slot in self.engine.hardware:
            slot.component.serve_while_waiting = self.serve_while_waiting  # type: ignore[attr-defined]

    def serve_while_waiting(self) -> None:
        self.now += 1e-4
        for emulator in self.emulators:
            emulator.service(self.now)

    def run(self, cycles: int, fwd: list[float] | None = None) -> None:
        for _ in range(cycles):
            if fwd is not None:
                self.engine.manager.records["fwd"].instance.accept({"values": fwd})
            self.engine.run_cycles(1)
            self.now += self.engine.period
            for emulator in self.emulators:
                emulator.service(self.now)

    def plant_positions(self) -> list[float]:
        return [*self.emulators[0].plant.positions, *self.emulators[1].plant.positions]

    def faults(self) -> list[str | None]:
        return [j["fault"] for j in self.engine.status()["joints"]]

    def close(self) -> None:
        if self.engine.started:
            self.engine.stop()
        for bus in self.buses:
            bus.shutdown()


@pytest.fixture
def two_bus(write_config: Any) -> Any:
    robot = TwoBusRobot(write_config)
    yield robot
    robot.close()


def test_engine_serves_two_buses_in_the_same_cycle(two_bus: TwoBusRobot) -> None:
    engine = two_bus.engine
    engine.start()
    np.testing.assert_allclose(engine.state.position, [0.2, -0.3, 0.4], atol=p_lsb(DM4310))
    assert all(fw.enabled for fw in two_bus.left_fw + two_bus.right_fw)
    two_bus.run(100)
    np.testing.assert_allclose(two_bus.plant_positions(), [0.2, -0.3, 0.4], atol=2e-3)  # held where it started
    assert engine.status()["mode"] == "hold"
    assert engine.switch(["fwd"], []).ok
    two_bus.run(750, fwd=[0.5, 0.1, -0.2])
    np.testing.assert_allclose(two_bus.plant_positions(), [0.5, 0.1, -0.2], atol=5e-3)
    np.testing.assert_allclose(engine.state.position, two_bus.plant_positions(), atol=1e-3)
    assert all(s.component.bad_frames.total == 0 for s in engine.hardware)  # type: ignore[attr-defined]
    engine.stop()
    for emulator in two_bus.emulators:
        emulator.service(two_bus.now + 0.01)
    assert not any(fw.enabled for fw in two_bus.left_fw + two_bus.right_fw)


def test_engine_faults_only_the_joints_of_the_bus_that_fails(two_bus: TwoBusRobot) -> None:
    engine = two_bus.engine
    engine.start()
    two_bus.run(5)
    two_bus.right_fw[0].silent = True
    stale = engine.loaded.config.safety.stale_feedback_cycles
    two_bus.run(stale)  # the first of these cycles still reads the reply that was on the wire
    assert two_bus.faults() == [None, None, None]
    two_bus.run(1)
    assert two_bus.faults() == [None, None, f"no feedback for {stale} cycles"]
    two_bus.left_fw[0].inject_fault(0x8)
    two_bus.run(2)
    assert two_bus.faults()[0] == "left: damiao fault 0x8: over-voltage"
    assert two_bus.faults()[1] is None


def test_engine_reset_clears_the_drive_fault_but_only_enable_re_arms(two_bus: TwoBusRobot) -> None:
    engine = two_bus.engine
    engine.start()
    two_bus.run(5)
    two_bus.left_fw[1].inject_fault(0xA)
    two_bus.run(2)
    assert two_bus.faults()[1] == "left: damiao fault 0xa: over-current"
    assert "reset first" in engine.enable(["b"])["error"]  # the drive still reports its error
    reset = engine.submit(engine.reset)  # the operator's reset sends clear-error; it never enables a motor
    two_bus.run(20)
    assert reset.result(timeout=0)["cleared"] == ["b: left: damiao fault 0xa: over-current"]  # once confirmed
    fw = two_bus.left_fw[1]
    assert fw.fault == 0 and not fw.enabled
    assert two_bus.faults()[1] is not None and "not re-enabled automatically" in two_bus.faults()[1]
    assert two_bus.left_fw[0].enabled and two_bus.right_fw[0].enabled
    sagged = engine.state.position[1]
    assert engine.enable(["b"]) == {"enabled": ["b"]}  # the explicit operator command
    two_bus.run(5)
    assert fw.enabled
    assert two_bus.faults() == [None, None, None]
    assert any("b: drive enabled, holding where it is" in e.message for e in engine.events.drain())
    two_bus.run(200)
    assert abs(engine.state.position[1] - sagged) < 5e-3  # held where it was re-enabled: no swing back
    assert [j["mode"] for j in engine.status()["joints"]] == ["hold"] * 3


def test_engine_set_zero_on_can_motors_does_not_move_the_arm(two_bus: TwoBusRobot) -> None:
    engine = two_bus.engine
    engine.start()
    two_bus.run(50)
    before = two_bus.plant_positions()
    assert engine.set_zero("b") == {"joint": "b"}
    assert engine.set_zero("c") == {"joint": "c"}
    travel = np.zeros(3)
    for _ in range(400):
        two_bus.run(1)
        travel = np.maximum(travel, np.abs(np.subtract(two_bus.plant_positions(), before)))
    # No pull toward the old target (0.3 rad away); what remains is the creep of the supervisor's damping-only
    # settle (kp = 0, v = 0): 0 rad/s is not representable, the drive gets −v_max/4095 (≈ 6 mrad over 0.5 s).
    assert travel.max() < 1.5e-2
    np.testing.assert_allclose(engine.state.position, [before[0], 0.0, 0.0], atol=1.5e-2)  # the new zero, same creep
    assert two_bus.faults() == [None, None, None]
    assert [j["mode"] for j in engine.status()["joints"]] == ["hold"] * 3
    assert two_bus.left_fw[1].enabled and two_bus.right_fw[0].enabled
