"""End to end: ``hild run configs/arm6_twin.yaml`` as a subprocess, talked to only over Zenoh on loopback.

The daemon runs the real-time twin on the wall clock, so every check waits for a condition with a generous
timeout instead of sleeping a fixed time and hoping.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hild.api.client import HildError
from tests.conftest import CONFIGS
from tests.helpers import HildRun, free_endpoint, free_port, wait_for


class Recorder:
    """Keeps the messages of one subscription, thread-safely."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.messages: list[dict[str, Any]] = []

    def __call__(self, message: dict[str, Any]) -> None:
        with self.lock:
            self.messages.append(message)

    def last(self) -> dict[str, Any] | None:
        with self.lock:
            return self.messages[-1] if self.messages else None

    def texts(self) -> list[str]:
        with self.lock:
            return [m.get("message", "") for m in self.messages]


def run_to_exit(config: Path, endpoint: str) -> subprocess.CompletedProcess[str]:
    """``hild run`` on ``config`` listening on ``endpoint``, for a daemon expected to refuse to start."""
    command = [sys.executable, "-m", "hild.cli", "run", str(config), "--listen", endpoint]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[HildRun]:
    run = HildRun(CONFIGS / "arm6_twin.yaml", free_endpoint(), "arm6", log=tmp_path / "daemon.log", cwd=tmp_path)
    try:
        yield run
    finally:
        run.close()


def test_daemon_over_zenoh_only(daemon: HildRun) -> None:
    with daemon.started().client() as arm:
        arm.wait_alive(timeout=30.0)
        states, events = Recorder(), Recorder()
        arm.subscribe("joint_states", states)
        arm.subscribe("events", events)
        wait_for(lambda: states.last() is not None, 10.0, "joint_states")
        sample = states.last()
        assert sample is not None
        assert sample["name"] == ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
        assert {"stamp", "seq", "position", "velocity", "effort"} <= set(sample)

        status = arm.status()
        assert status["ok"] and status["mode"] == "hold"
        assert all(j["mode"] == "hold" for j in status["joints"])
        controllers = {c["name"]: c["state"] for c in arm.list_controllers()}
        assert controllers == {
            "joint_state_broadcaster": "active",
            "forward_position": "inactive",
            "joint_trajectory": "inactive",
            "servo": "inactive",
        }

        # Hold under gravity: a second of joint states stays within a milliradian of the start.
        start = np.array(sample["position"])
        time.sleep(1.0)
        latest = states.last()
        assert latest is not None
        assert np.abs(np.array(latest["position"]) - start).max() < 1e-3

        # Activate the forward controller and stream until the arm is at the target.
        assert arm.switch(activate=["forward_position"])["activated"] == ["forward_position"]
        target = start + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.2])

        def at_target() -> bool:
            last = states.last()
            return last is not None and np.abs(np.array(last["position"]) - target).max() < 5e-3

        wait_for(
            at_target,
            15.0,
            "the arm to reach the streamed target",
            tick=lambda: arm.send("forward_position", target.tolist()),
        )
        assert arm.status()["mode"] == "active"

        # Deactivate: the arm stays exactly where it was.
        assert arm.switch(deactivate=["forward_position"])["deactivated"] == ["forward_position"]
        at_release = np.array(states.last()["position"])  # type: ignore[index]
        time.sleep(1.0)
        assert np.abs(np.array(states.last()["position"]) - at_release).max() < 2e-3  # type: ignore[index]
        assert all(j["mode"] == "hold" for j in arm.status()["joints"])

        # Bad input: clear errors, nothing moves, the daemon keeps answering.
        bad = arm.call("switch_controllers", {"activate": "forward_position"}, check=False)
        assert bad["ok"] is False and bad["error"]
        with pytest.raises(HildError, match="ghost"):
            arm.switch(activate=["ghost"])
        arm.put("forward_position", {"values": "not a list"})
        wait_for(lambda: any("dropped command" in t for t in events.texts()), 10.0, "a dropped-command event")

        # E-stop, then reset.
        arm.estop()
        wait_for(lambda: arm.status()["mode"] == "estop", 10.0, "e-stop")
        with pytest.raises(HildError, match="e-stop"):
            arm.switch(activate=["forward_position"])
        arm.reset()
        wait_for(lambda: arm.status()["mode"] == "hold", 10.0, "hold after reset")

    # Ctrl-C: hold, release the hardware, exit 0.
    assert daemon.stop(20.0, signal.SIGINT) == 0, daemon.log
    text = daemon.log
    assert "stopped: hardware released" in text
    assert "leaked" not in text  # extension objects were freed before the interpreter ended (no nanobind noise)


