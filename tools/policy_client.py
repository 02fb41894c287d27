"""A worked example of running a policy against hild: action chunks into the servo's ``chunk`` input.

    hild run configs/arm6_twin.yaml                                    # a terminal: the twin
    python tools/policy_client.py --robot arm6 --connect tcp/127.0.0.1:7447 --seconds 20
    python tools/policy_client.py --robot arm6 --connect tcp/127.0.0.1:7447 --episode recordings/<id> --move-to-start

The loop is the one a real policy runs (LeRobot's ACT, diffusion or pi0 with ``n_action_steps`` left to hild):

1. every ``1/rate`` s take the newest ``joint_states`` (the observation; its ``stamp`` is the control clock);
2. infer a chunk: ``steps`` joint positions ``step_dt`` apart, step 0 being the observed instant;
3. send ``{"stamp": <the observation's stamp>, "dt": step_dt, "positions": [...]}`` to
   ``hild/<robot>/ctrl/<servo>/chunk`` — whenever it is ready: the servo skips the part already in the past (the
   inference delay), blends it into the running chunk within the jerk limits, and slows down if the next is late.

The "policy" here is synthetic: it replays a path — a recorded episode (``hild record``'s MCAP, its measured
positions), a CSV (``t`` then one column per joint, in the servo's joint order), or, with neither, a smooth motion
around where the arm is — and waits a jittered "inference" delay (uniform 50–300 ms) before sending each chunk, on
worker timers so several are in flight, as a slow policy server would. Replace :class:`ReplayPolicy` with your own:
anything with ``chunk(observation) -> np.ndarray (steps, n)``; :class:`LeRobotPolicy` shows the adapter for a
LeRobot policy (``predict_action_chunk``; no LeRobot import here).

hild must be in ``PYTHONPATH`` (``pip install -e .`` in the repository does it).
"""

from __future__ import annotations

import argparse
import csv
import heapq
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hild.client import HildClient

START_TOLERANCE = 0.05  # rad: farther than this from the path's start, --move-to-start is needed


@dataclass(frozen=True)
class Observation:
    stamp: float  # the joint_states stamp: the control clock
    positions: np.ndarray  # the servo's joints, in its order


class Policy(Protocol):
    def chunk(self, observation: Observation) -> np.ndarray:
        """``(steps, n)`` joint positions; row ``k`` for ``observation.stamp + k·step_dt``."""
        ...


class ReplayPolicy:
    """A path as a function of time, replayed from the first observation on: the chunk for an observation at
    ``stamp`` is the path from ``stamp − first stamp`` on (it ignores the observed positions)."""

    def __init__(self, path: Callable[[np.ndarray], np.ndarray], steps: int, step_dt: float) -> None:
        self.path, self.steps, self.step_dt = path, steps, step_dt
        self.origin: float | None = None

    def chunk(self, observation: Observation) -> np.ndarray:
        if self.origin is None:
            self.origin = observation.stamp
        return self.path(observation.stamp - self.origin + self.step_dt * np.arange(self.steps))


class LeRobotPolicy:
    """The adapter for a LeRobot policy (ACT, diffusion, pi0), as a sketch: ``make_batch`` builds the policy's input
    from the observation (its joint positions plus your cameras), ``predict_action_chunk`` returns ``(1, steps,
    n)`` actions — absolute joint positions in the servo's joint order and units (map and convert them here if your
    dataset's differ). Use the policy's own ``chunk_size`` and its training fps for ``--steps`` and ``--step-dt``;
    do not let the policy queue actions itself (``select_action``): hild plays the chunk, on the control clock."""

    def __init__(self, policy: Any, make_batch: Callable[[Observation], Any]) -> None:
        self.policy, self.make_batch = policy, make_batch

    def chunk(self, observation: Observation) -> np.ndarray:
        import torch  # the policy's own dependency

        with torch.no_grad():
            actions = self.policy.predict_action_chunk(self.make_batch(observation))
        return np.asarray(actions[0].detach().cpu().numpy(), dtype=np.float64)


