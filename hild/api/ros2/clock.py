"""The time the ROS 2 face stamps with, and ``/clock`` on the sim clock.

On the wall clock (``clock.source: wall``) ROS time is the robot PC's wall clock, as for any ROS node. On the sim
clock the cycle's time t = k·dt is the only time that means anything (lockstep runs faster or slower than real
time), so the face stamps with it — joint states with their sample's own t — and publishes it on ``/clock``
(rosgraph_msgs/msg/Clock), as a ROS simulator does: nodes with ``use_sim_time: true`` then share hild's time, and a
trajectory's header stamp is read against it.
"""

from __future__ import annotations

import time
from typing import Any

from hild.api.ros2 import types
from hild.api.ros2.node import Writer
from hild.daemon.link import CycleLink

CLOCK = "rosgraph_msgs/msg/Clock"
CLOCK_TOPIC = "/clock"  # global, whatever the node's namespace, as ROS's time source subscribes to it
CLOCK_PERIOD_NS = 10_000_000  # sim time between /clock messages: 100 Hz at real-time pace, as Gazebo's default
NS = 1_000_000_000


def ns(seconds: float) -> int:
    return round(seconds * NS)


def ros_time(stamp_ns: int) -> object:
    return types.message("builtin_interfaces/msg/Time", sec=stamp_ns // NS, nanosec=stamp_ns % NS)


def ros_ns(time: Any) -> int:
    """A builtin_interfaces Time or Duration as integer nanoseconds (``ros_time``'s inverse)."""
    return int(time.sec) * NS + int(time.nanosec)


class RosClock:
    """``now_ns`` and ``sample_ns`` in ROS time; ``tick`` publishes ``/clock`` when it is the sim clock's."""

    def __init__(self, engine: CycleLink, writer: Writer | None) -> None:
        self.engine = engine
        self.writer = writer  # None on the wall clock: ROS nodes have that one already
        self._published = -CLOCK_PERIOD_NS

    @property
    def sim(self) -> bool:
        return self.writer is not None

    def now_ns(self) -> int:
        return ns(self.engine.t) if self.sim else time.time_ns()

    def sample_ns(self, cycle_time: float) -> int:
        """The stamp of a sample the cycle took at ``cycle_time``: that time on the sim clock; on the wall clock
        the moment it is published (the cycle's wall time counts from start, not from the epoch)."""
        return ns(cycle_time) if self.sim else time.time_ns()

    def tick(self) -> None:
        """Publish the sim time if it advanced a period since the last message (every flush calls it)."""
        if self.writer is None:
            return
        now = self.now_ns()
        if now - self._published >= CLOCK_PERIOD_NS:
            self._published = now
            self.writer.put(types.encode(types.message(CLOCK, clock=ros_time(now)), CLOCK))
