"""tools/policy_client.py against a daemon in miniature: its synthetic policy's chunks drive the servo over Zenoh,
stamped with the joint_states stamps it observed (none refused), and the servo reports the policy as the source."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np

from hild.controllers.servo import ServoController
from hild.modes import Source
from tests.api.conftest import ROBOT, engine_from, robot_config, running

TOOL = Path(__file__).resolve().parents[2] / "tools" / "policy_client.py"


def tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location("policy_client", TOOL)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_example_policy_client_drives_the_servo_with_chunks(tmp_path: Path) -> None:
    config = robot_config()
    for joint in config["joints"].values():
        joint["limits"].update({"acceleration": 8.0, "jerk": 80.0})
    config["controllers"]["servo"] = {"type": "servo", "params": {"joints": ["a", "b", "c"], "command_timeout": 2.0}}
    engine = engine_from(config, tmp_path)
    with running(engine) as daemon:
        start = engine.command.position.copy()
        code = tool().main(
            ["--robot", ROBOT, "--connect", daemon.endpoint, "--seconds", "1.5", "--delay", "0.02", "0.1"]
        )
        assert code == 0
        servo = engine.manager.records["servo"].instance
        assert isinstance(servo, ServoController)
        assert servo.source == Source.POLICY
        assert servo._chunks.stamp > 0.0  # stamped with the control clock it observed
        assert np.abs(engine.command.position - start).max() > 0.01  # the joints moved
        assert daemon.events_with("chunk refused") == []
        assert daemon.events_with("could not plan") == []
