"""The motion paths measured: trajectory tracking on the lockstep twin, goal acceptance and servo latency over Zenoh.

    hild bench --only motion                           # defaults (--quick: fewer goals and steps)
    python -m hild.bench.motion                       # arm6 + rrbot tracking at 500 Hz, then the daemon parts
    python -m hild.bench.motion --rate 1000 --json bench.json

1. **Tracking** (deterministic, no daemon): each ``--tracking`` config on the sim clock (lockstep), the standard
   trajectory (``hild.motion.reference``) submitted to ``joint_trajectory``; per joint the RMS and max of
   commanded − measured position while the goal runs, the result, and the final error against the last point.
   ``--rate`` adds re-runs at other update rates (the twin's substeps are adjusted to keep its physics step).
2. **Goal acceptance** (wall clock): ``hild run --daemon-config`` as a subprocess on a free loopback port; ``--goals``
   move_to goals to the current position, each sent and its handle closed at once (the ``wait=False`` path).
   Timed: ``send_goal`` = declare the result subscriber + the ``goal`` query round trip (parse, plan, enqueue).
   For scale, the same number of ``result`` queries (same queryable path, no planning) is timed as a baseline.
3. **Servo target → motion** (wall clock, same daemon, broadcaster at full rate): ``servo`` active and held still by
   a 100 Hz stream of the rest target, then a step of ``--step`` rad on ``--servo-joint``; the latency is from the
   first publish of the step to the first ``joint_states`` sample that moved more than ``--threshold`` from rest.
   It includes the jerk-limited start of the motion, printed separately so it can be subtracted.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shlex
import signal
import sys
import tempfile
import textwrap
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hild.api.client import HildClient, HildError, ServoStream
from hild.api.goals import GoalEndpoint
from hild.bench.children import free_endpoint, wait_for
from hild.bench.daemon import CONFIGS, HildRun
from hild.bench.measure import RateRefused, lockstep_engine
from hild.config import load_config
from hild.config.documents import load_document
from hild.crossing.stats import percentiles
from hild.motion.reference import standard_trajectory

JTC = "joint_trajectory"
SERVO = "servo"
BROADCASTER = "joint_state_broadcaster"
TRACKING_LIMIT_S = 20.0  # sim seconds: a standard trajectory takes ~4 s
SETTLE_AFTER_RESULT_S = 1.0  # sim seconds of holding the final point before the "settled" error
HOLD_STREAM_HZ = 100.0  # servo targets while holding still and while stepping (the servo stops after silence)
STILL_FOR = 0.1  # s: a servo step starts only after the joint has been still this long


# ---- 1. tracking on the lockstep twin ---------------------------------------------------------------------------
def measure_tracking(config: Path, rate: float | None) -> dict[str, Any]:
    """Run the standard trajectory through joint_trajectory; tracking error = final command − measured position."""
    try:
        engine = lockstep_engine(config, rate)
    except RateRefused as exc:
        return {"config": config.name, "rate_hz": rate, "skipped": str(exc)}
    try:
        switched = engine.switch([JTC], [])
        if not switched.ok:
            return {"config": config.name, "rate_hz": engine.update_rate, "skipped": f"cannot activate: {switched}"}
        action = GoalEndpoint.of(engine.manager.records[JTC].instance.action)
        home = engine.state.position.copy()
        goal = standard_trajectory(engine.joints, home)
        reply = action.submit(goal)
        if not reply["ok"]:
            return {"config": config.name, "rate_hz": engine.update_rate, "skipped": f"rejected: {reply['error']}"}
        goal_id = reply["goal_id"]
        errors: list[np.ndarray] = []
        result = None
        started = time.perf_counter()
        for _ in range(int(TRACKING_LIMIT_S * engine.update_rate)):
            engine.run_cycles(1)
            errors.append(engine.final.position - engine.state.position)
            result = next((r for r in action.collect() if r.goal_id == goal_id), None)
            if result is not None:
                break
        wall = time.perf_counter() - started
        error = np.array(errors)
        final_point = np.array(goal["trajectory"]["points"][-1]["positions"])
        final_error = engine.state.position - final_point
        engine.run_cycles(round(SETTLE_AFTER_RESULT_S * engine.update_rate))
        settled_error = engine.state.position - final_point
        return {
            "config": config.name,
            "robot": engine.robot,
            "rate_hz": engine.update_rate,
            "status": str(result.status) if result else "no result",
            "error_code": int(result.error_code) if result else None,
            "error_string": result.error_string if result else f"none within {TRACKING_LIMIT_S:g} s",
            "cycles": len(errors),
            "sim_s": round(len(errors) * engine.period, 4),
            "wall_s": round(wall, 3),
            "joints": [
                {
                    "name": name,
                    "rms_rad": float(np.sqrt(np.mean(error[:, i] ** 2))),
                    "max_rad": float(np.abs(error[:, i]).max()),
                    "final_rad": float(final_error[i]),
                    "settled_rad": float(settled_error[i]),
                }
                for i, name in enumerate(engine.joints)
            ],
        }
    finally:
        engine.stop()


def format_tracking(row: dict[str, Any]) -> str:
    if "skipped" in row:
        return f"{row['config']} @ {row['rate_hz']:g} Hz: skipped ({row['skipped']})"
    head = (
        f"{row['config']} @ {row['rate_hz']:g} Hz: {row['status']} (error_code {row['error_code']}"
        f"{', ' + row['error_string'] if row['error_string'] else ''}) after {row['sim_s']:.3f} s sim "
        f"({row['cycles']} cycles, {row['wall_s']:.2f} s wall)"
    )
    lines = [head, f"  {'joint':<14} {'rms':>8} {'max':>8} {'final':>8} {'settled':>8}   (mrad)"]
    for j in row["joints"]:
        values = (j["rms_rad"], j["max_rad"], j["final_rad"], j["settled_rad"])
        lines.append(f"  {j['name']:<14} " + " ".join(f"{v * 1e3:>8.3f}" for v in values))
    return "\n".join(lines)


# ---- the daemon -------------------------------------------------------------------------------------------------
def full_rate_copy(config: Path, directory: Path) -> Path:
    """A copy of ``config`` in ``directory`` with the broadcaster at the update rate and model paths made absolute.

    Written as JSON (a subset of YAML), so the tool needs no YAML writer."""
    data = load_document(config)
    if BROADCASTER not in data.get("controllers", {}):
        raise ValueError(f"{config} has no {BROADCASTER!r} controller to publish joint_states")
    broadcaster = data["controllers"][BROADCASTER]
    broadcaster["params"] = {**(broadcaster.get("params") or {}), "publish_rate": data["update_rate"]}
    robot = data["robot"]
    if robot.get("model"):
        robot["model"] = str((config.parent / robot["model"]).resolve())
    for hardware in data["hardware"].values():
        params = hardware.get("params") or {}
        if isinstance(params.get("model"), str):
            params["model"] = str((config.parent / params["model"]).resolve())
    copy = directory / f"{config.stem}.full_rate.yaml"
    copy.write_text(json.dumps(data, indent=1))
    return copy


def percentiles_ms(samples_s: Sequence[float]) -> dict[str, float | int]:
    """``percentiles`` in ms (to the µs), with the count and the fastest sample."""
    if not samples_s:
        return {"n": 0}
    return {
        "n": len(samples_s),
        **percentiles(samples_s, "s", to="ms", digits=3),
        "min": round(min(samples_s) * 1e3, 3),
    }


class StateWatch:
    """Keeps the latest joint state and, once armed for a step, the receive time of the first sample beyond the
    threshold and the furthest excursion in the step's direction (for the overshoot).

    Runs on a Zenoh thread; the receive time is taken there, so the main loop's pacing does not blur it."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.position: list[float] = []
        self.velocity: list[float] = []
        self.names: list[str] = []
        self._joint = -1
        self._rest = 0.0
        self._threshold = math.inf
        self._direction = 1.0
        self._peak = 0.0
        self.moved_at: float | None = None

    def __call__(self, message: dict[str, Any]) -> None:
        now = time.perf_counter()
        position = message["position"]
        with self.lock:
            self.position, self.velocity, self.names = position, message["velocity"], message["name"]
            if self._joint < 0:
                return
            moved = position[self._joint] - self._rest
            self._peak = max(self._peak, moved * self._direction)
            if self.moved_at is None and abs(moved) > self._threshold:
                self.moved_at = now

    def arm(self, joint: int, rest: float, threshold: float, direction: float) -> None:
        with self.lock:
            self._joint, self._rest, self._threshold, self._direction = joint, rest, threshold, direction
            self._peak, self.moved_at = 0.0, None

    def disarm(self) -> float:
        """Stop watching; return the furthest excursion from rest in the step's direction."""
        with self.lock:
            self._joint = -1
            return self._peak

    def latest(self) -> tuple[np.ndarray, np.ndarray]:
        with self.lock:
            return np.array(self.position), np.array(self.velocity)


