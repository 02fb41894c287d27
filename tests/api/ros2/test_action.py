"""follow_joint_trajectory over rmw_zenoh's action layout, against a bare Zenoh peer: a goal runs to its result
with feedback and status, a cancel ends it, and bad goals are refused the ROS way (accepted = false, an error
reply) with an event, nothing moving."""

from __future__ import annotations

import uuid as uuidlib
from typing import Any

import numpy as np
import zenoh
import zenoh.ext

from hild.api.ros2 import types, wire
from tests.api.conftest import WAIT, Daemon
from tests.api.ros2.conftest import call, request
from tests.api.ros2.test_face import Inbox, position, switch
from tests.helpers import wait_for

ACTION = "control_msgs/action/FollowJointTrajectory"
SEND, RESULT, CANCEL = f"{ACTION}_SendGoal", f"{ACTION}_GetResult", "action_msgs/srv/CancelGoal"
BASE = "/traj/follow_joint_trajectory/_action"
m = types.message


def duration(seconds: float) -> Any:
    return m("builtin_interfaces/msg/Duration", sec=int(seconds), nanosec=round((seconds % 1) * 1e9))


def point(positions: list[float], at: float) -> Any:
    empty = np.zeros(0)
    return m(
        "trajectory_msgs/msg/JointTrajectoryPoint",
        positions=np.array(positions, dtype=np.float64),
        velocities=empty,
        accelerations=empty,
        effort=empty,
        time_from_start=duration(at),
    )


