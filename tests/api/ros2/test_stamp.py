"""The trajectory's header stamp, read as ros2_control's JTC reads it (hild/api/ros2/trajectory.py): zero starts
now, a past stamp drops the points already passed and shifts the rest, a trajectory that has ended or a stamp that
asks for a delayed start is refused — with accepted = false (or a dropped command) and an event, nothing moving."""

from __future__ import annotations

import uuid as uuidlib

import numpy as np
import pytest
import zenoh

from hild.api.ros2 import types, wire
from hild.api.ros2.trajectory import FUTURE_SLACK_NS, NS, trajectory_body
from tests.api.conftest import Daemon
from tests.api.ros2.test_action import goal, point, result, send
from tests.api.ros2.test_face import position, switch
from tests.helpers import wait_for

NOW = 1_800_000_000 * NS  # a fixed "now": the conversion is a pure function of it
TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"


def body(points: list[tuple[list[float], float]], stamp_ns: int) -> dict[str, object]:
    trajectory = goal([point(p, t) for p, t in points], stamp_ns=stamp_ns).trajectory
    return trajectory_body(trajectory, NOW)


def times(converted: dict[str, object]) -> list[float]:
    return [p["time_from_start"]["sec"] + p["time_from_start"]["nanosec"] / NS for p in converted["points"]]  # type: ignore[index, attr-defined]


POINTS = [([0.0, 0.0, 0.0], 0.0), ([0.1, 0.0, 0.0], 0.3), ([0.2, 0.0, 0.0], 0.6), ([0.3, 0.0, 0.0], 1.0)]


def test_a_zero_stamp_starts_now() -> None:
    assert times(body(POINTS, 0)) == pytest.approx([0.0, 0.3, 0.6, 1.0])


def test_a_past_stamp_drops_the_points_passed_and_shifts_the_rest() -> None:
    converted = body(POINTS, NOW - NS // 2)  # started 0.5 s ago: the points at 0 and 0.3 are behind it
    assert times(converted) == pytest.approx([0.1, 0.5])
    assert [p["positions"] for p in converted["points"]] == [[0.2, 0.0, 0.0], [0.3, 0.0, 0.0]]  # type: ignore[attr-defined, index]


def test_a_stamp_within_the_clock_slack_counts_as_now() -> None:
    assert times(body(POINTS, NOW + FUTURE_SLACK_NS)) == pytest.approx([0.0, 0.3, 0.6, 1.0])


def test_a_trajectory_that_has_ended_is_refused() -> None:
    with pytest.raises(ValueError, match="ended before it arrived"):
        body(POINTS, NOW - 2 * NS)


def test_a_delayed_start_is_refused() -> None:
    with pytest.raises(ValueError, match=r"1\.000 s in the future: hild does not delay"):
        body(POINTS, NOW + NS)


def sim_now(daemon: Daemon) -> int:
    """The daemon's ROS time: its lockstep sim clock (what a ``use_sim_time`` node reads on ``/clock``), at least
    1.5 s in so stamps in the past stay positive."""
    wait_for(lambda: daemon.engine.t > 1.5, what="1.5 s of sim time")
    return round(daemon.engine.t * NS)


def test_over_ros_a_past_stamp_runs_the_rest_and_bad_stamps_are_refused(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    assert switch(peer, ["traj"])
    start = position(ros_daemon)
    future = goal([point([0.3, 0.0, 0.0], 1.0)], stamp_ns=sim_now(ros_daemon) + 5 * NS)
    assert not send(peer, uuidlib.uuid4().bytes, future)
    wait_for(lambda: ros_daemon.events_with("in the future: hild does not delay"), what="the refusal's event")
    ended = goal([point([0.3, 0.0, 0.0], 0.5)], stamp_ns=sim_now(ros_daemon) - NS)
    assert not send(peer, uuidlib.uuid4().bytes, ended)
    wait_for(lambda: ros_daemon.events_with("ended before it arrived"), what="the refusal's event")
    np.testing.assert_allclose(position(ros_daemon), start, atol=1e-3)

    target = [0.2, 0.1, -0.1]
    passed = [point([0.9, 0.9, 0.9], 0.5), point(target, 1.5)]  # the first point is 0.5 s behind the stamp
    raw_id = uuidlib.uuid4().bytes
    assert send(peer, raw_id, goal(passed, stamp_ns=sim_now(ros_daemon) - NS))  # 0.5 s left to the target
    done = result(peer, raw_id)
    assert (done.status, done.result.error_code) == (4, 0)  # SUCCEEDED
    np.testing.assert_allclose(position(ros_daemon), target, atol=0.02)


def test_the_topic_drops_a_delayed_trajectory_with_an_event(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["traj"])
    start = position(ros_daemon)
    pub = peer.declare_publisher(wire.data_key(0, "/traj/joint_trajectory", TRAJECTORY))
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    delayed = goal([point([0.3, 0.0, 0.0], 1.0)], stamp_ns=sim_now(ros_daemon) + 5 * NS).trajectory
    pub.put(types.encode(delayed, TRAJECTORY), attachment=wire.attachment(1, bytes(16)))
    wait_for(lambda: ros_daemon.events_with("dropped command on /traj/joint_trajectory: the header stamp"))
    np.testing.assert_allclose(position(ros_daemon), start, atol=1e-3)
    pub.undeclare()