def test_bad_config_exits_1_with_its_message(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text((CONFIGS / "rrbot_twin.yaml").read_text().replace("update_rate: 500", "update_rate: fast"))
    run = subprocess.run(
        [sys.executable, "-m", "hild.cli", "run", str(bad)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 1
    assert "update_rate: expected:" in run.stderr and "found 'fast' (str)" in run.stderr


def test_a_taken_port_is_refused_in_one_line_that_says_nothing_was_opened(tmp_path: Path) -> None:
    """Issue [layout] 8.3: the client domain and the main process both logged "start-up failed; the hardware was
    released", though the cycle process (the hardware) is started only once Zenoh is open."""
    config = tmp_path / "rrbot.yaml"
    config.write_text(
        (CONFIGS / "rrbot_twin.yaml").read_text().replace("model: rrbot.urdf", f"model: {CONFIGS / 'rrbot.urdf'}")
    )
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        run = run_to_exit(config, f"tcp/127.0.0.1:{port}")
    assert run.returncode == 1, run.stderr
    assert run.stderr.count("start-up failed") == 1, run.stderr
    assert "start-up failed; nothing was opened: cannot open the Zenoh API" in run.stderr
    assert "released" not in run.stderr, run.stderr


def test_a_second_daemon_of_the_same_robot_exits_1_naming_the_first_ones_main_process(
    daemon: HildRun, tmp_path: Path
) -> None:
    """Issue [layout] 8.2: the refusal named the first daemon's client domain, whose end only makes its main process
    start another: the name stays taken. It names the main process, the one systemd and an operator stop."""
    endpoint = daemon.started().endpoint
    config = tmp_path / "second.yaml"
    data = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    (tmp_path / "arm6.xml").write_text((CONFIGS / "arm6.xml").read_text())  # the robot's and the twin's model
    data.setdefault("zenoh", {})["connect"] = [endpoint]  # the same network as the first daemon
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    run = run_to_exit(config, f"tcp/127.0.0.1:{free_port()}")
    assert run.returncode == 1, run.stderr
    assert "robot 'arm6' already has a daemon on this Zenoh network" in run.stderr
    assert f"listening on {endpoint}" in run.stderr
    assert f"pid {daemon.pid}," in run.stderr and f"pid {daemon.client_process()}," not in run.stderr
    # Refused before the hardware was touched (the cycle process is started only after the check): nothing enabled.
    assert run.stderr.count("start-up failed") == 1, run.stderr
    assert "start-up failed; nothing was opened: robot 'arm6' already has a daemon" in run.stderr
    assert daemon.process.poll() is None  # the first one runs on


def _mapped_libraries(pid: int) -> set[str]:
    """The file names of the shared objects process ``pid`` has mapped."""
    lines = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return {Path(line.split()[-1]).name for line in lines if ".so" in line.split()[-1]}


def test_hild_run_is_three_processes_and_the_cycle_maps_no_client_library(daemon: HildRun) -> None:
    """docs/architecture.md, "Three processes": the cycle process loads none of what clients reach (Zenoh, rerun,
    rosbags); the client domain has Zenoh, which shows the check can see a mapped library."""
    with daemon.started().client() as arm:
        arm.wait_alive(timeout=30.0)
        cycle, client = daemon.cycle_process(), daemon.client_process()
        assert len({daemon.pid, cycle, client}) == 3
        cycle_maps, client_maps = _mapped_libraries(cycle), _mapped_libraries(client)
    client_only = ("zenoh", "rerun", "rosbags")
    assert any("zenoh" in name for name in client_maps), sorted(client_maps)
    assert sorted(name for name in cycle_maps if any(word in name for word in client_only)) == []
