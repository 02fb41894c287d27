"""The daemon with telemetry on: `hild run` records the arm to a .rrd that reads back as commanded vs measured."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from hild.telemetry import replay
from tests.conftest import CONFIGS
from tests.test_e2e import connect_when_up, free_port


def test_the_daemon_records_telemetry_and_stops_cleanly(tmp_path: Path) -> None:
    config = yaml.safe_load((CONFIGS / "rrbot_twin.yaml").read_text())
    config["robot"]["model"] = str(CONFIGS / "rrbot.urdf")
    config["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "rrbot.urdf")
    config["robot"]["name"] = "arm6"  # the name connect_when_up looks for
    config["telemetry"] = {"enabled": True, "sinks": [{"kind": "file", "path": "rec/run.rrd"}], "pose_rate": 10}
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path / "daemon.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hild.cli", "run", str(path), "--listen", endpoint], stdout=out, stderr=out
        )
    try:
        with connect_when_up(proc, endpoint, log, timeout=60.0) as robot:
            robot.wait_alive(timeout=30.0)
            robot.switch(activate=["joint_trajectory"])
            state = robot.next_message("joint_states", 10.0)
            target = [p + 0.2 for p in state["position"]]
            result = robot.move_to("joint_trajectory", target, timeout=20.0)
            assert result["status"] == "succeeded", f"{result}\n{log.read_text()[-3000:]}"
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    text = log.read_text()
    assert "stopped: hardware released" in text
    recordings = list((tmp_path / "rec").glob("*.rrd"))
    assert recordings, text
    commanded, measured = replay.tracking(recordings[0], "position")
    assert len(measured.tick) > 100 and np.all(np.diff(measured.tick) == 1)  # every cycle, none lost
    moved = measured.column("joint1").max() - measured.column("joint1").min()
    assert moved > 0.15  # the move is in the recording
    assert np.abs(commanded.column("joint1") - target[0]).min() < 1e-6  # the goal's end point was commanded
