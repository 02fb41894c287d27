"""Replay: an episode's recorded joint path sent back as one ``joint_trajectory`` goal (docs/recording.md).

The path is the *measured* positions (where the arm went, not what it was told), decimated to ``rate`` waypoints
(50 Hz by default: far denser than any arm's bandwidth, and 200 s fit the controller's 10 000-point limit; longer
episodes get a lower rate), each with the velocity the path has there (finite differences of the waypoints), so the
controller interpolates them with cubics; the first and the last point are at rest, so the arm stops exactly at
the recorded end pose (a trajectory ending in motion would get a stop appended, beyond it). ``speed`` scales time:
times divided by it, velocities multiplied.

Safety, in order, before anything moves:
1. The daemon's hardware must be simulated (every component's driver is the MuJoCo twin or the mock), unless the
   operator said ``--yes-on-hardware``: replaying on a real arm repeats a motion in a world that may have changed.
2. The arm must already be at the episode's start pose (within ``start_tolerance``), or replay refuses and says
   where it is. Moving there first is an *unrecorded* motion through a path nobody chose, so it happens only when
   asked for (``move_to_start``), as a jerk-limited ``move_to``. Within the tolerance, the small remaining offset is
   closed by a ``move_to`` too, so the trajectory's first point (at time 0) is exactly where the controller is.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from hild.record.frames import frame_rows
from hild.record.model import Episode, RecordError

MAX_POINTS = 10_000  # hild.controllers.trajectory_goals.MAX_POINTS: the longest timed goal joint_trajectory takes
SIMULATED_DRIVERS = frozenset({"mujoco", "mock"})  # no arm moves when these do
TRAJECTORY = "joint_trajectory"


class ReplayClient(Protocol):
    """What replay uses of ``hild.api.client.HildClient``."""

    def list_hardware(self) -> list[dict[str, Any]]: ...
    def list_controllers(self) -> list[dict[str, Any]]: ...
    def get_parameters(self, controller: str, names: Sequence[str] = ()) -> dict[str, Any]: ...
    def next_message(self, topic: str, timeout: float | None = None) -> dict[str, Any]: ...
    def move_to(self, controller: str, positions: Sequence[float], **kw: Any) -> dict[str, Any]: ...
    def execute_trajectory(
        self, controller: str, joint_names: Sequence[str], points: Sequence[dict[str, Any]], **kw: Any
    ) -> dict[str, Any]: ...


@dataclass(frozen=True)
class ReplayPlan:
    joint_names: list[str]
    times: np.ndarray  # (N,) s from the start, strictly increasing, times[0] = 0
    positions: np.ndarray  # (N, J)
    velocities: np.ndarray  # (N, J)

    @property
    def start(self) -> np.ndarray:
        return self.positions[0]

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def points(self) -> list[dict[str, Any]]:
        """The goal's ``trajectory.points``."""
        return [
            {"positions": p.tolist(), "velocities": v.tolist(), "time_from_start": float(t)}
            for t, p, v in zip(self.times, self.positions, self.velocities, strict=True)
        ]


def plan_replay(
    episode: Episode,
    joint_names: Sequence[str],
    *,
    rate: float = 50.0,
    speed: float = 1.0,
    max_points: int = MAX_POINTS,
) -> ReplayPlan:
    """The recorded measured path of ``joint_names`` as timed waypoints: the cycles a ``rate`` Hz zero-order hold
    picks (at their own recorded times), the last cycle always, times ÷ ``speed``."""
    if not speed > 0.0:
        raise RecordError(f"speed must be positive; found {speed}")
    missing = [j for j in joint_names if j not in episode.meta.joints]
    if missing:
        raise RecordError(f"episode {episode.meta.id} has no recording of {missing} (it has {episode.meta.joints})")
    rows = episode.rows
    if len(rows) < 2:
        raise RecordError(f"episode {episode.meta.id} has {len(rows)} cycle(s): nothing to replay")
    duration = float(rows.t[-1] - rows.t[0])
    if duration <= 0.0:
        raise RecordError(f"episode {episode.meta.id} lasts no time: nothing to replay")
    rate = min(rate, (max_points - 2) / duration)
    _, picked = frame_rows(rows.t, rate)
    picked = np.unique(np.append(picked, len(rows) - 1))  # sorted, each cycle once, ending on the last
    cols = [episode.meta.joints.index(j) for j in joint_names]
    times = (rows.t[picked] - rows.t[0]) / speed
    positions = rows.measured_position[np.ix_(picked, cols)]
    velocities = np.gradient(positions, times, axis=0)
    velocities[[0, -1]] = 0.0  # from rest (after the move to the start) to rest exactly at the recorded end pose
    return ReplayPlan(list(joint_names), times, positions, velocities)


