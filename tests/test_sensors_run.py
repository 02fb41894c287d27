"""``hild run`` with the cycle in its own process: a wrist F/T sensor on the twin, its wrench published by a
broadcaster whose cycle half and API half live in two processes, its state in status."""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import Any

import yaml

from tests.conftest import CONFIGS
from tests.helpers import HildRun, free_endpoint, wait_for


def test_the_twin_arm_publishes_its_wrist_wrench_across_processes(tmp_path: Path) -> None:
    config = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    for section in (config["robot"], config["hardware"]["twin"]["params"]):
        section["model"] = str(CONFIGS / "arm6.xml")
    config["hardware"]["twin"]["sensors"] = {"wrist_ft": {"type": "force_torque", "frame_id": "wrist_3_link"}}
    config["controllers"]["wrist_wrench"] = {
        "type": "force_torque_sensor_broadcaster",
        "params": {"sensor_name": "wrist_ft", "publish_rate": 50, "low_pass_cutoff": 10},
        "autostart": True,
    }
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    got: list[dict[str, Any]] = []
    lock = threading.Lock()

    def keep(message: dict[str, Any]) -> None:
        with lock:
            got.append(message)

    with HildRun(path, free_endpoint(), "arm6") as run, run.client() as robot:
        robot.wait_alive(timeout=30.0)
        with robot.subscribe_controller("wrist_wrench", "wrench", keep):
            wait_for(lambda: len(got) >= 5, 20.0, "wrenches from the cycle process")
        status = robot.status()
        assert status["sensors"] == [
            {"name": "wrist_ft", "type": "force_torque", "frame_id": "wrist_3_link", "hardware": "twin", "fault": None}
        ]
        assert run.stop(sig=signal.SIGINT) == 0, run.log
    with lock:
        last = got[-1]
    assert last["frame_id"] == "wrist_3_link" and last["fresh"] is True
    weight = sum(v * v for v in last["force"].values()) ** 0.5
    assert 1.7 < weight < 2.0  # wrist_3_link's 0.188 kg hanging below the sensor, in N