# ---- 2. goal acceptance -----------------------------------------------------------------------------------------
def measure_goal_latency(arm: HildClient, watch: StateWatch, goals: int, warmup: int = 10) -> dict[str, Any]:
    arm.switch(activate=[JTC], deactivate=[SERVO], strict=False)
    here = watch.latest()[0].tolist()
    accepted: list[float] = []
    rejected: list[str] = []
    last_id = ""
    for k in range(warmup + goals):
        start = time.perf_counter()
        try:
            handle = arm.send_goal(JTC, {"positions": here})
        except HildError as exc:
            rejected.append(str(exc))
            continue
        elapsed = time.perf_counter() - start
        handle.close()
        last_id = handle.goal_id
        if k >= warmup:
            accepted.append(elapsed)
    baseline: list[float] = []
    for _ in range(goals if last_id else 0):
        start = time.perf_counter()
        arm.goal_result(JTC, last_id)
        baseline.append(time.perf_counter() - start)
    return {
        "goals": goals,
        "warmup": warmup,
        "rejected": len(rejected),
        "rejections": sorted(set(rejected))[:5],
        "send_goal_ms": percentiles_ms(accepted),
        "result_query_ms": percentiles_ms(baseline),
    }


# ---- 3. servo target → motion -----------------------------------------------------------------------------------
def jerk_ramp_time(distance: float, jerk: float, acceleration: float) -> float:
    """Time for a rest-to-rest time-optimal jerk-limited move to cover ``distance`` (small: before the cruise).

    The profile opens with full jerk (p = j·t³/6) until the acceleration limit, then constant acceleration."""
    t1 = acceleration / jerk
    p1 = jerk * t1**3 / 6.0
    if distance <= p1:
        return float((6.0 * distance / jerk) ** (1.0 / 3.0))
    v1 = acceleration * t1 / 2.0  # p(t1 + s) = p1 + v1·s + a·s²/2
    s = (-v1 + math.sqrt(v1 * v1 + 2.0 * acceleration * (distance - p1))) / acceleration
    return t1 + s


