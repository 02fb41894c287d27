"""CDR bytes and type hashes compared with real ROS 2 Jazzy: rclpy and its message packages from PyPI (the
``ros2-verify`` extra; .ci/run installs it). Skipped only when that extra is not installed.

Byte comparison, exactly: rclpy (Fast-CDR through rmw_fastrtps_cpp) leaves alignment padding uninitialised and
may hand back a few bytes past the message's end (its buffer length), so the comparison is: every byte hild
writes that is not padding equals rclpy's byte at the same offset, rclpy's extra tail is at most 8 bytes,
and rclpy decodes hild's bytes into a message equal to its own.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="the ros2-verify extra (real ROS 2 Jazzy from PyPI) is not installed")

from action_msgs.msg import GoalInfo, GoalStatus, GoalStatusArray  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String  # noqa: E402
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402
from unique_identifier_msgs.msg import UUID  # noqa: E402

from hild.api.ros2 import types  # noqa: E402

m = types.message


def hild_joint_state() -> Any:
    header = m("std_msgs/msg/Header", stamp=m("builtin_interfaces/msg/Time", sec=12, nanosec=345), frame_id="base")
    return m(
        "sensor_msgs/msg/JointState",
        header=header,
        name=["shoulder", "elbow", "w"],
        position=np.array([0.1, -0.2, 0.3]),
        velocity=np.array([1.0, 2.0, 3.0]),
        effort=np.array([-4.0, 5.5, 0.0]),
    )


def ros_joint_state() -> Any:
    msg = JointState()
    msg.header.stamp = Time(sec=12, nanosec=345)
    msg.header.frame_id = "base"
    msg.name = ["shoulder", "elbow", "w"]
    msg.position, msg.velocity, msg.effort = [0.1, -0.2, 0.3], [1.0, 2.0, 3.0], [-4.0, 5.5, 0.0]
    return msg


def hild_float_array() -> Any:
    dim = m("std_msgs/msg/MultiArrayDimension", label="joints", size=3, stride=3)
    layout = m("std_msgs/msg/MultiArrayLayout", dim=[dim], data_offset=0)
    return m("std_msgs/msg/Float64MultiArray", layout=layout, data=np.array([0.5, -0.25, 1e-9]))


def ros_float_array() -> Any:
    msg = Float64MultiArray(data=[0.5, -0.25, 1e-9])
    msg.layout.dim = [MultiArrayDimension(label="joints", size=3, stride=3)]
    return msg


def hild_trajectory() -> Any:
    point = m(
        "trajectory_msgs/msg/JointTrajectoryPoint",
        positions=np.array([0.1, 0.2]),
        velocities=np.array([0.0, 0.0]),
        accelerations=np.array([], dtype=np.float64),
        effort=np.array([], dtype=np.float64),
        time_from_start=m("builtin_interfaces/msg/Duration", sec=2, nanosec=500_000_000),
    )
    header = m("std_msgs/msg/Header", stamp=m("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id="")
    return m("trajectory_msgs/msg/JointTrajectory", header=header, joint_names=["a", "bb"], points=[point])


def ros_trajectory() -> Any:
    point = JointTrajectoryPoint(positions=[0.1, 0.2], velocities=[0.0, 0.0])
    point.time_from_start.sec, point.time_from_start.nanosec = 2, 500_000_000
    return JointTrajectory(joint_names=["a", "bb"], points=[point])


def hild_wrench() -> Any:
    header = m("std_msgs/msg/Header", stamp=m("builtin_interfaces/msg/Time", sec=5, nanosec=6), frame_id="tool0")
    vector = "geometry_msgs/msg/Vector3"
    wrench = m(
        "geometry_msgs/msg/Wrench", force=m(vector, x=1.0, y=-2.0, z=9.81), torque=m(vector, x=0.1, y=0.0, z=-0.3)
    )
    return m("geometry_msgs/msg/WrenchStamped", header=header, wrench=wrench)


def ros_wrench() -> Any:
    msg = WrenchStamped()
    msg.header.stamp = Time(sec=5, nanosec=6)
    msg.header.frame_id = "tool0"
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = 1.0, -2.0, 9.81
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = 0.1, 0.0, -0.3
    return msg


GOAL_ID = list(range(16))


def hild_status() -> Any:
    info = m(
        "action_msgs/msg/GoalInfo",
        goal_id=m("unique_identifier_msgs/msg/UUID", uuid=np.array(GOAL_ID, dtype=np.uint8)),
        stamp=m("builtin_interfaces/msg/Time", sec=3, nanosec=4),
    )
    return m("action_msgs/msg/GoalStatusArray", status_list=[m("action_msgs/msg/GoalStatus", goal_info=info, status=2)])


def ros_status() -> Any:
    info = GoalInfo(goal_id=UUID(uuid=GOAL_ID), stamp=Time(sec=3, nanosec=4))
    return GoalStatusArray(status_list=[GoalStatus(goal_info=info, status=2)])


CASES: dict[str, tuple[Callable[[], Any], Callable[[], Any], type]] = {
    "sensor_msgs/msg/JointState": (hild_joint_state, ros_joint_state, JointState),
    "std_msgs/msg/Float64MultiArray": (hild_float_array, ros_float_array, Float64MultiArray),
    "std_msgs/msg/String": (
        lambda: m("std_msgs/msg/String", data="<robot name='x'/>"),
        lambda: String(data="<robot name='x'/>"),
        String,
    ),
    "trajectory_msgs/msg/JointTrajectory": (hild_trajectory, ros_trajectory, JointTrajectory),
    "action_msgs/msg/GoalStatusArray": (hild_status, ros_status, GoalStatusArray),
    "geometry_msgs/msg/WrenchStamped": (hild_wrench, ros_wrench, WrenchStamped),
    "rosgraph_msgs/msg/Clock": (
        lambda: m("rosgraph_msgs/msg/Clock", clock=m("builtin_interfaces/msg/Time", sec=7, nanosec=8_000_009)),
        lambda: Clock(clock=Time(sec=7, nanosec=8_000_009)),
        Clock,
    ),
}


def padding(msg: Any, name: str) -> set[int]:
    """Offsets hild's serializer skips (alignment): serialized into buffers prefilled two ways, they keep the fill."""
    store = types.typestore()
    msgdef = store.get_msgdef(name)
    size = 4 + msgdef.getsize_cdr(0, msg, store)
    filled = []
    for fill in (0xAA, 0x55):
        buffer = bytearray([fill]) * size
        msgdef.serialize_cdr_le(memoryview(buffer)[4:], 0, msg, store)
        filled.append(buffer)
    return {i for i in range(4, size) if filled[0][i] == 0xAA and filled[1][i] == 0x55}


