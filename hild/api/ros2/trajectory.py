"""A trajectory_msgs/JointTrajectory as the ``trajectory`` of hild's JSON goal body, its header stamp read as
ros2_control's joint_trajectory_controller reads it.

JTC: a zero stamp starts the trajectory now; a stamp in the past starts it as if it had started then (the points
already passed are dropped; a trajectory that has ended is refused); a stamp in the future delays the start. hild's
goals start when the cycle adopts them and always from the current desired state (no jump), so a past stamp is the
remaining points, their times shifted to now, reached from where the arm is; a delayed start is something a hild
goal cannot say, so a stamp more than ``FUTURE_SLACK`` ahead is refused rather than started early. Within the slack
(clocks of two machines never agree exactly) it counts as now.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hild.api.ros2.clock import NS, ros_ns

FUTURE_SLACK_NS = 100_000_000  # a stamp this little ahead of the robot's clock is clock skew: start now


def trajectory_body(trajectory: Any, now_ns: int) -> dict[str, Any]:
    """The JSON ``trajectory``; ValueError (the ROS-side refusal's reason) for a stamp hild cannot honour."""
    elapsed = 0
    stamp = ros_ns(trajectory.header.stamp)
    if stamp != 0:
        elapsed = now_ns - stamp
        if elapsed < -FUTURE_SLACK_NS:
            raise ValueError(
                f"the header stamp is {-elapsed / NS:.3f} s in the future: hild does not delay a trajectory's start; "
                "send a zero stamp (start now)"
            )
        elapsed = max(elapsed, 0)
    points = []
    for p in trajectory.points:
        at = ros_ns(p.time_from_start) - elapsed
        if elapsed and at <= 0:
            continue  # passed already: JTC samples the trajectory from its stamp, so these never run
        point: dict[str, Any] = {
            "positions": np.asarray(p.positions, dtype=float).tolist(),
            "time_from_start": {"sec": at // NS, "nanosec": at % NS},
        }
        for key, values in (("velocities", p.velocities), ("accelerations", p.accelerations), ("effort", p.effort)):
            if len(values):
                point[key] = np.asarray(values, dtype=float).tolist()
        points.append(point)
    if trajectory.points and not points:
        raise ValueError(f"the trajectory ended before it arrived (header stamp {elapsed / NS:.3f} s ago)")
    return {"joint_names": list(trajectory.joint_names), "points": points}