def daemon_setup(config: Path, joint: str) -> tuple[str, float, float]:
    """Check the daemon config has what the benchmark drives; return the robot name and the (jerk, acceleration)
    the servo controller plans ``joint`` with: its limits times the controller's ``acceleration_scale``."""
    loaded = load_config(config)
    missing = [c for c in (JTC, SERVO, BROADCASTER) if c not in loaded.config.controllers]
    if missing:
        raise ValueError(f"{config} has no controller(s) {missing}: the daemon benchmark needs all of them")
    if joint not in loaded.config.joints:
        raise ValueError(f"--servo-joint {joint!r} is not a joint of {config} ({list(loaded.config.joints)})")
    limits = loaded.config.joints[joint].limits
    if limits.jerk is None or limits.acceleration is None:
        raise ValueError(f"joint {joint} has no jerk/acceleration limit: the servo controller cannot plan it")
    scale = float(getattr(loaded.controller_params[SERVO], "acceleration_scale", 1.0))
    return loaded.config.robot.name, float(limits.jerk) * scale, float(limits.acceleration) * scale


def servo_floor(config: Path, joint_name: str, step: float, threshold: float) -> dict[str, float]:
    """The same step in-process on the lockstep twin: cycles until the command, then the measured position, moved.

    Counted from the cycle that takes the target (1 = that cycle); no Zenoh, no pick-up wait, no thread wake-up,
    so the daemon's latency minus this is the transport and scheduling share."""
    engine = lockstep_engine(config, None)
    try:
        joint = engine.joints.index(joint_name)
        if not engine.switch([SERVO], []).ok:
            raise ValueError(f"cannot activate {SERVO} on the lockstep twin of {config}")
        engine.run_cycles(round(0.5 * engine.update_rate))  # at rest, held by servo
        rest_command, rest_measured = float(engine.final.position[joint]), float(engine.state.position[joint])
        target = engine.state.position.copy()
        target[joint] += step
        engine.manager.records[SERVO].instance.accept({"positions": target.tolist()})
        command_cycles = measured_cycles = 0
        for cycle in range(1, round(engine.update_rate) + 1):
            engine.run_cycles(1)
            if not command_cycles and abs(engine.final.position[joint] - rest_command) > threshold:
                command_cycles = cycle
            if abs(engine.state.position[joint] - rest_measured) > threshold:
                measured_cycles = cycle
                break
        return {
            "command_ms": round(command_cycles * engine.period * 1e3, 3),
            "measured_ms": round(measured_cycles * engine.period * 1e3, 3),
        }
    finally:
        engine.stop()


