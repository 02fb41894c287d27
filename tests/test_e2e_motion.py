"""End to end through Zenoh: goals, feedback, results, cancel and servo streaming against a subprocess daemon.

The daemon runs the real-time twin on the wall clock; every wait is for a condition with a generous timeout.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from hild.client import AsyncHildClient, HildError
from hild.motion.reference import standard_trajectory
from tests.helpers import HildRun, wait_for
from tests.test_e2e import Recorder, daemon

__all__ = ["daemon"]  # the fixture, re-used


def ctl(endpoint: str, *args: str) -> tuple[int, str]:
    proc = subprocess.run(
        [sys.executable, "-m", "hild.cli", "ctl", "--connect", endpoint, "--timeout", "5", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    return proc.returncode, proc.stdout + proc.stderr


def test_goals_and_streams_over_zenoh(daemon: HildRun, tmp_path: Path) -> None:
    endpoint = daemon.endpoint
    with daemon.started().client() as arm:
        arm.wait_alive(timeout=30.0)
        states = Recorder()
        arm.subscribe("joint_states", states)
        wait_for(lambda: states.last() is not None, 10.0, "joint_states")
        home = np.array(states.last()["position"])  # type: ignore[index]
        names = list(states.last()["name"])  # type: ignore[index]

        # A goal to an inactive controller is refused with the reason.
        with pytest.raises(HildError, match="not active"):
            arm.move_to("joint_trajectory", home.tolist())
        arm.switch(activate=["joint_trajectory"])

        # The standard trajectory: accepted, feedback for this goal, result succeeded, arm back home.
        feedback = Recorder()
        goal = standard_trajectory(names, home.tolist())["trajectory"]
        result = arm.execute_trajectory("joint_trajectory", goal["joint_names"], goal["points"], feedback=feedback,
                                        timeout=30.0)  # fmt: skip
        assert result["status"] == "succeeded", result
        assert result["error_code"] == 0
        assert len(feedback.messages) > 20  # ~25 Hz over 4 s
        assert {m["goal_id"] for m in feedback.messages} == {result["goal_id"]}
        assert set(feedback.messages[-1]) >= {"stamp", "joint_names", "desired", "actual", "error"}
        wait_for(lambda: np.abs(np.array(states.last()["position"]) - home).max() < 0.01, 10.0, "home")  # type: ignore[index]

        # A bad goal: rejected with its reason, nothing moves.
        with pytest.raises(HildError, match="outside its limits"):
            arm.move_to("joint_trajectory", [9.0, *home[1:].tolist()])

        # Cancel a running move: canceled, and the arm stops short of the target.
        handle = arm.send_goal("joint_trajectory", {"positions": (home + 0.8).tolist(), "duration": 4.0})
        with handle:
            time.sleep(0.5)
            assert arm.goal_result("joint_trajectory", handle.goal_id)["status"] == "executing"
            assert handle.cancel()["ok"]
            result = handle.wait(10.0)
        assert result["status"] == "canceled"
        stopped = np.array(states.last()["position"])  # type: ignore[index]
        assert (np.abs(stopped - (home + 0.8)) > 0.1).all()

        # The CLI: move-to and trajectory FILE.yaml print the result and exit 0 on success.
        code, out = ctl(endpoint, "move-to", *[str(x) for x in home], "--json")
        assert code == 0, out
        assert json.loads(out[out.index("{") :])["status"] == "succeeded"
        file = tmp_path / "wave.yaml"
        file.write_text(yaml.safe_dump(standard_trajectory(names, home.tolist(), scale=0.3)))
        code, out = ctl(endpoint, "trajectory", str(file))
        assert code == 0 and "succeeded" in out, out
        code, out = ctl(endpoint, "move-to", "1", "2")
        assert code == 1 and "expected 6 values" in out, out

        # Servo: stream targets, the arm follows; silence → it stops and holds.
        arm.switch(activate=["servo"], deactivate=["joint_trajectory"])
        stream = arm.servo_stream("servo")
        target = home + np.array([0.3, -0.2, 0.2, 0.0, 0.0, 0.4])

        def at(goal: np.ndarray) -> bool:
            return np.abs(np.array(states.last()["position"]) - goal).max() < 0.01  # type: ignore[index]

        wait_for(lambda: at(target), 15.0, "servo to reach the target", tick=lambda: stream.send(target.tolist()))
        time.sleep(0.6)  # command_timeout 0.25 s: stopped and holding
        held = np.array(states.last()["position"])  # type: ignore[index]
        time.sleep(0.5)
        assert np.abs(np.array(states.last()["position"]) - held).max() < 2e-3  # type: ignore[index]


def test_async_client(daemon: HildRun) -> None:
    import asyncio

    endpoint = daemon.started().endpoint

    async def main() -> str:
        async with await AsyncHildClient.connect("arm6", [endpoint], timeout=10.0) as arm:
            await arm.switch(["joint_trajectory"])
            state = await arm.next_message("joint_states", 10.0)
            result = await arm.move_to("joint_trajectory", [p + 0.05 for p in state["position"]], timeout=20.0)
            handle = await arm.send_goal("joint_trajectory", {"positions": state["position"]})
            sent = await arm.wait_result(handle, timeout=20.0)  # send_goal's handle, awaited without a thread of ours
            return f"{result['status']} {sent['status']}"

    assert asyncio.run(main()) == "succeeded succeeded"