@pytest.mark.parametrize("name", sorted(CASES))
def test_cdr_bytes_equal_rclpy(name: str) -> None:
    make_hild, make_ros, ros_type = CASES[name]
    ours = types.encode(make_hild(), name)
    theirs = serialize_message(make_ros())
    assert ours[:4] == theirs[:4] == b"\x00\x01\x00\x00"
    assert len(ours) <= len(theirs) <= len(ours) + 8
    skip = padding(make_hild(), name)
    differing = [i for i in range(len(ours)) if i not in skip and ours[i] != theirs[i]]
    assert differing == [], f"bytes differ at {differing[:8]}"
    assert deserialize_message(ours, ros_type) == make_ros()
    assert len(skip) < len(ours) // 4  # the mask hides padding, not the message


@pytest.fixture(scope="module")
def node() -> Any:
    from rclpy.node import Node

    # DDS discovery on this host only (Jazzy's setting), in a domain no other test uses.
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=117)
    n = Node("hild_hash_probe", context=context, start_parameter_services=False)
    yield n
    n.destroy_node()
    rclpy.shutdown(context=context)


@pytest.mark.parametrize("name", sorted(CASES))
def test_type_hash_equals_what_rclpy_reports(node: Any, name: str) -> None:
    ros_type = CASES[name][2]
    topic = "/hash_probe_" + name.replace("/", "_")
    publisher = node.create_publisher(ros_type, topic, 10)
    (info,) = node.get_publishers_info_by_topic(topic)
    assert str(info.topic_type_hash) == types.type_hash(name)
    node.destroy_publisher(publisher)
