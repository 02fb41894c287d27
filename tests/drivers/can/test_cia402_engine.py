"""cia402 in the real engine against the emulated CiA 402 drives, in lockstep: start holds without a jump, a
move_to goal arrives in CSP, an EMCY fault latches with its name and reset + enable bring the joint back, stop
ends in a confirmed Switch On Disabled."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import yaml

from drivers.can.cia402.driver import Cia402Driver
from drivers.can.emulator import MotorPlant
from drivers.can.emulator.runtime import build_firmware
from hild.config.loader import load_config
from tests.drivers.can.test_cia402_config import robot
from tests.faults.rigs import JTC, EmulatedBusRig

START = (0.2, -0.3)


class EngineRig(EmulatedBusRig):
    def __init__(self, mode: str = "csp", homing: dict[str, Any] | None = None) -> None:
        path = self._workspace("cia402") / "robot.yaml"
        config = robot(2, mode=mode)
        if homing is not None:
            config["hardware"]["arm"]["params"]["drives"]["j1"]["homing"] = homing
        config["hardware"]["arm"]["params"]["bus"]["channel"] = self.channel
        config["controllers"] = {
            JTC: {
                "type": "joint_trajectory",
                "params": {
                    "joints": ["j1", "j2"],
                    "command_interfaces": ["position"],
                    "constraints": {
                        "stopped_velocity_tolerance": 0.05,
                        "joints": {"j1": {"goal": 0.01}, "j2": {"goal": 0.01}},
                    },
                },
            }
        }
        config["safety"]["stale_feedback_cycles"] = 10
        path.write_text(yaml.safe_dump(config, sort_keys=False))
        loaded = load_config(path)
        self.firmwares = build_firmware(loaded.driver_params["arm"], ["j1", "j2"], loaded.directory)  # type: ignore[arg-type]
        self.plant = MotorPlant(2, inertia=0.05, damping=0.05, positions=START)
        self._start(loaded, self.firmwares, self.plant)
        assert isinstance(self.driver, Cia402Driver)


@pytest.fixture
def rig() -> Any:
    made = EngineRig()
    yield made
    made.close()


def test_start_holds_and_a_move_to_goal_arrives(rig: Any) -> None:
    assert all(fw.state == "OPERATION ENABLED" for fw in rig.firmwares)
    rig.seconds(0.3)
    np.testing.assert_allclose(rig.engine.state.position, START, atol=5e-3)  # held where it was: no jump
    assert not rig.any_fault()
    rig.switch([JTC])
    goal = rig.move([0.3, -0.2])
    result = rig.finish(goal)
    assert result.status == "succeeded", result
    np.testing.assert_allclose(rig.engine.state.position, [0.5, -0.5], atol=0.01)


def test_an_emcy_fault_latches_by_name_and_reset_then_enable_bring_it_back(rig: Any) -> None:
    rig.seconds(0.1)
    rig.firmwares[1].inject_fault(0x3210)
    rig.until(lambda: "j2" in rig.faulted(), 0.2, "j2 faulted")
    words = [e.message for _, e in rig.events if e.level == "error"]
    assert any("DC-link over-voltage (0x3210)" in w for w in words), words
    answer = rig.reset()
    assert not answer.get("error"), answer
    assert rig.firmwares[1].state == "SWITCH ON DISABLED"  # out of FAULT, not re-enabled by the reset
    answer = rig.enable()
    rig.seconds(0.1)
    assert rig.firmwares[1].state == "OPERATION ENABLED"
    assert not rig.any_fault()


def test_stop_ends_in_a_confirmed_switch_on_disabled(rig: Any) -> None:
    rig.seconds(0.1)
    rig.engine.stop()
    assert all(fw.state == "SWITCH ON DISABLED" for fw in rig.firmwares)


def test_a_silent_drive_faults_within_the_stale_bound(rig: Any) -> None:
    rig.seconds(0.1)
    rig.firmwares[0].silent = True
    cycles = rig.until(lambda: "j1" in rig.faulted(), 0.1, "j1 faulted")
    assert cycles <= 10 + 2  # safety.stale_feedback_cycles: a missing TPDO is stale the cycle it is missed
    assert "j2" not in rig.faulted()


def test_a_rebooted_drive_faults_and_is_not_re_enabled(rig: Any) -> None:
    rig.seconds(0.1)
    rig.firmwares[1].reboot()
    rig.until(lambda: "j2" in rig.faulted(), 0.3, "j2 faulted")
    words = [e.message for _, e in rig.events if e.level == "error"]
    assert any("left NMT OPERATIONAL" in w or "not OPERATION ENABLED" in w for w in words), words
    rig.seconds(0.2)
    assert rig.firmwares[1].state != "OPERATION ENABLED"


def test_home_runs_the_drives_own_homing_and_hold_takes_over_in_its_new_frame() -> None:
    rig = EngineRig(homing={"method": 37, "offset": 0.05})
    try:
        rig.seconds(0.1)
        reply = rig.request(lambda: rig.engine.home("j1"))
        assert reply.get("state") == "running", reply

        def entry() -> dict[str, Any]:
            return next(h for h in rig.engine.status()["homing"] if h["joint"] == "j1")

        rig.until(lambda: entry()["state"] != "running", 2.0, "the homing's end")
        assert entry()["state"] == "attained", entry()
        assert rig.firmwares[0].mode == 8  # back in CSP
        rig.seconds(1.2)  # past the engine's settle window
        assert rig.engine.state.position[0] == pytest.approx(0.05, abs=2e-3)  # the drive's new frame: home = offset
        assert rig.engine.state.position[1] == pytest.approx(START[1], abs=5e-3)  # the other joint held
        assert not rig.any_fault()
    finally:
        rig.close()


def test_in_cst_hold_keeps_the_arm_still_and_a_trajectory_arrives() -> None:
    """CST: the drive takes torque only; hild applies hold's and the trajectory's servo law on the torque path."""
    rig = EngineRig(mode="cst")
    try:
        assert all(fw.mode == 10 for fw in rig.firmwares)
        rig.seconds(0.5)
        np.testing.assert_allclose(rig.engine.state.position, START, atol=5e-3)  # held where it was: no jump
        assert not rig.any_fault()
        rig.switch([JTC])
        result = rig.finish(rig.move([0.3, -0.2]))
        assert result.status == "succeeded", result
        np.testing.assert_allclose(rig.engine.state.position, [0.5, -0.5], atol=0.01)
        assert not rig.any_fault()
    finally:
        rig.close()
