"""End to end over CANopen without kernel CAN: `hild emulate` and `hild run` on configs/arm6_cia402_loopback.yaml as
two processes on 127.0.0.1 — six emulated CiA 402 drives (configs/cia402_generic.eds) with the arm6 twin behind them,
in cyclic synchronous position, hild producing SYNC.

What issue [cia402] asks of the loopback rig, in one run: start holds without a jump, a trajectory arrives, an EMCY
fault latches with its standard name and reset confirms it from the statusword (not re-enabled), enable brings the
drive back, `home` runs a drive's own homing and it returns to CSP, a drive that falls silent faults within the
stale bound, and Ctrl-C ends in a confirmed Switch On Disabled on every drive. Every wait is for a condition with a
generous timeout; both processes are always killed.
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
from hild.motion.reference import standard_trajectory
from tests.helpers import wait_for
from tests.test_e2e import Recorder

ENABLED = "OPERATION ENABLED"
DISABLED = "SWITCH ON DISABLED"


class Cia402Processes(CanProcesses):
    CONFIG = "arm6_cia402_loopback.yaml"
    FILES = ("arm6.xml", "cia402_generic.eds")
    SERVED = "ws://127.0.0.1:54702/"


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Cia402Processes]:
    rigs = Cia402Processes(tmp_path)
    try:
        yield rigs
    finally:
        rigs.close()


def run_trajectory(arm: Any, rig: CanProcesses, home: np.ndarray) -> None:
    """The standard trajectory (half size) from ``home``, to its end: succeeded, and the plant back at ``home``."""
    goal = standard_trajectory([j["name"] for j in arm.status()["joints"]], home.tolist(), scale=0.5)
    with arm.send_goal("joint_trajectory", goal) as handle:
        deadline = time.monotonic() + 60.0
        while True:
            try:
                result = handle.wait(0.2)
                break
            except HildError:
                assert time.monotonic() < deadline, f"no result after 60 s\n{rig.logs()}"
    assert result["status"] == "succeeded", f"{result}\n{rig.logs()}"
    wait_for(lambda: np.abs(rig.positions() - home).max() < 0.01, 15.0, "the arm back home")


def test_the_cia402_loopback_rig_runs_the_tour(rig: Cia402Processes) -> None:
    before = rig.positions()  # where the unpowered (braked) arm rests
    assert {d["cia402_state"] for d in rig.drives()} == {DISABLED}
    with rig.start_daemon() as arm:
        states = Recorder()
        arm.subscribe("joint_states", states)
        wait_for(lambda: states.last() is not None, 10.0, "joint_states")

        def measured() -> np.ndarray:
            return np.array(states.last()["position"])  # type: ignore[index]

        # Start: every drive in Operation Enabled (NMT operational, CSP), the daemon holding where the arm was.
        drives = rig.drives()
        assert all(d["cia402_state"] == ENABLED and d["nmt_state"] == 5 and d["mode"] == 8 for d in drives), drives
        assert arm.status()["mode"] == "hold", rig.logs()
        time.sleep(0.5)  # let a jump, if any, show in the plant
        assert np.abs(rig.positions() - before).max() < 2e-3, (rig.positions(), before)
        # The daemon's view is the plant's truth, to a count of the encoders (2^17 per revolution) and a little motion.
        wait_for(lambda: np.abs(measured() - rig.positions()).max() < 1e-3, 15.0, "joint_states to match the plant")
        home = measured()

        arm.switch(activate=["joint_trajectory"])
        # move_to within the goal tolerance (0.01 rad per joint: the config's constraints), checked on the plant.
        target = home + np.array([0.2, -0.15, 0.2, 0.3, -0.3, 0.4])
        result = arm.move_to("joint_trajectory", target.tolist(), timeout=60.0)
        assert result["status"] == "succeeded", f"{result}\n{rig.logs()}"
        assert np.abs(rig.positions() - target).max() < 0.01, (rig.positions(), target)
        run_trajectory(arm, rig, home)
        arm.switch(deactivate=["joint_trajectory"])

        def faults() -> list[str | None]:
            return [j["fault"] for j in arm.status()["joints"]]

        # An EMCY fault: latched by the drive, named by its standard CiA 402 name on that joint only.
        assert request(rig.control, {"op": "fault", "joint": "wrist_3", "code": 0x2310})["ok"]
        wait_for(lambda: faults()[5] is not None, 10.0, "the EMCY fault to reach the daemon")
        assert "continuous over-current (0x2310)" in str(faults()[5]) and faults()[:5] == [None] * 5, faults()
        # The emulated drive's supply is cleared (an operator power-cycling it); reset sends the fault-reset edge and
        # answers once the statusword left FAULT: Switch On Disabled, never re-enabled by the reset.
        assert request(rig.control, {"op": "clear", "joint": "wrist_3"})["ok"]
        arm.reset()
        assert rig.drives()[5]["cia402_state"] == DISABLED, rig.drives()[5]
        arm.call("enable", {"joints": ["wrist_3"]})
        wait_for(lambda: rig.drives()[5]["cia402_state"] == ENABLED, 10.0, "wrist_3 enabled again")
        wait_for(lambda: faults() == [None] * 6, 10.0, "every joint healthy again")

        # Homing (the drive's own, mode 6, method 37 here): `home` answers at once, the status says how it ends.
        assert arm.call("home", {"joint": "wrist_3"})["state"] == "running"

        def homing() -> dict[str, Any]:
            return next(h for h in arm.status()["homing"] if h["joint"] == "wrist_3")

        wait_for(lambda: homing()["state"] != "running", 15.0, "the homing's end")
        assert homing()["state"] == "attained", homing()
        assert rig.drives()[5]["mode"] == 8 and rig.drives()[5]["cia402_state"] == ENABLED  # back in CSP
        wait_for(lambda: abs(measured()[5]) < 2e-3, 10.0, "wrist_3 read at its new home (0)")
        assert faults() == [None] * 6, faults()

        # Silence (the transceiver cut: no TPDO, no heartbeat): the joint goes stale within the configured bound
        # (25 missed cycles and 0.2 s, plus a cycle; here also the wall time of two processes on a shared machine).
        assert request(rig.control, {"op": "set", "joint": "wrist_2", "silent": True})["ok"]
        started = time.monotonic()
        wait_for(lambda: faults()[4] is not None, 10.0, "the silent drive to fault")
        assert time.monotonic() - started < 2.0, time.monotonic() - started
        assert "stale" in str(faults()[4]) or "no feedback" in str(faults()[4]), faults()[4]
        assert request(rig.control, {"op": "set", "joint": "wrist_2", "silent": False})["ok"]

    # Ctrl-C: the daemon stops the drives and waits for their statuswords: every one in Switch On Disabled.
    assert rig.run is not None
    assert rig.run.stop(30, signal.SIGINT) == 0, rig.logs()
    drives = rig.drives()
    assert all(d["cia402_state"] == DISABLED or d["name"] == "wrist_2" for d in drives), drives
    assert request(rig.control, {"op": "stop"}) == {"ok": True}
    assert rig.emulator.wait(30) == 0, rig.logs()


class CstProcesses(Cia402Processes):
    """The same rig with the daemon's drives in cyclic synchronous torque: hild closes the servo law over the bus."""

    PATCHES = (("      mode: csp ", "      mode: cst "),)


def test_in_cst_the_arm_holds_and_a_trajectory_arrives_over_the_loopback_bus(tmp_path: Path) -> None:
    rig = CstProcesses(tmp_path)
    try:
        before = rig.positions()
        with rig.start_daemon() as arm:
            drives = rig.drives()
            assert all(d["cia402_state"] == ENABLED and d["mode"] == 10 for d in drives), drives
            time.sleep(0.5)
            assert np.abs(rig.positions() - before).max() < 5e-3, (rig.positions(), before)  # held: no jump, no sag
            states = Recorder()
            arm.subscribe("joint_states", states)
            wait_for(lambda: states.last() is not None, 10.0, "joint_states")
            arm.switch(activate=["joint_trajectory"])
            run_trajectory(arm, rig, np.array(states.last()["position"]))  # type: ignore[index]
            assert all(j["fault"] is None for j in arm.status()["joints"]), arm.status()["joints"]
    finally:
        rig.close()