def check_simulated(hardware: Sequence[dict[str, Any]], confirmed: bool) -> None:
    """Refuse unless every hardware component is simulated or the operator confirmed a real arm."""
    real = [f"{h.get('name')} ({h.get('driver')})" for h in hardware if h.get("driver") not in SIMULATED_DRIVERS]
    if real and not confirmed:
        raise RecordError(
            f"the daemon drives real hardware: {', '.join(real)}; replay moves the arm along the recorded path "
            "without watching for what changed around it. Add --yes-on-hardware to do it anyway"
        )


def trajectory_controller(controllers: Sequence[dict[str, Any]], asked: str | None) -> str:
    """The active joint_trajectory controller to replay with: the one asked for, or the only one."""
    found = [c for c in controllers if c.get("type") == TRAJECTORY]
    if asked is not None:
        found = [c for c in found if c["name"] == asked]
        if not found:
            raise RecordError(f"no {TRAJECTORY} controller named {asked!r}")
    elif len(found) != 1:
        names = ", ".join(c["name"] for c in found) or "none"
        raise RecordError(f"choose the {TRAJECTORY} controller to replay with (--controller): found {names}")
    chosen = found[0]
    if chosen.get("state") != "active":
        name = chosen["name"]
        raise RecordError(f"{name} is {chosen.get('state')}: activate it first (hild ctl switch --activate {name})")
    return str(chosen["name"])


def replay(
    client: ReplayClient,
    episode: Episode,
    *,
    speed: float = 1.0,
    controller: str | None = None,
    on_hardware: bool = False,
    start_tolerance: float = 0.05,
    move_to_start: bool = False,
    rate: float = 50.0,
    say: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Check, move to the start (within the tolerance, or when asked), send the path; returns the goal's result."""
    check_simulated(client.list_hardware(), on_hardware)
    name = trajectory_controller(client.list_controllers(), controller)
    joints = list(client.get_parameters(name, ["joints"])["joints"])
    plan = plan_replay(episode, joints, rate=rate, speed=speed)
    state = client.next_message("joint_states")
    by_name = dict(zip(state.get("name") or [], state.get("position") or [], strict=False))
    if any(j not in by_name for j in joints):
        raise RecordError(f"joint_states does not report {[j for j in joints if j not in by_name]}")
    offset = np.abs(np.array([by_name[j] for j in joints]) - plan.start)
    worst = int(np.argmax(offset))
    if offset[worst] > start_tolerance and not move_to_start:
        raise RecordError(
            f"the arm is {offset[worst]:.3g} rad from the episode's start on {joints[worst]} (tolerance "
            f"{start_tolerance:g}): move it there first, or add --move-to-start for a jerk-limited move_to"
        )
    say(f"moving to the start pose ({offset[worst]:.3g} rad away) with {name}")
    moved = client.move_to(name, plan.start.tolist(), joint_names=joints, timeout=60.0)
    if moved.get("status") != "succeeded":
        raise RecordError(f"the move to the start pose did not succeed: {moved}")
    say(f"replaying {episode.meta.id}: {len(plan.times)} waypoints over {plan.duration:.2f} s (speed {speed:g})")
    return client.execute_trajectory(name, joints, plan.points(), timeout=plan.duration + 30.0)