def stamp(ns: int) -> Any:
    return m("builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9)


def goal(points: list[Any], joints: tuple[str, ...] = ("a", "b", "c"), stamp_ns: int = 0) -> Any:
    """A FollowJointTrajectory goal; ``stamp_ns``: the trajectory's header stamp (0: start now)."""
    header = m("std_msgs/msg/Header", stamp=stamp(0), frame_id="")
    multi = m("trajectory_msgs/msg/MultiDOFJointTrajectory", header=header, joint_names=[], points=[])
    traj_header = m("std_msgs/msg/Header", stamp=stamp(stamp_ns), frame_id="")
    return m(
        f"{ACTION}_Goal",
        trajectory=m(
            "trajectory_msgs/msg/JointTrajectory", header=traj_header, joint_names=list(joints), points=points
        ),
        multi_dof_trajectory=multi,
        path_tolerance=[],
        component_path_tolerance=[],
        goal_tolerance=[],
        component_goal_tolerance=[],
        goal_time_tolerance=duration(0.0),
    )


def uuid_msg(raw: bytes) -> Any:
    return m("unique_identifier_msgs/msg/UUID", uuid=np.frombuffer(raw, dtype=np.uint8).copy())


def send(peer: zenoh.Session, raw_id: bytes, body: Any, base: str = BASE) -> bool:
    reply = call(peer, f"{base}/send_goal", SEND, request(SEND, goal_id=uuid_msg(raw_id), goal=body))
    assert reply.ok is not None
    return bool(types.decode(reply.ok.payload.to_bytes(), f"{SEND}_Response").accepted)


def result(peer: zenoh.Session, raw_id: bytes, base: str = BASE) -> Any:
    reply = call(peer, f"{base}/get_result", RESULT, request(RESULT, goal_id=uuid_msg(raw_id)))
    assert reply.ok is not None
    return types.decode(reply.ok.payload.to_bytes(), f"{RESULT}_Response")


def test_a_goal_runs_to_its_result_with_feedback_and_status(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    feedback = Inbox()
    sub = peer.declare_subscriber(wire.data_key(0, f"{BASE}/feedback", f"{ACTION}_FeedbackMessage"), feedback)
    raw_id = uuidlib.uuid4().bytes
    target = [0.2, 0.1, -0.1]
    assert send(peer, raw_id, goal([point([0.15, 0.0, 0.0], 0.3), point(target, 0.6)]))
    done = result(peer, raw_id)  # answers when the goal has ended
    assert (done.status, done.result.error_code) == (4, 0)  # SUCCEEDED
    np.testing.assert_allclose(position(ros_daemon), target, atol=0.02)
    wait_for(lambda: len(feedback) >= 1, what="feedback")
    message = types.decode(feedback.last().payload.to_bytes(), f"{ACTION}_FeedbackMessage")
    assert bytes(message.goal_id.uuid) == raw_id and list(message.feedback.joint_names) == ["a", "b", "c"]
    statuses = Inbox()  # a late joiner gets the kept status
    late = zenoh.ext.declare_advanced_subscriber(
        peer,
        wire.data_key(0, f"{BASE}/status", "action_msgs/msg/GoalStatusArray"),
        statuses,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
    )
    wait_for(lambda: len(statuses) >= 1, what="the kept status")
    array = types.decode(statuses.last().payload.to_bytes(), "action_msgs/msg/GoalStatusArray")
    assert [(bytes(s.goal_info.goal_id.uuid), s.status) for s in array.status_list] == [(raw_id, 4)]
    sub.undeclare()
    late.undeclare()


def test_cancel_ends_a_running_goal(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    raw_id = uuidlib.uuid4().bytes
    assert send(peer, raw_id, goal([point([0.9, 0.9, 0.9], 20.0)]))
    info = m(
        "action_msgs/msg/GoalInfo", goal_id=uuid_msg(raw_id), stamp=m("builtin_interfaces/msg/Time", sec=0, nanosec=0)
    )
    reply = call(peer, f"{BASE}/cancel_goal", CANCEL, request(CANCEL, goal_info=info))
    assert reply.ok is not None
    canceled = types.decode(reply.ok.payload.to_bytes(), f"{CANCEL}_Response")
    assert canceled.return_code == 0 and [bytes(g.goal_id.uuid) for g in canceled.goals_canceling] == [raw_id]
    assert result(peer, raw_id).status == 5  # CANCELED
    unknown = uuidlib.uuid4().bytes
    info = m(
        "action_msgs/msg/GoalInfo", goal_id=uuid_msg(unknown), stamp=m("builtin_interfaces/msg/Time", sec=0, nanosec=0)
    )
    reply = call(peer, f"{BASE}/cancel_goal", CANCEL, request(CANCEL, goal_info=info))
    assert reply.ok is not None
    assert types.decode(reply.ok.payload.to_bytes(), f"{CANCEL}_Response").return_code == 2  # UNKNOWN_GOAL_ID
    assert result(peer, unknown).status == 0  # UNKNOWN, at once


def test_a_goal_for_joints_the_controller_does_not_own_is_rejected(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    start = position(ros_daemon)
    assert not send(peer, uuidlib.uuid4().bytes, goal([point([0.2, 0.2], 1.0)], joints=("a", "elbow")))
    wait_for(lambda: ros_daemon.events_with("refused ROS request on /traj/follow_joint_trajectory send_goal"))
    assert ros_daemon.events_with("elbow")
    np.testing.assert_allclose(position(ros_daemon), start, atol=1e-3)


def test_too_many_points_are_rejected_by_hilds_own_limit(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    start = position(ros_daemon)
    points = [point([0.0, 0.0, 0.0], 0.001 * (k + 1)) for k in range(10_001)]
    assert not send(peer, uuidlib.uuid4().bytes, goal(points))
    wait_for(lambda: ros_daemon.events_with("at most 10000"), what="the refusal event")
    np.testing.assert_allclose(position(ros_daemon), start, atol=1e-3)


def test_a_million_points_are_refused_unread(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """10^6 points cannot fit in the 1 MiB a request may have: refused by size before decoding (an error reply,
    as for any request rmw_zenoh cannot take), with an event."""
    assert switch(peer, ["traj"])
    start = position(ros_daemon)
    one = point([0.0, 0.0, 0.0], 1.0)
    payload = request(SEND, goal_id=uuid_msg(uuidlib.uuid4().bytes), goal=goal([one] * 1_000_000))
    assert len(payload) > 1 << 20
    reply = call(peer, f"{BASE}/send_goal", SEND, payload)
    assert reply.err is not None
    wait_for(lambda: ros_daemon.events_with("request larger than"), what="the refusal event")
    np.testing.assert_allclose(position(ros_daemon), start, atol=1e-3)


def test_the_action_is_in_the_ros_graph(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """rcl_action_server_is_available needs the three service servers and a feedback publisher."""
    keys = [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**", timeout=WAIT) if r.ok is not None]
    entities = {(k.split("/")[5], k.split("/")[9]) for k in keys if k.count("/") > 9}
    base = "%traj%follow_joint_trajectory%_action%"
    assert {
        ("SS", base + "send_goal"),
        ("SS", base + "get_result"),
        ("SS", base + "cancel_goal"),
        ("MP", base + "feedback"),
        ("MP", base + "status"),
    } <= entities


def test_the_joint_trajectory_topic_moves_the_arm(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    pub = peer.declare_publisher(wire.data_key(0, "/traj/joint_trajectory", "trajectory_msgs/msg/JointTrajectory"))
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    target = [-0.2, 0.15, 0.1]
    trajectory = goal([point(target, 0.4)]).trajectory
    pub.put(types.encode(trajectory, "trajectory_msgs/msg/JointTrajectory"), attachment=wire.attachment(1, bytes(16)))
    wait_for(lambda: np.allclose(position(ros_daemon), target, atol=0.02), what="the arm at the target")


def test_malformed_trajectories_on_the_topic_are_dropped(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    start = position(ros_daemon)
    pub = peer.declare_publisher(wire.data_key(0, "/traj/joint_trajectory", "trajectory_msgs/msg/JointTrajectory"))
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    pub.put(b"\x00\x01\x00\x00\x07\x00\x00\x00abc")
    wait_for(lambda: ros_daemon.events_with("dropped command on /traj/joint_trajectory: malformed CDR"))
    outside = goal([point([5.0, 0.0, 0.0], 1.0)]).trajectory  # beyond the position limits: hild's own refusal
    pub.put(types.encode(outside, "trajectory_msgs/msg/JointTrajectory"))
    wait_for(lambda: len(ros_daemon.events_with("dropped command on /traj/joint_trajectory")) >= 2)
    np.testing.assert_allclose(position(ros_daemon), start, atol=1e-3)
