"""``hild ctl gripper`` and ``HildClient.gripper`` over Zenoh: open, close on the box, the result's fields."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hild.api.client import HildClient, HildError
from hild.api.ctl import EXIT_OK, EXIT_SERVICE
from hild.config import load_config
from hild.cycle.engine import Engine
from tests.api.conftest import Daemon, robot_config
from tests.api.test_ctl import ctl
from tests.controllers.test_parallel_gripper import BOX_HALF_WIDTH, rig_engine
from tests.helpers import free_endpoint


@pytest.fixture
def rig_daemon(tmp_path: Path) -> Iterator[Daemon]:
    daemon = Daemon(rig_engine(tmp_path), free_endpoint())
    daemon.start()
    try:
        yield daemon
    finally:
        daemon.stop()


def test_close_stalls_on_the_box_and_open_reaches_the_goal(
    rig_daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(rig_daemon, "switch", "--activate", "gripper") == EXIT_OK
    capsys.readouterr()
    assert ctl(rig_daemon, "--json", "gripper", "close", "--effort", "8") == EXIT_OK
    result = json.loads(capsys.readouterr().out)
    assert result["status"] == "succeeded" and result["stalled"] is True and result["reached_goal"] is False
    assert result["position"] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)
    assert ctl(rig_daemon, "gripper", "open") == EXIT_OK
    out = capsys.readouterr().out
    assert "succeeded (reached at 0.03" in out or "succeeded (reached at 0.04" in out


def test_the_client_method_returns_the_result_and_feedback(rig_daemon: Daemon) -> None:
    with HildClient(None, [rig_daemon.endpoint], 2.0) as client:
        client.switch(["gripper"], [])
        feedback: list[dict[str, object]] = []
        result = client.gripper("gripper", 0.02, max_velocity=0.02, feedback=feedback.append, timeout=10.0)
        assert result["status"] == "succeeded" and result["reached_goal"] is True
        assert result["position"] == pytest.approx(0.02, abs=0.01)
        assert feedback and feedback[-1]["joint"] == "finger"
        with pytest.raises(HildError, match="outside finger's soft range"):
            client.gripper("gripper", 0.5)


def test_a_gripper_goal_to_a_controller_of_another_type_says_so(
    rig_daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(rig_daemon, "gripper", "open", "--controller", "lift") == EXIT_SERVICE
    assert "rejected" in capsys.readouterr().err  # the trajectory controller refuses a gripper goal


def test_without_a_gripper_controller_ctl_names_the_controllers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(robot_config(), sort_keys=False))
    daemon = Daemon(Engine(load_config(path)), free_endpoint())
    daemon.start()
    try:
        assert ctl(daemon, "gripper", "close") == EXIT_SERVICE
        assert "has no gripper controller (controllers: " in capsys.readouterr().err
    finally:
        daemon.stop()
