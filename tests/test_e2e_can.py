"""End to end over CAN without kernel CAN: `hild emulate` and `hild run` as two processes on 127.0.0.1 (arm6, and
arm6 with its gripper).

The emulator hosts the bus (python-can-remote, ``--serve-remote``) with Damiao firmware models and the MuJoCo twin
behind them; the daemon runs configs/arm6_can_loopback.yaml (its bus channel patched to a free port) on the wall
clock. A trajectory goes in over Zenoh; the emulator's control channel reports where the arm really is. Every wait
is for a condition with a generous timeout; both processes are always killed.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.can.emulator.runtime import request
from hild.bench.daemon import CanProcesses
from hild.client import HildError
from hild.motion.reference import OFFSETS, standard_trajectory
from tests.helpers import wait_for
from tests.test_e2e import Recorder


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[CanProcesses]:
    rigs = CanProcesses(tmp_path)
    try:
        yield rigs
    finally:
        rigs.close()


def test_trajectory_over_zenoh_drives_the_emulated_arm(rig: CanProcesses) -> None:
    with rig.start_daemon() as arm:
        states = Recorder()
        arm.subscribe("joint_states", states)
        wait_for(lambda: states.last() is not None, 10.0, "joint_states")

        def measured() -> np.ndarray:
            return np.array(states.last()["position"])  # type: ignore[index]

        def agree(tolerance: float) -> bool:
            """The daemon's joint states and the emulator's true joint positions agree (the arm is at rest)."""
            return bool(np.abs(measured() - rig.positions()).max() < tolerance)

        # Start-up: every drive enabled and healthy, brakes released, the daemon holding where the arm is.
        status = rig.status()
        assert all(j["enabled"] and j["fault"] == 0 and not j["braked"] for j in status["joints"]), rig.logs()
        assert arm.status()["mode"] == "hold", rig.logs()
        # 1 feedback LSB (0.19 / 0.38 mrad) plus a little motion between the two samples.
        wait_for(lambda: agree(1e-3), 15.0, "joint_states to match the emulator at rest")
        home = measured()

        arm.switch(activate=["joint_trajectory"])
        goal = standard_trajectory(list(states.last()["name"]), home.tolist())  # type: ignore[index]
        excursion = np.zeros(6)
        with arm.send_goal("joint_trajectory", goal) as handle:
            deadline = time.monotonic() + 60.0
            while True:
                excursion = np.maximum(excursion, np.abs(rig.positions() - home))
                try:
                    result = handle.wait(0.1)
                    break
                except HildError:
                    assert time.monotonic() < deadline, f"no result after 60 s\n{rig.logs()}"
        assert result["status"] == "succeeded", f"{result}\n{rig.logs()}"
        # The emulated arm itself went through the motion (sampled every ~0.1 s, so a little short of the peaks).
        assert (excursion > 0.7 * np.abs(OFFSETS).max(axis=0)).all(), excursion

        # Back home: the daemon's view and the emulator's truth agree, and both are home.
        wait_for(lambda: agree(1e-3), 15.0, "joint_states to match the emulator after the trajectory")
        assert np.abs(rig.positions() - home).max() < 0.01
        status = rig.status()
        assert all(j["enabled"] and j["fault"] == 0 for j in status["joints"]), status["joints"]
        (bus,) = status["buses"]
        assert bus["unknown"] == bus["garbled"] == bus["error_frames"] == 0
        assert bus["received"] > 6 * 500 * 2  # seconds of 500 Hz commands to 6 motors…
        assert bus["sent"] == bus["handled"] == bus["received"]  # …each answered
        assert arm.status()["ok"], rig.logs()

        # Run-time fault injection: the drive latches it, the daemon names it on that joint only.
        assert request(rig.control, {"op": "fault", "joint": "wrist_3", "code": 0x8})["ok"]

        def faults() -> list[str | None]:
            return [j["fault"] for j in arm.status()["joints"]]

        wait_for(lambda: faults()[5] is not None, 10.0, "the injected fault to reach the daemon")
        assert "damiao fault 0x8: over-voltage" in faults()[5] and faults()[:5] == [None] * 5, faults()

    # Ctrl-C: the daemon holds, disables the drives and exits; the emulator sees them disabled.
    assert rig.run is not None
    assert rig.run.stop(30, signal.SIGINT) == 0, rig.logs()
    wait_for(lambda: not any(j["enabled"] for j in rig.status()["joints"]), 10.0, "the drives to be disabled")
    assert request(rig.control, {"op": "stop"}) == {"ok": True}
    assert rig.emulator.wait(30) == 0, rig.logs()


class GripperProcesses(CanProcesses):
    """The same rig on configs/arm6_gripper_can_loopback.yaml: seven drives, the DM4310 gripper motor among them."""

    CONFIG = "arm6_gripper_can_loopback.yaml"
    FILES = ("arm6_gripper.xml",)


def test_the_gripper_motor_moves_the_finger_over_the_loopback_bus(tmp_path: Path) -> None:
    """The loopback variant over CAN-FD: the DM4310 answers and a command in metres turns it through 23.8 rad/m."""
    rig = GripperProcesses(tmp_path)
    try:

        def gripper() -> dict[str, Any]:
            (drive,) = [j for j in rig.drives() if j["name"] == "gripper"]
            return drive

        with rig.start_daemon() as arm:
            assert all(j["enabled"] and j["fault"] == 0 for j in rig.drives()), rig.logs()
            assert gripper()["actuator_position"] == pytest.approx(-1.0472, abs=2e-3)  # open: 0.044 m
            arm.switch(activate=["gripper_position"])

            def at(opening: float) -> bool:
                arm.put("gripper_position", {"values": [opening]})  # a stream: the controller times out in 0.5 s
                return bool(abs(gripper()["position"] - opening) < 2e-4)

            wait_for(lambda: at(0.03), 20.0, "the finger at 3 cm", logs=rig.logs, every=0.05)
            assert gripper()["actuator_position"] == pytest.approx(-0.03 * 1.0472 / 0.044, abs=5e-3)
            assert arm.status()["ok"], rig.logs()
        assert rig.run is not None
        assert rig.run.stop(30, signal.SIGINT) == 0, rig.logs()
    finally:
        rig.close()