# ---- paths ----------------------------------------------------------------------------------------------------
def interpolated(t: np.ndarray, positions: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Linear interpolation of a sampled path, holding its ends."""
    columns = range(positions.shape[1])
    return lambda at: np.stack([np.interp(at, t, positions[:, j]) for j in columns], axis=-1)


def episode_path(directory: Path, joints: Sequence[str]) -> Callable[[np.ndarray], np.ndarray]:
    from hild.record.mcap_files import read_episode

    episode = read_episode(directory)
    missing = [j for j in joints if j not in episode.meta.joints]
    if missing:
        raise SystemExit(f"episode {episode.meta.id} has no recording of {missing} (it has {episode.meta.joints})")
    cols = [episode.meta.joints.index(j) for j in joints]
    rows = episode.rows
    return interpolated(rows.t - rows.t[0], rows.measured_position[:, cols])


def csv_path(file: Path, joints: Sequence[str]) -> Callable[[np.ndarray], np.ndarray]:
    with file.open() as f:
        table = [row for row in csv.reader(f) if row]
    header, body = table[0], np.array(table[1:], dtype=np.float64)
    if header[0] != "t" or len(header) != len(joints) + 1:
        raise SystemExit(f"{file}: expected the columns t, {', '.join(joints)}; found {', '.join(header)}")
    return interpolated(body[:, 0] - body[0, 0], body[:, 1:])


def own_motion(start: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Around where the arm is: each joint within ±0.5 rad of ``start``, two sines, starting there."""
    phase = np.linspace(0.0, 2.0, len(start))

    def path(at: np.ndarray) -> np.ndarray:
        a = np.asarray(at)[..., None]
        slow = np.sin(1.3 * a + phase) - np.sin(phase)
        fast = np.sin(2.9 * a + phase) - np.sin(phase)
        return start + 0.175 * slow + 0.075 * fast

    return path


# ---- the loop -------------------------------------------------------------------------------------------------
class Latest:
    """The newest joint_states, kept by the subscription's callback (a Zenoh thread)."""

    def __init__(self, joints: Sequence[str]) -> None:
        self.joints, self._lock, self._message = list(joints), threading.Lock(), None

    def __call__(self, message: dict[str, Any]) -> None:
        with self._lock:
            self._message = message

    def observation(self) -> Observation | None:
        with self._lock:
            message = self._message
        if message is None:
            return None
        names, positions = message["name"], message["position"]
        return Observation(float(message["stamp"]), np.array([positions[names.index(j)] for j in self.joints]))


def run(
    client: HildClient,
    controller: str,
    policy: Policy,
    latest: Latest,
    args: argparse.Namespace,
) -> dict[str, int]:
    """Observe at ``rate``, infer, send each chunk after its (synthetic) delay; until ``seconds`` have passed."""
    rng = np.random.default_rng(args.seed)
    pending: list[tuple[float, int, dict[str, Any]]] = []  # (send at, order, chunk): in flight
    sent = observed = 0
    begin = time.monotonic()
    next_observation = begin
    while time.monotonic() - begin < args.seconds or pending:
        now = time.monotonic()
        if now >= next_observation and now - begin < args.seconds:
            next_observation += 1.0 / args.rate
            observation = latest.observation()
            if observation is not None:
                positions = policy.chunk(observation)
                chunk = {"stamp": observation.stamp, "dt": args.step_dt, "positions": positions.tolist()}
                heapq.heappush(pending, (now + rng.uniform(*args.delay), observed, chunk))
                observed += 1
        while pending and pending[0][0] <= time.monotonic():
            client.put(controller, heapq.heappop(pending)[2], input="chunk")
            sent += 1
        wakes = [p[0] for p in pending[:1]]  # the next chunk due
        if time.monotonic() - begin < args.seconds:
            wakes.append(next_observation)
        if wakes:
            time.sleep(max(0.0, min(min(wakes) - time.monotonic(), 0.01)))
    return {"observed": observed, "sent": sent}


def activate(client: HildClient, name: str, other: str) -> None:
    """Make ``name`` active (``other``, which claims the same joints, inactive) unless it already is."""
    states = {c["name"]: c["state"] for c in client.list_controllers()}
    if states.get(name) != "active":
        client.switch(activate=[name], deactivate=[other] if states.get(other) == "active" else [])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robot", required=True)
    parser.add_argument("--connect", action="append", default=[], help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--controller", default="servo", help="the servo to drive (default servo)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--episode", type=Path, help="a hild record episode directory: replay its measured path")
    source.add_argument("--csv", type=Path, help="a CSV path: t, then one column per joint (servo order)")
    parser.add_argument("--seconds", type=float, default=20.0, help="how long the policy runs (default 20)")
    parser.add_argument("--rate", type=float, default=10.0, help="observations (and chunks) per second (default 10)")
    parser.add_argument("--steps", type=int, default=50, help="steps per chunk (default 50, at most 100)")
    parser.add_argument("--step-dt", type=float, default=0.02, help="s between steps (default 0.02)")
    parser.add_argument("--delay", type=float, nargs=2, default=(0.05, 0.30), metavar=("MIN", "MAX"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--command-timeout", type=float, help="set the servo's command_timeout first (s; ≥ the longest chunk gap)"
    )
    parser.add_argument("--move-to-start", action="store_true", help="move to the path's start first (move_to)")
    parser.add_argument("--trajectory-controller", default="joint_trajectory", help="for --move-to-start")
    args = parser.parse_args(argv)

    endpoints = {"connect": args.connect} if args.connect else {}
    with HildClient(robot=args.robot, **endpoints) as client:
        if args.command_timeout is not None:
            client.set_parameters(args.controller, {"command_timeout": args.command_timeout})
        params = client.get_parameters(args.controller, ["joints", "command_timeout"])
        joints = list(params["joints"])
        gap = 1.0 / args.rate + args.delay[1] - args.delay[0]  # the longest time between two chunks' arrivals
        if params["command_timeout"] < gap:
            print(
                f"warning: {args.controller}'s command_timeout {params['command_timeout']:g} s is shorter than the "
                f"longest gap between chunks ({gap:g} s): it will stop between them (--command-timeout)",
                file=sys.stderr,
            )
        latest = Latest(joints)
        with client.subscribe("joint_states", latest):
            deadline = time.monotonic() + 5.0
            while latest.observation() is None:
                if time.monotonic() > deadline:
                    raise SystemExit("no joint_states within 5 s: is a joint_state_broadcaster active?")
                time.sleep(0.01)
            here = latest.observation()
            assert here is not None
            if args.episode is not None:
                path = episode_path(args.episode, joints)
            elif args.csv is not None:
                path = csv_path(args.csv, joints)
            else:
                path = own_motion(here.positions)
            start = path(np.array(0.0))
            offset = float(np.abs(start - here.positions).max())
            if offset > START_TOLERANCE:
                if not args.move_to_start:
                    raise SystemExit(f"the path starts {offset:.3f} rad from where the arm is: add --move-to-start")
                activate(client, args.trajectory_controller, args.controller)
                client.move_to(args.trajectory_controller, start.tolist())
            activate(client, args.controller, args.trajectory_controller)
            counts = run(client, args.controller, ReplayPolicy(path, args.steps, args.step_dt), latest, args)
    print(f"{counts['observed']} observations, {counts['sent']} chunks sent to {args.controller}/chunk")
    return 0


if __name__ == "__main__":
    sys.exit(main())