def stream_for(stream: ServoStream, target: list[float], seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        stream.send(target)
        time.sleep(1.0 / HOLD_STREAM_HZ)


def settle(
    stream: ServoStream, watch: StateWatch, target: list[float], joint: int, threshold: float, limit: float
) -> bool:
    """Stream ``target`` until the joint has stayed still near it for ``STILL_FOR`` s; False after ``limit`` s.

    "Still" = within threshold/2 of the target and slower than 2·threshold per second, so the rest position cannot
    drift by a tenth of the threshold while the next step is being detected."""
    deadline = time.monotonic() + limit
    still_since: float | None = None
    while time.monotonic() < deadline:
        stream_for(stream, target, 1.0 / HOLD_STREAM_HZ)
        position, velocity = watch.latest()
        still = abs(position[joint] - target[joint]) < threshold / 2 and abs(velocity[joint]) < 2 * threshold
        now = time.monotonic()
        if not still:
            still_since = None
        elif still_since is None:
            still_since = now
        elif now - still_since >= STILL_FOR:
            return True
    return False


def measure_servo_latency(
    arm: HildClient, watch: StateWatch, joint_name: str, steps: int, step: float, threshold: float, settle_limit: float
) -> dict[str, Any]:
    if joint_name not in watch.names:
        raise ValueError(f"no joint {joint_name!r} in joint_states ({watch.names})")
    joint = watch.names.index(joint_name)
    arm.switch(activate=[SERVO], deactivate=[JTC], strict=False)
    stream = arm.servo_stream(SERVO)
    home = watch.latest()[0]
    target = home.tolist()
    latencies: list[float] = []
    overshoots: list[float] = []
    missed = unsettled = 0
    started = time.monotonic()
    unsettled += not settle(stream, watch, target, joint, threshold, settle_limit)
    for k in range(steps):
        rest = float(watch.latest()[0][joint])
        direction = 1.0 if k % 2 == 0 else -1.0  # up by the step, then back home
        target = home.tolist()
        target[joint] = float(home[joint] + (step if direction > 0 else 0.0))
        watch.arm(joint, rest, threshold, direction)
        sent = time.perf_counter()
        deadline = time.monotonic() + 2.0
        while watch.moved_at is None and time.monotonic() < deadline:
            stream.send(target)
            time.sleep(1.0 / HOLD_STREAM_HZ)
        moved = watch.moved_at
        if moved is None:
            missed += 1
        else:
            latencies.append(moved - sent)
        unsettled += not settle(stream, watch, target, joint, threshold, settle_limit)
        overshoots.append(watch.disarm() - step)
    arm.switch(deactivate=[SERVO])
    return {
        "joint": joint_name,
        "steps": steps,
        "step_rad": step,
        "threshold_rad": threshold,
        "missed": missed,
        "unsettled": unsettled,
        "overshoot_max_rad": float(max(overshoots, default=0.0)),
        "seconds": round(time.monotonic() - started, 2),
        "latency_ms": percentiles_ms(latencies),
    }


def format_latency(label: str, stats: dict[str, Any]) -> str:
    if not stats.get("n"):
        return f"  {label:<40} no samples"
    return (
        f"  {label:<40} {stats['n']:>5} {stats['p50']:>8.3f} {stats['p99']:>8.3f} {stats['max']:>8.3f} "
        f"{stats['min']:>8.3f}"
    )


def format_daemon(config_name: str, goals: dict[str, Any], servo: dict[str, Any]) -> str:
    latency, ramp = servo["latency_ms"], servo["ramp_to_threshold_ms"]
    lines = [
        f"2./3. Over Zenoh against `hild run {config_name}` (wall clock, loopback TCP, broadcaster at the update rate)",
        f"  {'':<40} {'n':>5} {'p50':>8} {'p99':>8} {'max':>8} {'min':>8}   (ms)",
        format_latency("goal: send_goal → accepted", goals["send_goal_ms"]),
        format_latency("  baseline: result query round trip", goals["result_query_ms"]),
        format_latency(f"servo: step → {servo['joint']} moved", latency),
    ]
    if latency.get("n"):
        for label, floor in (
            ("  minus the jerk-limited ramp", ramp),
            ("  minus the same step in-process", servo["lockstep_floor"]["measured_ms"]),
        ):
            net = {key: round(latency[key] - floor, 3) for key in ("p50", "p99", "max", "min")}
            lines.append(format_latency(label, {"n": latency["n"], **net}))
    if goals["rejected"]:
        lines.append(f"  {goals['rejected']} goals rejected: {goals['rejections']}")
    if servo["missed"]:
        lines.append(f"  {servo['missed']} servo steps never crossed the threshold within 2 s")
    if servo["unsettled"]:
        lines.append(f"  {servo['unsettled']} servo steps did not settle in time (the next step started anyway)")
    floor = servo["lockstep_floor"]
    notes = [
        f"Goals: {goals['goals']} move_to the current position (after {goals['warmup']} warm-up), each preempting the"
        " last. send_goal includes declaring the result subscriber; the result query is the same queryable path"
        " without parsing or planning.",
        f"Servo: {servo['steps']} steps of ±{servo['step_rad']:g} rad on {servo['joint']}, each from rest, targets"
        f" streamed at {HOLD_STREAM_HZ:g} Hz; timed from the first publish of the step to the first joint_states"
        f" sample more than {servo['threshold_rad']:g} rad from rest. This includes the jerk-limited start: with jerk"
        f" {servo['jerk_limit']:g} rad/s³ (acceleration {servo['acceleration_limit']:g} rad/s²) the commanded"
        f" position itself needs {ramp:.2f} ms to move {servo['threshold_rad']:g} rad (x = j·t³/6), and the drive"
        " lags behind its command. In-process on the lockstep twin the same step moves the command past the"
        f" threshold in {floor['command_ms']:g} ms and the measured position in {floor['measured_ms']:g} ms"
        " (counting the cycle that takes the target, ±1 cycle); what remains above that is Zenoh, the asyncio side,"
        " the wait for the next cycle and the broadcaster. Largest overshoot of the measured position past the"
        f" target: {servo['overshoot_max_rad'] * 1e3:.2f} mrad. Servo part: {servo['seconds']:g} s.",
    ]
    lines.extend(textwrap.fill(note, 116, initial_indent="  ", subsequent_indent="  ") for note in notes)
    return "\n".join(lines)


# ---- the run ----------------------------------------------------------------------------------------------------
@dataclass
class MotionSettings:
    """What to measure and how much (``python -m hild.bench.motion``'s flags; ``hild bench --only motion`` takes these
    defaults, ``--quick`` fewer goals and steps)."""

    tracking: list[Path] = field(default_factory=lambda: [CONFIGS / "arm6_twin.yaml", CONFIGS / "rrbot_twin.yaml"])
    rates: list[float] = field(default_factory=list)  # tracking re-runs at these update rates, too
    daemon_config: Path | None = CONFIGS / "arm6_twin.yaml"  # None: tracking only
    goals: int = 200
    steps: int = 20
    servo_joint: str = "shoulder_pan"
    step: float = 0.05
    threshold: float = 1e-4
    settle: float = 3.0

    @classmethod
    def quick(cls) -> MotionSettings:
        return cls(goals=40, steps=5)


def run_motion(settings: MotionSettings) -> dict[str, Any]:
    """Tracking on every config and rate, then (with a daemon config) goal acceptance and servo latency."""
    report: dict[str, Any] = {
        "host": {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()},
        "tracking": [
            measure_tracking(config, rate) for config in settings.tracking for rate in [None, *settings.rates]
        ],
    }
    if settings.daemon_config is None:
        return report
    daemon_config = settings.daemon_config.resolve()
    robot, jerk, acceleration = daemon_setup(daemon_config, settings.servo_joint)
    with tempfile.TemporaryDirectory(prefix="hild-motion-bench-") as tmp:
        workdir = Path(tmp)
        config = full_rate_copy(daemon_config, workdir)
        run = HildRun(config, free_endpoint(), robot, cwd=workdir, args=("--log-level", "warning"))
        try:
            with run.connected() as arm:
                watch = StateWatch()
                with arm.subscribe("joint_states", watch):
                    wait_for(lambda: bool(watch.position), 10.0, "joint_states")
                    goals = measure_goal_latency(arm, watch, settings.goals)
                    servo = measure_servo_latency(
                        arm,
                        watch,
                        settings.servo_joint,
                        settings.steps,
                        settings.step,
                        settings.threshold,
                        settings.settle,
                    )
        finally:
            run.end(15.0, signal.SIGINT)
    servo["jerk_limit"] = jerk
    servo["acceleration_limit"] = acceleration
    servo["ramp_to_threshold_ms"] = round(jerk_ramp_time(settings.threshold, jerk, acceleration) * 1e3, 3)
    servo["lockstep_floor"] = servo_floor(daemon_config, settings.servo_joint, settings.step, settings.threshold)
    report["daemon"] = {"config": str(settings.daemon_config), "broadcaster_rate": "update_rate", "clock": "wall"}
    report["goal_acceptance"] = goals
    report["servo_latency"] = servo
    return report


def format_motion(report: dict[str, Any]) -> str:
    lines = [
        "1. Tracking: standard trajectory via joint_trajectory on the lockstep twin (sim clock)",
        "   error = final command position − measured position, every cycle while the goal runs;",
        "   final = measured − last trajectory point at the result; settled = the same after 1 s holding it",
        *(format_tracking(row) for row in report["tracking"]),
    ]
    if "daemon" in report:
        config = Path(report["daemon"]["config"]).name
        lines += ["", format_daemon(config, report["goal_acceptance"], report["servo_latency"])]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    defaults = MotionSettings()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--tracking", type=Path, nargs="*", default=defaults.tracking, help="configs for the lockstep tracking runs"
    )
    parser.add_argument("--rate", type=float, nargs="*", default=[], help="also run tracking at these update rates")
    parser.add_argument("--daemon-config", type=Path, default=defaults.daemon_config)
    parser.add_argument("--no-daemon", action="store_true", help="tracking only: skip the Zenoh measurements")
    parser.add_argument("--goals", type=int, default=defaults.goals, help="goals for the acceptance latency")
    parser.add_argument(
        "--steps", type=int, default=defaults.steps, help="servo steps for the target-to-motion latency"
    )
    parser.add_argument("--servo-joint", default=defaults.servo_joint)
    parser.add_argument("--step", type=float, default=defaults.step, help="servo step size (rad)")
    parser.add_argument("--threshold", type=float, default=defaults.threshold, help="motion detection threshold (rad)")
    parser.add_argument("--settle", type=float, default=defaults.settle, help="at most this long (s) to settle a step")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # unwind, so the daemon is stopped on the way out
    settings = MotionSettings(
        args.tracking,
        args.rate,
        None if args.no_daemon else args.daemon_config,
        args.goals,
        args.steps,
        args.servo_joint,
        args.step,
        args.threshold,
        args.settle,
    )
    try:
        report = {"command": shlex.join(sys.argv), **run_motion(settings)}
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    print(format_motion(report))
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
        print(f"\n(JSON written to {args.json})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
