"""``hild ctl move-to`` / ``trajectory`` / ``cancel`` find the trajectory controller themselves (issue [import-real]).

An imported robot keeps its controllers' ROS names (``arm_controller``, ``joint_trajectory_controller``): without
``--controller`` the robot's only joint_trajectory controller is used, several or none are named, and a name the
robot does not have is said to be that — with the key that was asked, not only "no reply".
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from hild.api.ctl import EXIT_OK, EXIT_SERVICE
from hild.config import load_config
from hild.cycle.engine import Engine
from tests.api.conftest import ROBOT, Daemon, robot_config
from tests.api.test_ctl import ctl
from tests.conftest import with_trajectory
from tests.helpers import free_endpoint


def daemon_with(tmp_path: Path, trajectory_controllers: list[str]) -> Iterator[Daemon]:
    config = with_trajectory(robot_config(), *trajectory_controllers)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    daemon = Daemon(Engine(load_config(path)), free_endpoint())
    daemon.start()
    try:
        yield daemon
    finally:
        daemon.stop()


@pytest.fixture
def one(tmp_path: Path) -> Iterator[Daemon]:
    yield from daemon_with(tmp_path, ["arm_controller"])


@pytest.fixture
def two(tmp_path: Path) -> Iterator[Daemon]:
    yield from daemon_with(tmp_path, ["arm_controller", "joint_trajectory_controller"])


def test_move_to_uses_the_only_trajectory_controller(one: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert ctl(one, "switch", "--activate", "arm_controller") == EXIT_OK
    capsys.readouterr()
    assert ctl(one, "--json", "move-to", "0.2", "-0.1", "0.3") == EXIT_OK
    assert json.loads(capsys.readouterr().out)["status"] == "succeeded"


def test_move_to_names_the_trajectory_controllers_when_there_are_several(
    two: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(two, "move-to", "0.2", "-0.1", "0.3") == EXIT_SERVICE
    err = capsys.readouterr().err
    assert f"robot {ROBOT!r} has 2 trajectory controllers: arm_controller, joint_trajectory_controller" in err
    assert "choose one with --controller" in err
    assert ctl(two, "switch", "--activate", "joint_trajectory_controller") == EXIT_OK
    capsys.readouterr()
    assert ctl(two, "move-to", "--controller", "joint_trajectory_controller", "0.2", "-0.1", "0.3") == EXIT_OK


def test_a_robot_without_a_trajectory_controller_says_which_it_has(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(daemon, "move-to", "0.2", "-0.1", "0.3") == EXIT_SERVICE
    err = capsys.readouterr().err
    assert f"robot {ROBOT!r} has no trajectory controller" in err
    assert "jsb (joint_state_broadcaster), fwd (forward_command), fwd_a (forward_command)" in err


def test_a_controller_the_robot_lacks_is_named_with_the_key_asked(
    one: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(one, "move-to", "--controller", "joint_trajectory", "0.2", "-0.1", "0.3") == EXIT_SERVICE
    err = capsys.readouterr().err
    assert f"robot {ROBOT!r} has no controller 'joint_trajectory' (trajectory controllers: arm_controller)" in err
    assert f"hild/{ROBOT}/ctrl/joint_trajectory/goal" in err
    assert ctl(one, "move-to", "--controller", "fwd", "0.2", "-0.1", "0.3") == EXIT_SERVICE
    assert "controller 'fwd' (forward_command) takes no goals (trajectory controllers: arm_controller)" in (
        capsys.readouterr().err
    )


def test_trajectory_and_cancel_pick_the_controller_too(
    one: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert ctl(one, "switch", "--activate", "arm_controller") == EXIT_OK
    goal = tmp_path / "goal.yaml"
    points = [{"positions": [0.1, 0.0, 0.1], "time_from_start": 0.5}]
    goal.write_text(yaml.safe_dump({"joint_names": ["a", "b", "c"], "points": points}))
    assert ctl(one, "trajectory", str(goal)) == EXIT_OK
    capsys.readouterr()
    assert ctl(one, "move-to", "--no-wait", "--duration", "5", "-0.2", "0.1", "-0.3") == EXIT_OK
    goal_id = capsys.readouterr().out.strip()
    assert ctl(one, "cancel", goal_id) == EXIT_OK
    assert capsys.readouterr().out.strip() == f"cancel requested for {goal_id}"
