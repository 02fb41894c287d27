"""The daemon with telemetry on: `hild run` records the arm to a .rrd that reads back as commanded vs measured."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import yaml

from hild.telemetry import replay
from tests.conftest import CONFIGS
from tests.helpers import HildRun, free_endpoint


def test_the_daemon_records_telemetry_and_stops_cleanly(tmp_path: Path) -> None:
    config = yaml.safe_load((CONFIGS / "rrbot_twin.yaml").read_text())
    config["robot"]["model"] = str(CONFIGS / "rrbot.urdf")
    config["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "rrbot.urdf")
    config["robot"]["name"] = "arm6"
    config["telemetry"] = {"enabled": True, "sinks": [{"kind": "file", "path": "rec/run.rrd"}], "pose_rate": 10}
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    with HildRun(path, free_endpoint(), "arm6") as run, run.client() as robot:
        robot.wait_alive(timeout=30.0)
        robot.switch(activate=["joint_trajectory"])
        state = robot.next_message("joint_states", 10.0)
        target = [p + 0.2 for p in state["position"]]
        result = robot.move_to("joint_trajectory", target, timeout=20.0)
        assert result["status"] == "succeeded", f"{result}\n{run.log[-3000:]}"
        assert run.stop(sig=signal.SIGINT) == 0, run.log
    text = run.log
    assert "stopped: hardware released" in text
    recordings = list((tmp_path / "rec").glob("*.rrd"))
    assert recordings, text
    commanded, measured = replay.tracking(recordings[0], "position")
    assert len(measured.tick) > 100 and np.all(np.diff(measured.tick) == 1)  # every cycle, none lost
    moved = measured.column("joint1").max() - measured.column("joint1").min()
    assert moved > 0.15  # the move is in the recording
    assert np.abs(commanded.column("joint1") - target[0]).min() < 1e-6  # the goal's end point was commanded
