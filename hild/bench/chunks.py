"""``hild bench --only chunks``: a synthetic policy's action chunks on the arm6 twin, in lockstep ([teleop] item 3).

The policy: a smooth reference motion (each joint a sum of two sines, within half the servo's velocity limit and a
fraction of its acceleration and jerk limits) observed every 100 ms (the observation's stamp: the cycle time, as the
joint_states ``stamp`` says it), each observation answered after a jittered inference delay (uniform 50–300 ms, in
sim time: deterministic) by a chunk of 50 steps 20 ms apart — the reference from the observation's time on, so a
perfect controller would follow the reference exactly. Jitter reorders arrivals: a chunk overtaken by a newer one
arrives stale and is dropped. Positions only, as policies send them.

The same chunks, at the same cycles, go to two controllers on two fresh twins:

* ``servo`` — the servo's ``chunk`` input (hild/motion/chunks.py): sampled at ``t − stamp``, tracked jerk-limited;
* ``jtc`` — JTC-style upsampling as chunks are usually fed to ros2_controllers' JointTrajectoryController: each
  chunk a ``joint_trajectory`` goal replacing the previous one, its header stamp 0 (start now), step ``k`` at
  ``k·dt`` from the arrival (step 0, the observed position, dropped), linear between positions-only points, from the
  current desired state, coming to rest at the last point. The inference delay is not compensated: the motion lags
  the plan by it.
* ``jtc_stamped`` — the same goals with the delay compensated (the chunk's stamp honoured: steps before the arrival
  dropped, step ``k`` at ``k·dt − delay`` from now). On this bench's exact reference its command's RMS error is the
  lowest, but every handoff splices into the first remaining point within a few ms (accelerations far beyond the
  limits, the supervisor's velocity limit engaging, a repeated command), and the arm does not follow that.

The RMS target compares the arm's measured error with the servo against the better of the two JTC variants.

Judged the same way (rows ``chunks disagreeing: …``): the same three with chunks that disagree, as a real policy's
do — each chunk drifts from the reference by a per-joint N(0, ``PREDICTION_ERROR``) × k/steps (0 at its observation,
the full error at its end; seeded), so successive chunks differ by a few mrad where they meet. The reference stays the
truth the errors are measured against, and the JTC variants get the same chunks.

Figures, on the commanded positions (what the controller writes, every cycle, once the first chunk arrived):
speed at every handoff (each chunk's arrival, the 100 ms after it) as a fraction of the reference's speed there
(where the reference moves at ≥ 25 % of its peak speed); velocity, acceleration and jerk peaks (finite differences,
as tests/controllers/test_servo.py checks them) as fractions of the limits; pauses (cycles at rest, < 1 % of the
peak speed, while the reference moves at ≥ 10 % of it); RMS error against the reference at the same time, of the
command and of the arm's measured position (the target: the arm's, against the better JTC variant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from hild.api.goals import GoalEndpoint
from hild.bench.report import target_row
from hild.bench.scenarios import ARM6
from hild.config import load_config
from hild.cycle.engine import Engine

GROUP = "teleop"
SCENARIO = "twin6@500 lockstep"
SERVO, JTC = "policy", "upsampling"  # loaded for the bench: no path tolerances to abort on
HANDOFF_SPEED = 0.9  # of the plan's speed, at least
MOVING = 0.25  # of the peak speed: handoffs judged where the reference moves at least this fast
PAUSE_MOVING, AT_REST = 0.10, 0.01  # a pause: slower than AT_REST × peak while the reference moves at PAUSE_MOVING
JERK_SLACK = 1e-6
KINDS = ("servo", "jtc", "jtc_stamped")
MIN_SECONDS = 3.0
PREDICTION_ERROR = 0.01  # rad (σ): a policy's chunks drift from the truth along their horizon, each its own way
SETTLE = 1.0  # s after the first chunk's arrival before the figures count: the arm starts at rest, the reference not


@dataclass(frozen=True)
class ChunkSettings:
    seconds: float = 20.0
    chunk_rate: float = 10.0  # Hz: observations, one chunk each
    steps: int = 50
    step_dt: float = 0.02
    delay: tuple[float, float] = (0.05, 0.30)  # s, uniform
    seed: int = 1
    command_timeout: float = 1.0  # the servo's: more than the longest gap between two chunks
    prediction_error: float = 0.0  # rad: each chunk drifts from the reference by up to this at its end (see play)

    @classmethod
    def make(cls, quick: bool, seed: int | None = None, seconds: float | None = None) -> ChunkSettings:
        """``--quick`` 5 s, else 20 s, or ``--seconds`` (at least ``MIN_SECONDS``: the figures start after a settling
        second and need handoffs after it)."""
        chosen = seconds or (5.0 if quick else 20.0)
        return cls(seconds=max(chosen, MIN_SECONDS), seed=1 if seed is None else seed)


class Reference:
    """Each joint: home + two sines, scaled to stay within fractions of the twin's limits."""

    def __init__(self, home: np.ndarray, vmax: np.ndarray, amax: np.ndarray, jmax: np.ndarray) -> None:
        n = len(home)
        self.home = home
        self.w = np.array([1.3, 2.9])  # rad/s
        self.phase = np.linspace(0.0, 2.0, n)
        # amplitude per joint so that speed ≤ 0.5 vmax, acceleration ≤ 0.4 amax, jerk ≤ 0.4 jmax (sum of both sines)
        split = np.array([0.7, 0.3])
        bound = np.minimum.reduce([0.5 * vmax / (split @ self.w), 0.4 * amax / (split @ self.w**2)])
        bound = np.minimum(bound, 0.4 * jmax / (split @ self.w**3))
        self.amplitude = np.minimum(bound, 0.5)[:, None] * split[None, :]  # (n, 2)

    def at(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[..., None, None]
        angle = self.w * t + self.phase[:, None]
        return self.home + (self.amplitude * (np.sin(angle) - np.sin(self.phase[:, None]))).sum(-1)

    def velocity(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[..., None, None]
        angle = self.w * t + self.phase[:, None]
        return (self.amplitude * self.w * np.cos(angle)).sum(-1)


def twin_engine() -> Engine:
    """configs/arm6_twin.yaml on the sim clock (lockstep), started."""
    loaded = load_config(ARM6)
    loaded.in_lockstep()
    engine = Engine(loaded)
    engine.start()
    return engine


def schedule(settings: ChunkSettings, start: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    """(arrival, stamp) of every chunk, by arrival (ties: the older first, so it is the one dropped)."""
    period = 1.0 / settings.chunk_rate
    count = int(settings.seconds * settings.chunk_rate)
    stamps = start + period * np.arange(count)
    delays = rng.uniform(*settings.delay, count)
    return sorted(zip((stamps + delays).tolist(), stamps.tolist(), strict=True))


def play(kind: str, settings: ChunkSettings) -> dict[str, Any]:
    """Run the chunks into ``kind`` (servo or jtc) on a fresh twin; the trace of commanded positions."""
    engine = twin_engine()
    try:
        name = SERVO if kind == "servo" else JTC
        compensated = kind == "jtc_stamped"
        joints = list(engine.manager.records["joint_trajectory"].instance.params.joints)
        if kind == "servo":
            engine.load_controller(SERVO, "servo", {"joints": joints, "command_timeout": settings.command_timeout})
        else:
            engine.load_controller(JTC, "joint_trajectory", {"joints": joints})
        result = engine.switch([name], [])
        if not result.ok:
            raise RuntimeError(f"cannot activate {name}: {result.error}")
        controller = engine.manager.records[name].instance
        index = [engine.joints.index(j) for j in controller.params.joints]
        lim = engine.limits
        ref = Reference(
            engine.state.position[index].copy(),
            lim.velocity[index],
            lim.acceleration[index],
            lim.jerk[index],
        )
        dt = engine.period
        start = engine.t + 0.1
        arrivals = schedule(settings, _on_cycle(start, dt), np.random.default_rng(settings.seed))
        arrivals = [(_on_cycle(a, dt), _on_cycle(s, dt)) for a, s in arrivals]
        drift = np.random.default_rng(settings.seed + 1).normal(
            0.0, settings.prediction_error, (len(arrivals), len(index))
        )
        ramp = np.arange(settings.steps)[:, None] / settings.steps
        endpoint = GoalEndpoint.of(controller.action) if kind != "servo" else None
        end = arrivals[-1][0] + 0.5
        times, commands, measured, taken = [], [], [], []
        newest = -math.inf
        k = 0
        while engine.t < end - 1e-9:
            t_next = engine.t + dt  # the cycle about to run
            while k < len(arrivals) and arrivals[k][0] <= t_next + 1e-9:
                arrival, stamp = arrivals[k]
                k += 1
                chunk = ref.at(stamp + settings.step_dt * np.arange(settings.steps)) + ramp * drift[k - 1]
                if kind == "servo":
                    controller.accept_chunk({"stamp": stamp, "dt": settings.step_dt, "positions": chunk.tolist()})
                    if stamp >= newest:
                        taken.append(arrival)
                elif stamp >= newest:  # a JTC would execute an older chunk too; that only worsens its figures
                    delay = arrival - stamp if compensated else 0.0
                    _send_goal(endpoint, controller.params.joints, chunk, delay, settings.step_dt)
                    taken.append(arrival)
                newest = max(newest, stamp)
            engine.run_cycles(1)
            times.append(engine.t)
            commands.append(engine.command.position[index].copy())
            measured.append(engine.state.position[index].copy())
        return {
            "t": np.array(times),
            "command": np.array(commands),
            "measured": np.array(measured),
            "handoffs": np.array(taken),
            "first": arrivals[0][0],
            "reference": ref,
            "limits": (lim.velocity[index], lim.acceleration[index], lim.jerk[index]),
            "dt": dt,
            "events": [f"{e.level}: {e.message}" for e in engine.events.drain()],
        }
    finally:
        engine.stop()


def _on_cycle(t: float, dt: float) -> float:
    return round(t / dt) * dt


def _send_goal(endpoint: Any, joints: list[str], chunk: np.ndarray, delay: float, step_dt: float) -> None:
    times = step_dt * np.arange(len(chunk)) - delay
    keep = times > 1e-9
    points = [
        {"positions": p.tolist(), "time_from_start": float(s)} for p, s in zip(chunk[keep], times[keep], strict=True)
    ]
    reply = endpoint.submit({"trajectory": {"joint_names": joints, "points": points}})
    if not reply["ok"]:
        raise RuntimeError(f"joint_trajectory refused a chunk: {reply['error']}")


def figures(trace: dict[str, Any], settings: ChunkSettings) -> dict[str, Any]:
    t, cmd, dt, ref = trace["t"], trace["command"], trace["dt"], trace["reference"]
    vmax, amax, jmax = trace["limits"]
    window = t >= trace["first"] + SETTLE
    plan_speed = np.linalg.norm(ref.velocity(t), axis=1)
    velocity = np.vstack([np.zeros((1, cmd.shape[1])), np.diff(cmd, axis=0) / dt])
    speed = np.linalg.norm(velocity, axis=1)
    peak = float(plan_speed[window].max())
    ratios = []
    for arrival in trace["handoffs"]:
        near = window & (t >= arrival) & (t < arrival + 1.0 / settings.chunk_rate) & (plan_speed >= MOVING * peak)
        if near.any():
            ratios.append(float((speed[near] / plan_speed[near]).min()))
    moving = window & (plan_speed >= PAUSE_MOVING * peak)
    pauses = int((moving & (speed < AT_REST * peak)).sum())
    c = cmd[window]
    acc = np.diff(c, 2, axis=0) / dt**2
    jerk = np.diff(c, 3, axis=0) / dt**3
    error = cmd[window] - ref.at(t[window])
    arm_error = trace["measured"][window] - ref.at(t[window])
    return {
        "handoffs": len(ratios),
        "handoff_speed_min": round(min(ratios), 4) if ratios else None,
        "handoff_speed_p5": round(float(np.percentile(ratios, 5)), 4) if ratios else None,
        "pauses": pauses,
        "velocity_peak": round(float((np.abs(velocity[window]) / vmax).max()), 4),
        "acceleration_peak": round(float((np.abs(acc) / amax).max()), 4),
        "jerk_peak": round(float((np.abs(jerk) / jmax).max()), 4),
        "rms_error_mrad": round(1e3 * float(np.sqrt((error**2).mean())), 4),
        "max_error_mrad": round(1e3 * float(np.abs(error).max()), 4),
        "measured_rms_error_mrad": round(1e3 * float(np.sqrt((arm_error**2).mean())), 4),
        "cycles": int(window.sum()),
    }


def run_chunks(settings: ChunkSettings) -> dict[str, Any]:
    report: dict[str, Any] = {
        "scenario": SCENARIO,
        "settings": {
            "seconds": settings.seconds,
            "chunk_rate_hz": settings.chunk_rate,
            "steps": settings.steps,
            "step_dt": settings.step_dt,
            "delay_s": list(settings.delay),
            "seed": settings.seed,
        },
    }
    for kind in KINDS:
        report[kind] = figures(play(kind, settings), settings)
    noisy = replace(settings, prediction_error=PREDICTION_ERROR)
    report["disagreeing"] = {"prediction_error_rad": PREDICTION_ERROR}
    for kind in KINDS:  # what successive chunks that disagree do to each controller
        report["disagreeing"][kind] = figures(play(kind, noisy), noisy)
    report["targets"] = chunk_targets(report)
    return report


def chunk_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The same four rows for the exact chunks (``chunks: …``) and, when run, for the disagreeing ones
    (``chunks disagreeing: …``), each against the JTC variants fed the same chunks."""
    s = report["settings"]
    basis = (
        f"{s['chunk_rate_hz']:g} Hz chunks of {s['steps']} × {1e3 * s['step_dt']:g} ms, delay "
        f"{1e3 * s['delay_s'][0]:g}–{1e3 * s['delay_s'][1]:g} ms jittered, {s['seconds']:g} s sim time"
    )
    rows = _variant_targets("chunks", report, basis)
    disagreeing = report.get("disagreeing")
    if disagreeing:
        drift = f"each chunk drifting N(0, {1e3 * disagreeing['prediction_error_rad']:g} mrad) × k/steps; {basis}"
        rows += _variant_targets("chunks disagreeing", disagreeing, drift)
    return rows


def _variant_targets(name: str, variant: dict[str, Any], basis: str) -> list[dict[str, Any]]:
    servo, jtc, stamped = variant["servo"], variant["jtc"], variant["jtc_stamped"]
    shortfall = None if servo["handoff_speed_min"] is None else 100.0 * (1.0 - servo["handoff_speed_min"])
    best = min(jtc["measured_rms_error_mrad"], stamped["measured_rms_error_mrad"])  # the better JTC, as the arm moved
    ratio = 100.0 * servo["measured_rms_error_mrad"] / best if best > 0 else None
    rows = [
        target_row(
            f"{name}: handoff speed shortfall",
            shortfall,
            round(100.0 * (1.0 - HANDOFF_SPEED), 6),
            "%",
            f"worst of {servo['handoffs']} handoffs: speed ≥ {HANDOFF_SPEED:.0%} of the plan's; {basis}",
            scenario=SCENARIO,
            group=GROUP,
        ),
        target_row(
            f"{name}: peak jerk / limit",
            100.0 * servo["jerk_peak"] / (1.0 + JERK_SLACK),  # finite differences may round a hair above
            100.0,
            "%",
            f"third differences of the command; acceleration peak {servo['acceleration_peak']:.0%}, velocity "
            f"{servo['velocity_peak']:.0%} of the limits",
            scenario=SCENARIO,
            group=GROUP,
        ),
        target_row(
            f"{name}: cycles at rest while moving",
            float(servo["pauses"]),
            0.0,
            "",
            f"speed < {AT_REST:.0%} of peak while the reference moves ≥ {PAUSE_MOVING:.0%}; {servo['cycles']} cycles",
            scenario=SCENARIO,
            group=GROUP,
        ),
        target_row(
            f"{name}: arm RMS / JTC upsampling",
            ratio,
            100.0,
            "%",
            f"the arm's measured position vs the reference, RMS: servo {servo['measured_rms_error_mrad']:g} mrad, "
            f"JTC-style goals {jtc['measured_rms_error_mrad']:g} mrad, with the delay compensated "
            f"{stamped['measured_rms_error_mrad']:g} mrad (the better of the two is the limit). The commands: servo "
            f"{servo['rms_error_mrad']:g}, JTC {jtc['rms_error_mrad']:g}, compensated {stamped['rms_error_mrad']:g} "
            f"mrad, the latter by leaving the limits at every handoff (acceleration peak "
            f"{stamped['acceleration_peak']:g}× the limit, {stamped['pauses']} cycles at rest)",
            scenario=SCENARIO,
            group=GROUP,
        ),
    ]
    return rows


def format_chunks(report: dict[str, Any]) -> str:
    s = report["settings"]
    lines = [
        f"CHUNKS: {report['scenario']}, {s['chunk_rate_hz']:g} Hz × {s['steps']} steps of {1e3 * s['step_dt']:g} ms, "
        f"delay {1e3 * s['delay_s'][0]:g}–{1e3 * s['delay_s'][1]:g} ms, {s['seconds']:g} s, seed {s['seed']}",
        f"  {'':<11} {'handoffs':>8} {'speed min':>9} {'p5':>6} {'pauses':>6} {'v peak':>6} {'a peak':>6} "
        f"{'j peak':>7} {'RMS mrad':>9} {'max mrad':>9} {'arm RMS':>8}",
    ]
    for kind in KINDS:
        r = report[kind]
        lines.append(
            f"  {kind:<11} {r['handoffs']:>8} {_num(r['handoff_speed_min']):>9} {_num(r['handoff_speed_p5']):>6} "
            f"{r['pauses']:>6} {r['velocity_peak']:>6.2f} {r['acceleration_peak']:>6.2f} {r['jerk_peak']:>7.2f} "
            f"{r['rms_error_mrad']:>9.3f} {r['max_error_mrad']:>9.3f} {r['measured_rms_error_mrad']:>8.3f}"
        )
    lines.append(
        "  (peaks: fraction of the joints' limits; speed: fraction of the reference's at each handoff; errors: the "
        "command vs the reference, arm RMS: the measured position vs the reference)"
    )
    disagreeing = report.get("disagreeing")
    if disagreeing:
        lines.append(
            f"  chunks that disagree (each drifts from the reference by N(0, {disagreeing['prediction_error_rad']:g} "
            "rad) × k/steps; judged as `chunks disagreeing: …`):"
        )
        for kind in KINDS:
            r = disagreeing[kind]
            lines.append(
                f"  {kind:<11} {r['handoffs']:>8} {_num(r['handoff_speed_min']):>9} {_num(r['handoff_speed_p5']):>6} "
                f"{r['pauses']:>6} {r['velocity_peak']:>6.2f} {r['acceleration_peak']:>6.2f} {r['jerk_peak']:>7.2f} "
                f"{r['rms_error_mrad']:>9.3f} {r['max_error_mrad']:>9.3f} {r['measured_rms_error_mrad']:>8.3f}"
            )
    return "\n".join(lines)


def _num(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f}"
