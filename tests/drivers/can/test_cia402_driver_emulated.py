"""cia402 against the emulated CiA 402 drives (``Cia402Firmware``) and a plant, on a virtual bus, in lockstep:
configure → activate → hold → move in CSP and CST → fault and reset → deactivate."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.can.cia402.driver import FAULT_STATE, Cia402Driver
from drivers.can.cia402.wiring import wire_drives
from drivers.can.emulator import Cia402Firmware, MotorPlant
from drivers.can.params import Cia402Params
from hild.hardware import HardwareContext
from tests.drivers.can.lockstep import LockstepRig, rig_factory

RATE = 500.0
DT = 1.0 / RATE
CONFIGS = Path(__file__).resolve().parents[3] / "configs"


class Rig(LockstepRig):
    def __init__(self, nodes: dict[str, int], *, positions: list[float] | None = None, **params: Any) -> None:
        super().__init__("cia402", tuple(nodes), RATE, wait_step=5e-4)
        raw = {
            "bus": {"interface": "virtual", **params.pop("bus", {}), "channel": self.channel},
            "eds": "cia402_generic.eds",
            "drives": {joint: {"node_id": node} for joint, node in nodes.items()},
            "reply_timeout_ms": 300,  # SDO answers under load; lockstep otherwise
            **params,
        }
        validated = Cia402Params.model_validate(raw)
        wiring, problems = wire_drives(validated, self.joints, CONFIGS)
        assert not problems
        n = len(nodes)
        self.attach(
            Cia402Driver(self.context("arm"), validated),
            [Cia402Firmware(w, seed=k) for k, w in enumerate(wiring)],
            MotorPlant(n, inertia=0.01, damping=0.05, positions=positions or [0.0] * n),
        )

    def context(self, name: str) -> HardwareContext:
        base = super().context(name)
        return HardwareContext(name, base.joints, CONFIGS, base.update_rate, base.clock_source, base.emit_event)

    def hold(self, kp: float = 0.0, kd: float = 0.0) -> None:
        super().hold(kp, kd)


rigs = rig_factory(Rig)


def test_start_holds_where_the_arm_is_then_moves_in_csp(rigs: Any) -> None:
    rig = rigs({"shoulder": 1, "elbow": 2}, positions=[0.4, -0.3])
    rig.start()
    assert all(fw.state == "OPERATION ENABLED" for fw in rig.firmwares)
    np.testing.assert_allclose(rig.state.position, [0.4, -0.3], atol=1e-4)
    rig.hold()
    rig.cycle(100)
    np.testing.assert_allclose(rig.state.position, [0.4, -0.3], atol=2e-3)  # no jump at enable
    assert rig.state.fresh.all() and not rig.state.fault.any()
    target = np.array([0.6, -0.1])
    start = rig.state.position.copy()
    for i in range(1, 251):  # a 0.5 s ramp, as a trajectory would stream it
        rig.command.position[:] = start + (target - start) * min(1.0, i / 200)
        rig.cycle()
    rig.cycle(100)
    np.testing.assert_allclose(rig.state.position, target, atol=5e-3)
    assert not rig.state.fault.any()
    assert rig.state.velocity == pytest.approx([0.0, 0.0], abs=0.05)


def test_cst_applies_the_effort_command(rigs: Any) -> None:
    rig = rigs({"wrist": 5}, mode="cst")
    rig.start()
    rig.hold()
    rig.command.effort[:] = 0.5
    rig.cycle(100)
    assert rig.firmwares[0].target_torque == round(0.5 * rig.driver.wiring[0].permille_per_nm)
    assert rig.state.position[0] > 0.05  # pushed by the torque
    assert rig.state.effort[0] == pytest.approx(0.5, abs=0.02)


def test_an_injected_fault_is_named_reset_confirms_and_enable_holds(rigs: Any) -> None:
    rig = rigs({"shoulder": 1, "elbow": 2})
    rig.start()
    rig.hold()
    rig.cycle(10)
    rig.firmwares[1].inject_fault(0x2310)
    rig.cycle(3)
    code = int(rig.state.fault[1])
    assert code & FAULT_STATE and code & 0xFFFF == 0x2310
    assert "continuous over-current (0x2310)" in rig.driver.describe_fault(code)
    rig.driver.clear_faults()
    for _ in range(200):
        if not rig.driver.confirming():
            break
        rig.cycle()
    assert not rig.driver.confirming() and rig.driver.persistent_errors() == {}
    assert rig.firmwares[1].state == "SWITCH ON DISABLED"  # out of FAULT, not re-enabled
    rig.driver.enable("elbow")
    rig.hold()
    rig.cycle(20)
    assert rig.firmwares[1].state == "OPERATION ENABLED" and not rig.state.fault.any()


def test_deactivate_ends_in_a_confirmed_switch_on_disabled(rigs: Any) -> None:
    rig = rigs({"shoulder": 1, "elbow": 2})
    rig.start()
    rig.hold()
    rig.cycle(10)
    rig.driver.on_deactivate()
    assert all(fw.state == "SWITCH ON DISABLED" for fw in rig.firmwares)
    assert not [msg for level, msg in rig.events if level == "error"]


def test_homing_method_37_against_the_emulated_drive(rigs: Any) -> None:
    rig = rigs({"shoulder": 1}, positions=[0.3], drives={"shoulder": {"node_id": 1, "homing": {"method": 37}}})
    rig.start()
    rig.hold()
    rig.cycle(5)
    rig.driver.start_homing("shoulder")
    outcome = None
    speeds = []
    for _ in range(500):
        rig.hold()  # as the engine does while a joint homes: hold follows the measured position
        rig.cycle()
        speeds.append(abs(float(rig.state.velocity[0])))
        outcome, detail = rig.driver.homing("shoulder")
        if outcome.value in ("attained", "failed"):
            break
    assert outcome is not None and outcome.value == "attained", detail
    for _ in range(10):
        rig.hold()
        rig.cycle()
        speeds.append(abs(float(rig.state.velocity[0])))
    assert max(speeds) < 0.5  # the home moved the position origin by 0.3 rad: no velocity spike from that jump
    assert rig.firmwares[0].mode == 8  # back in CSP
    assert rig.state.position[0] == pytest.approx(0.0, abs=1e-3)  # the current position became home (offset 0)
    rig.hold()
    rig.cycle(20)
    assert not rig.state.fault.any()


def test_csv_follows_the_velocity_command(rigs: Any) -> None:
    rig = rigs({"wrist": 5}, mode="csv")
    rig.start()
    assert sorted(rig.driver.COMMAND_FIELDS) == ["effort", "velocity"]
    rig.hold()
    rig.command.velocity[:] = 0.5
    rig.cycle(250)
    w = rig.driver.wiring[0]
    assert rig.firmwares[0].target_velocity == round(0.5 * w.velocity_per_rad_s)
    assert rig.state.velocity[0] == pytest.approx(0.5, abs=0.02)  # derived from the SYNC-latched positions
    assert not rig.state.fault.any()


def test_fd_layout_against_the_emulated_drive(rigs: Any) -> None:
    rig = rigs({"shoulder": 1}, positions=[0.1], bus={"fd": True})
    rig.start()
    rig.hold()
    rig.command.position[:] = 0.3
    speeds = []
    for _ in range(300):
        rig.cycle()
        speeds.append(float(rig.state.velocity[0]))
    assert max(speeds) > 0.5  # the drive's own velocity actual while it moves
    assert rig.state.position[0] == pytest.approx(0.3, abs=5e-3)
    assert rig.state.velocity[0] == pytest.approx(0.0, abs=0.05)  # 0x606C from the drive, in the one FD TPDO
    assert not rig.state.fault.any() and rig.state.fresh.all()
    assert rig.driver.statistics.get("ignored wrong length", 0) == 0
