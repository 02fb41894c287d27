"""arm6 for ROS: configs/arm6_twin_ros2.yaml is the README's twin plus a ``ros2:`` section, and its daemon publishes
configs/arm6.urdf on ``/robot_description`` although its ``robot.model`` is the MJCF (``ros2.robot_description``)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
import zenoh
import zenoh.ext

from hild.api.ros2 import types, wire
from hild.config import load_config
from hild.config.loader import LoadedConfig
from hild.cycle.engine import Engine
from tests.api.conftest import Daemon
from tests.api.ros2.conftest import peer_config, ros_robot_config, running
from tests.api.ros2.test_face import Inbox
from tests.conftest import CONFIGS
from tests.helpers import wait_for

STRING = "std_msgs/msg/String"


def lockstep(loaded: LoadedConfig) -> LoadedConfig:
    loaded.in_lockstep()
    return loaded


def test_the_ros2_config_is_the_twin_config_plus_its_ros2_section() -> None:
    """The README's run (arm6_twin.yaml) stays without ROS; the ROS one differs from it in nothing else but the
    Zenoh mode."""
    twin = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    ros = yaml.safe_load((CONFIGS / "arm6_twin_ros2.yaml").read_text())
    assert "ros2" not in twin
    settings = ros.pop("ros2")
    assert ros["zenoh"].pop("mode") == "router"  # rmw_zenoh's nodes wait for a router: hild is one
    assert ros == twin
    assert settings["robot_description"] == "arm6.urdf"
    assert load_config(CONFIGS / "arm6_twin_ros2.yaml").config.ros2 is not None


def robot_description(daemon: Daemon) -> str:
    """What a late transient-local subscriber (rviz, robot_state_publisher) receives on /robot_description."""
    received = Inbox()
    session = zenoh.open(peer_config(daemon.endpoint))
    try:
        sub = zenoh.ext.declare_advanced_subscriber(
            session,
            wire.data_key(0, "/robot_description", STRING),
            received,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        wait_for(lambda: len(received) >= 1, what="the cached robot_description")
        sub.undeclare()
    finally:
        session.close()
    return str(types.decode(received.last().payload.to_bytes(), STRING).data)


@pytest.fixture
def arm6_daemon() -> Iterator[Daemon]:
    with running(Engine(lockstep(load_config(CONFIGS / "arm6_twin_ros2.yaml")))) as d:
        yield d


def test_the_arm6_daemon_publishes_its_urdf(arm6_daemon: Daemon) -> None:
    assert arm6_daemon.engine.loaded.config.robot.model == "arm6.xml"
    assert robot_description(arm6_daemon) == (CONFIGS / "arm6.urdf").read_text()


def test_a_robot_description_gone_after_the_check_is_an_error_event_not_a_crash(tmp_path: Path) -> None:
    """`hild check` refuses a missing file (tests/test_config.py); one removed between loading and starting is
    reported by the daemon, which runs on without it."""
    config = ros_robot_config(tmp_path)
    config["ros2"]["robot_description"] = "vanishing.urdf"
    (tmp_path / "vanishing.urdf").write_text("<robot name='r'/>")
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    loaded = load_config(path)
    (tmp_path / "vanishing.urdf").unlink()
    with running(Engine(loaded)) as daemon:
        wait_for(lambda: daemon.events_with("/robot_description not offered"), what="the error event")
        assert daemon.events_with("vanishing.urdf")
