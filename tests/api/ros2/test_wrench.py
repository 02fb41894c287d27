"""force_torque_sensor_broadcaster on the ROS 2 face: geometry_msgs/msg/WrenchStamped on ``<controller>/wrench``
with Jazzy's type hash, and the sensors' state interfaces in ``list_hardware_interfaces``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from hild.api.ros2 import types, wire
from tests.api.conftest import WAIT, Daemon, engine_from, running
from tests.api.ros2.conftest import ask, peer_of, ros_robot_config
from tests.api.ros2.test_face import Inbox
from tests.helpers import wait_for

WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
# geometry_msgs/msg/WrenchStamped.json as ROS 2 Jazzy's geometry_msgs ships it (the ros2-verify extra; hild's hash of
# every shipped message is held to those files by test_against_rosidl.py, and to pyzeros' by test_against_pyzeros.py)
JAZZY_HASH = "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77"
VALUES = [1.5, -2.0, 9.0, 0.1, -0.2, 0.3]


@pytest.fixture
def sensor_daemon(tmp_path: Path) -> Iterator[Daemon]:
    config = ros_robot_config(tmp_path)
    config["hardware"]["bus"]["sensors"] = {
        "wrist_ft": {"type": "force_torque", "frame_id": "ft_link", "params": {"values": VALUES, "noise": 0.001}}
    }
    config["controllers"]["ftb"] = {
        "type": "force_torque_sensor_broadcaster",
        "params": {"sensor_name": "wrist_ft", "frame_id": "tool0"},
        "autostart": True,
    }
    with running(engine_from(config, tmp_path)) as daemon:
        yield daemon


@pytest.fixture
def sensor_peer(sensor_daemon: Daemon) -> Iterator[zenoh.Session]:
    yield from peer_of(sensor_daemon)


def test_wrench_stamped_has_jazzys_type_hash() -> None:
    assert types.type_hash(WRENCH_STAMPED) == JAZZY_HASH


def test_the_wrench_is_published_as_wrench_stamped(sensor_daemon: Daemon, sensor_peer: zenoh.Session) -> None:
    inbox = Inbox()
    sub = sensor_peer.declare_subscriber(wire.data_key(0, "/ftb/wrench", WRENCH_STAMPED), inbox)
    wait_for(lambda: len(inbox) >= 3, what="three wrenches")
    msg = types.decode(inbox.last().payload.to_bytes(), WRENCH_STAMPED)
    assert msg.header.frame_id == "tool0"
    force, torque = msg.wrench.force, msg.wrench.torque
    np.testing.assert_allclose([force.x, force.y, force.z, torque.x, torque.y, torque.z], VALUES, atol=0.01)
    assert msg.header.stamp.sec > 0 or msg.header.stamp.nanosec > 0
    sub.undeclare()
    keys = [str(r.ok.key_expr) for r in sensor_peer.liveliness().get("@ros2_lv/0/**", timeout=WAIT) if r.ok]
    assert any("/MP/" in k and "%ftb%wrench/geometry_msgs::msg::dds_::WrenchStamped_/" in k for k in keys)


def test_a_stale_sensor_is_not_published_on_ros(sensor_daemon: Daemon, sensor_peer: zenoh.Session) -> None:
    inbox = Inbox()
    sub = sensor_peer.declare_subscriber(wire.data_key(0, "/ftb/wrench", WRENCH_STAMPED), inbox)
    wait_for(lambda: len(inbox) >= 1, what="a wrench")
    sensor_daemon.engine.hardware[0].component.sensor_silent.add("wrist_ft")  # type: ignore[attr-defined]
    wait_for(lambda: not sensor_daemon.engine.sensors.fresh[0], what="the sensor stale")
    count = len(inbox)
    json_samples = sensor_daemon.engine.controllers()["ftb"].ring.head
    wait_for(lambda: sensor_daemon.engine.controllers()["ftb"].ring.head >= json_samples + 5, what="JSON samples")
    assert len(inbox) <= count + 1  # at most one already on its way; the stale ones are not sent
    sensor_daemon.engine.hardware[0].component.sensor_silent.clear()  # type: ignore[attr-defined]
    wait_for(lambda: len(inbox) >= count + 3, what="wrenches again once the sensor reads")
    sub.undeclare()


def test_list_hardware_interfaces_lists_the_sensors_state_interfaces(
    sensor_daemon: Daemon, sensor_peer: zenoh.Session
) -> None:
    reply = ask(
        sensor_peer,
        "/controller_manager/list_hardware_interfaces",
        "controller_manager_msgs/srv/ListHardwareInterfaces",
    )
    state = {i.name: i for i in reply.state_interfaces}
    sensor = [f"wrist_ft/{v}" for v in ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")]
    assert set(sensor) <= set(state) and "a/position" in state
    assert all(state[n].is_available and not state[n].is_claimed for n in sensor)
    assert not any(i.name.startswith("wrist_ft/") for i in reply.command_interfaces)
