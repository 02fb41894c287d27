"""``hild bench --only teleop``: leader–follower teleoperation between two twin daemons through a relay that delays
and drops, and the [teleop] targets it is judged by.

Two ``hild run`` daemons on loopback (configs/arm6_leader_twin.yaml and configs/arm6_follower_twin.yaml, free
ports, wall clock), not linked to each other: the relay (``hild.bench.relay``, a process of its own) carries the
leader's joint_states to the follower as another robot's, with a one-way delay, jitter and loss. The leader runs
random jerk-limited moves (``move_to`` on its joint_trajectory controller, moderate speed); the follower's ``follow``
controller is activated and its dead-man held (``{"enable": true}`` at 10 Hz). Run once without delay and once at
``delay``/``loss``, each with the leader streaming at the control rate (its broadcaster's ``publish_rate`` = the
``update_rate``, ``follow``'s ``rate`` the same: judged) and at ``REPORTED_STREAM_RATE`` (reported, not judged).

How each figure is measured (docs/performance.md, "Leader–follower teleoperation"):

- **the follower's command** (replayed): the relayed stream as the follower's daemon received it (the bench
  subscribes to the relayed key there, and stamps arrivals) is replayed into the same follower config in lockstep
  (the sim clock, each sample handed over in the first cycle at or after its arrival time): every cycle's command
  is there exactly.
- **joint lag** (the target): per joint, the shift τ in [0, 0.5] s that minimises the RMS of command(t) −
  leader(t − τ), the leader's joint_states stamped on arrival here (one clock, this process's); the worst joint's.
  Target ([teleop]): ≤ 2 *control* periods + one-way delay, the leader streaming at the control rate. The same from
  the follower's measured joint_states is reported beside it: that adds the twin's own tracking of its command (a
  PD drive).
- **jumps**: replayed command steps > v_max·T (target 0).
- **dead-man → hold**: a second replay releases the dead-man while the arm moves: cycles from the cycle that
  adopts the release to every joint's mode HOLD (target ≤ 2). Beside it, from the live run: the time from sending
  ``{"enable": false}`` to a status query answering every joint in hold (Zenoh both ways and the query included).
"""

from __future__ import annotations

import contextlib
import json
import math
import random
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import numpy as np
import yaml
import zenoh

from hild.api.client import HildClient, HildError
from hild.api.session import client_config, open_session
from hild.bench.children import LoggedChild, distinct_free_ports, wait_for
from hild.bench.daemon import HILD, HildRun
from hild.bench.report import target_row
from hild.config import load_config
from hild.controllers.follow import FollowController
from hild.cycle.engine import Engine
from hild.modes import JointMode

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
LEADER, FOLLOWER, RELAYED = "arm6_leader", "arm6_follower", "arm6_leader_relayed"
GROUP = "teleop"
MAX_SHIFT = 0.5  # s: the longest lag looked for
STALL_ALLOWED = 5.0  # s: the rig's safety.max_cycle_gap (the configs' 0.5 s faults a twin on an overloaded machine)
ENABLE_EVERY = 0.1  # s between dead-man refreshes
# The stream rate run beside the judged one (which streams at the control rate): the broadcaster's default, reported
# for comparison, not judged.
REPORTED_STREAM_RATE = 100.0  # Hz


@dataclass(frozen=True)
class TeleopSettings:
    delay: float = 0.05  # s, one way
    jitter: float = 0.005  # s, ±
    loss: float = 0.05
    moves: int = 12  # random leader moves per run
    seed: int = 1

    @classmethod
    def make(cls, quick: bool, seed: int | None) -> TeleopSettings:
        return cls(moves=5 if quick else 12, seed=seed if seed is not None else 1)


@dataclass
class Stream:
    """Messages of one joint_states stream, stamped on arrival in this process (monotonic)."""

    arrival: list[float] = field(default_factory=list)
    stamp: list[float] = field(default_factory=list)
    seq: list[int] = field(default_factory=list)
    position: list[list[float]] = field(default_factory=list)
    messages: list[dict[str, Any]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    keep: bool = False  # keep the messages themselves (the relayed stream, for the replay)

    def __call__(self, message: dict[str, Any]) -> None:
        now = time.monotonic()
        with self.lock:
            self.arrival.append(now)
            self.stamp.append(float(message["stamp"]))
            self.seq.append(int(message["seq"]))
            self.position.append(list(message["position"][:6]))
            if self.keep:
                self.messages.append(message)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        with self.lock:
            return np.array(self.arrival), np.array(self.position)

    def stamped_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrival, position and the daemon's stamp of the same messages (one lock: the stream goes on meanwhile)."""
        with self.lock:
            return np.array(self.arrival), np.array(self.position), np.array(self.stamp)


def config_pair(
    directory: Path, leader_port: int, follower_port: int, stream_rate: float | None = None
) -> tuple[Path, Path]:
    """The README's two configs, on free ports, the follower following the relay's robot and linked to nothing; the
    leader's joint_state_broadcaster publishing at ``stream_rate`` Hz (default: as shipped), ``follow`` told so."""
    leader = yaml.safe_load((CONFIGS / "arm6_leader_twin.yaml").read_text())
    follower = yaml.safe_load((CONFIGS / "arm6_follower_twin.yaml").read_text())
    for cfg in (leader, follower):
        cfg["robot"]["model"] = str(CONFIGS / "arm6.xml")
        cfg["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "arm6.xml")
    leader["zenoh"] = {"listen": [f"tcp/127.0.0.1:{leader_port}"]}
    follower["zenoh"] = {"listen": [f"tcp/127.0.0.1:{follower_port}"]}
    follower["controllers"]["follow"]["params"]["leader"] = RELAYED
    if stream_rate is not None:
        follower["controllers"]["follow"]["params"]["rate"] = stream_rate
        leader["controllers"]["joint_state_broadcaster"]["params"]["publish_rate"] = stream_rate
    for cfg in (leader, follower):  # twins: nothing to protect when a loaded machine stalls a cycle for a second
        cfg["safety"]["max_cycle_gap"] = STALL_ALLOWED
    paths = directory / "leader.yaml", directory / "follower.yaml"
    for path, cfg in zip(paths, (leader, follower), strict=True):
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return paths


class TeleopRig:
    """Two twin daemons and the relay between them; ``with TeleopRig(...) as rig``. Streams recorded from start."""

    def __init__(
        self, directory: Path, delay: float, jitter: float, loss: float, seed: int, stream_rate: float | None = None
    ) -> None:
        self.directory = directory
        self.delay, self.jitter, self.loss, self.seed = delay, jitter, loss, seed
        lp, fp = distinct_free_ports(2)
        self.leader_endpoint, self.follower_endpoint = f"tcp/127.0.0.1:{lp}", f"tcp/127.0.0.1:{fp}"
        self.leader_config, self.follower_config = config_pair(directory, lp, fp, stream_rate)
        self.leader_stream, self.follower_stream, self.relayed_stream = Stream(), Stream(), Stream(keep=True)
        self._children: list[LoggedChild] = []
        self._subs: list[Any] = []
        self._session: zenoh.Session | None = None
        self.leader: HildClient | None = None
        self.follower: HildClient | None = None
        self._enabling = threading.Event()
        self._enabler: threading.Thread | None = None

    def __enter__(self) -> TeleopRig:
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _start(self) -> None:
        d = self.directory
        lead = HildRun(self.leader_config, self.leader_endpoint, LEADER, log=d / "leader.log", cwd=d)
        self._children.append(lead)
        follow = HildRun(self.follower_config, self.follower_endpoint, FOLLOWER, log=d / "follower.log", cwd=d)
        self._children.append(follow)
        relay_args = [
            *HILD[:2],
            "hild.bench.relay",
            *("--from", LEADER, "--to", RELAYED),
            *("--source-connect", self.leader_endpoint, "--target-connect", self.follower_endpoint),
            *("--delay", str(self.delay), "--jitter", str(self.jitter), "--loss", str(self.loss)),
            *("--seed", str(self.seed)),
        ]
        self.leader, self.follower = lead.connected(), follow.connected()
        relay = LoggedChild(relay_args, d / "relay.log", cwd=d)
        self._children.append(relay)
        wait_for(lambda: "relay ready" in relay.log, 30.0, "the relay", logs=lambda: relay.log)
        self._subs.append(self.leader.subscribe("joint_states", self.leader_stream))
        self._subs.append(self.follower.subscribe("joint_states", self.follower_stream))
        self._session = open_session(client_config([self.follower_endpoint]))
        relayed = self.relayed_stream

        def on_relayed(sample: zenoh.Sample) -> None:
            relayed(json.loads(sample.payload.to_bytes()))

        self._subs.append(self._session.declare_subscriber(f"hild/{RELAYED}/joint_states", on_relayed))
        wait_for(lambda: len(self.relayed_stream.arrival) > 10, 30.0, "the relayed stream at the follower")

    def engage(self) -> None:
        """Activate the follower's follow controller and hold its dead-man (a thread refreshing it)."""
        assert self.follower is not None
        self.follower.switch(activate=["follow"], deactivate=[])
        self._enabling.set()
        follower = self.follower

        def hold() -> None:
            while self._enabling.is_set():
                follower.put("follow", {"enable": True}, input="enable")
                time.sleep(ENABLE_EVERY)

        self._enabler = threading.Thread(target=hold, name="deadman", daemon=True)
        self._enabler.start()

    def release(self) -> None:
        assert self.follower is not None
        self._enabling.clear()
        if self._enabler is not None:
            self._enabler.join(timeout=2.0)
        self.follower.put("follow", {"enable": False}, input="enable")

    def random_moves(self, moves: int, seed: int) -> None:
        """``moves`` jerk-limited moves of every leader joint to random positions near home, ~0.6 rad/s peak."""
        assert self.leader is not None
        rng = random.Random(seed)
        self.leader.switch(activate=["joint_trajectory"], deactivate=[])
        home = self.leader.next_message("joint_states")["position"][:6]
        for _ in range(moves):
            target = [h + rng.uniform(-0.4, 0.4) for h in home]
            self.leader.move_to("joint_trajectory", target, duration=1.2, timeout=30.0)

    def close(self) -> None:
        self._enabling.clear()
        for sub in self._subs:
            with contextlib.suppress(Exception):  # closing anyway
                sub.undeclare() if hasattr(sub, "undeclare") else sub.close()
        self._subs.clear()
        for client in (self.leader, self.follower):
            if client is not None:
                client.close()
        if self._session is not None:
            self._session.close()
        for child in reversed(self._children):
            child.close()
        self._children.clear()


def joint_modes(client: HildClient) -> list[str]:
    """Each joint's mode, or [] when the daemon did not answer in time (a loaded machine): asked again."""
    try:
        return [j["mode"] for j in client.status()["joints"]]
    except HildError:
        return []


# ---- figures --------------------------------------------------------------------------------------------------
def best_shift(t_lead: np.ndarray, lead: np.ndarray, t_follow: np.ndarray, follow: np.ndarray) -> tuple[float, float]:
    """The shift τ (s, 1 ms steps up to ``MAX_SHIFT``) minimising the RMS of follow(t) − lead(t − τ), and that RMS,
    over the follower's samples whose shifted time the leader's cover."""
    best = (math.nan, math.inf)
    for tau in np.arange(0.0, MAX_SHIFT, 0.001):
        at = t_follow - tau
        inside = (at >= t_lead[0]) & (at <= t_lead[-1])
        if inside.sum() < 10:
            continue
        err = follow[inside] - np.interp(at[inside], t_lead, lead)
        rms = float(np.sqrt(np.mean(err * err)))
        if rms < best[1]:
            best = (float(tau), rms)
    return best


def lags(t_lead: np.ndarray, lead: np.ndarray, t_follow: np.ndarray, follow: np.ndarray) -> list[dict[str, float]]:
    """Per joint: the best shift (ms) and the RMS error left after it (mrad); joints that barely moved are skipped."""
    out = []
    for j in range(lead.shape[1]):
        if np.ptp(lead[:, j]) < 0.05:
            continue
        tau, rms = best_shift(t_lead, lead[:, j], t_follow, follow[:, j])
        out.append({"joint": j, "lag_ms": round(tau * 1e3, 1), "rms_mrad": round(rms * 1e3, 2)})
    return out


@dataclass
class Replay:
    times: np.ndarray  # s: each cycle's time on the arrival clock
    command: np.ndarray  # cycles × 6
    written: np.ndarray  # cycles × 6 (bool)
    jumps: int
    worst_step_ratio: float  # the largest |Δ command| / (v_max·T), over cycles written twice in a row
    release_cycles: int | None  # cycles from the release's adoption to every joint in HOLD


def replay(config: Path, relayed: Stream, release_after: float | None) -> Replay:
    """The relayed stream into the follower config in lockstep: each message handed over in the first cycle at or
    after its arrival; the dead-man held (refreshed every cycle) until ``release_after`` s into the stream."""
    loaded = load_config(config)
    loaded.in_lockstep()
    engine = Engine(loaded)
    engine.start()
    try:
        assert engine.switch(["follow"], []).ok
        follow = engine.manager.records["follow"].instance
        assert isinstance(follow, FollowController)
        index = follow._index
        with relayed.lock:
            arrivals, messages = list(relayed.arrival), list(relayed.messages)
        start, period = arrivals[0], engine.period
        vmax = engine.limits.velocity[index]
        cycles = int((arrivals[-1] - start) / period) + 50
        times, commands, written = np.zeros(cycles), np.zeros((cycles, len(index))), np.zeros((cycles, len(index)))
        k, released, release_cycle, hold_cycle = 0, False, None, None
        for c in range(cycles):
            now = c * period
            while k < len(messages) and arrivals[k] - start <= now:
                follow.accept_leader(messages[k])
                k += 1
            if release_after is None or now < release_after:
                follow.accept_enable({"enable": True})
            elif not released:
                follow.accept_enable({"enable": False})
                released, release_cycle = True, c
            engine.run_cycles(1)
            times[c] = start + now
            commands[c] = engine.command.position[index]
            written[c] = engine.command.written[index]
            if released and hold_cycle is None and (engine.supervisor.mode[index] == JointMode.HOLD).all():
                hold_cycle = c
        both = written[1:].astype(bool) & written[:-1].astype(bool)
        steps = np.abs(np.diff(commands, axis=0)) / (vmax * period)
        steps = np.where(both, steps, 0.0)
        return Replay(
            times,
            commands,
            written.astype(bool),
            int((steps > 1.0 + 1e-6).sum()),
            float(steps.max()) if steps.size else 0.0,
            None if release_cycle is None or hold_cycle is None else hold_cycle - release_cycle,
        )
    finally:
        engine.stop()


def run_once(
    directory: Path, delay: float, jitter: float, loss: float, moves: int, seed: int, stream_rate: float
) -> dict[str, Any]:
    with TeleopRig(directory, delay, jitter, loss, seed, stream_rate) as rig:
        rig.engage()
        rig.random_moves(moves, seed)
        moving_end = time.monotonic()
        wait_for(lambda: time.monotonic() > moving_end + 0.5, 5.0, "the follower to settle", every=0.05)
        released = time.monotonic()
        rig.release()
        follower = rig.follower
        assert follower is not None
        wait_for(
            lambda: set(joint_modes(follower)) in ({"hold"}, {"fault"}, {"hold", "fault"}), 30.0, "hold", every=0.002
        )
        release_wall_ms = (time.monotonic() - released) * 1e3
        faults = {j["fault"] for j in follower.status()["joints"] if j.get("fault")}
        if faults:  # its figures are not the follower's: say why, as the run's error
            raise RuntimeError(f"the follower faulted during the run: {'; '.join(sorted(faults))}")
        t_l, p_l = rig.leader_stream.arrays()
        t_f, p_f = rig.follower_stream.arrays()
        relayed = rig.relayed_stream
    measured = lags(t_l, p_l, t_f, p_f)
    replayed = replay(rig.follower_config, relayed, release_after=None)
    control_period = 1.0 / load_config(rig.follower_config).config.update_rate
    command = lags(
        t_l, p_l, replayed.times[replayed.written.all(axis=1)], replayed.command[replayed.written.all(axis=1)]
    )
    moving = relayed.arrival[-1] - relayed.arrival[0]
    release = replay(rig.follower_config, relayed, release_after=0.6 * moving)
    seqs = np.array(relayed.seq)
    sent = dict(zip(rig.leader_stream.seq, rig.leader_stream.arrival, strict=True))
    transit = [a - sent[q] for q, a in zip(relayed.seq, relayed.arrival, strict=True) if q in sent]
    return {
        "relay_ms": {
            "p50": round(float(np.percentile(transit, 50)) * 1e3, 1) if transit else math.nan,
            "p99": round(float(np.percentile(transit, 99)) * 1e3, 1) if transit else math.nan,
        },
        "delay_ms": delay * 1e3,
        "jitter_ms": jitter * 1e3,
        "loss_pct": loss * 100.0,
        "stream_rate_hz": stream_rate,
        "stream_period_ms": 1e3 / stream_rate,
        "control_period_ms": control_period * 1e3,
        "samples": {"leader": len(t_l), "relayed": len(relayed.arrival), "lost_seq": int(np.sum(np.diff(seqs) - 1))},
        "lag_measured": measured,
        "lag_measured_worst_ms": max((m["lag_ms"] for m in measured), default=math.nan),
        "lag_command": command,
        "lag_command_worst_ms": max((m["lag_ms"] for m in command), default=math.nan),
        "jumps": replayed.jumps,
        "worst_step_of_vmax_T": round(replayed.worst_step_ratio, 3),
        "deadman_hold_cycles": release.release_cycles,
        "deadman_release_to_hold_status_ms": round(release_wall_ms, 1),
    }


def run_teleop(settings: TeleopSettings, workdir: Path | None = None) -> dict[str, Any]:
    runs = []
    control_rate = float(yaml.safe_load((CONFIGS / "arm6_leader_twin.yaml").read_text())["update_rate"])
    conditions = (
        ("no delay", 0.0, 0.0, 0.0),
        (
            f"{settings.delay * 1e3:g} ms, {settings.loss * 100:g} % loss",
            settings.delay,
            settings.jitter,
            settings.loss,
        ),
    )
    with TemporaryDirectory(prefix="hild-teleop-") as tmp:
        base = workdir or Path(tmp)
        for stream_rate, judged in ((control_rate, True), (REPORTED_STREAM_RATE, False)):
            for condition, delay, jitter, loss in conditions:
                name = f"{condition} @ {stream_rate:g} Hz"
                directory = base / name.replace(" ", "_").replace(",", "").replace("%", "pct").replace("@", "at")
                directory.mkdir(parents=True, exist_ok=True)
                try:
                    row = run_once(directory, delay, jitter, loss, settings.moves, settings.seed, stream_rate)
                except Exception as exc:
                    row = {"error": f"{type(exc).__name__}: {exc}", "delay_ms": delay * 1e3, "loss_pct": loss * 100}
                runs.append({"run": name, "judged": judged, "control_period_ms": 1e3 / control_rate, **row})
    report: dict[str, Any] = {"runs": runs}
    report["targets"] = teleop_targets(report)
    return report


def teleop_targets(report: dict[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for run in report["runs"]:
        if not run.get("judged", True):
            continue  # reported beside the judged runs (format_teleop), not a target's
        scenario = run["run"]
        error = run.get("error")
        limit = 2 * run["control_period_ms"] + run["delay_ms"]
        basis = (
            f"2 control periods + one-way delay ({run['delay_ms']:g} ms), the leader streaming at the control rate;"
            " the follower's command, worst joint"
        )
        rows.append(
            target_row(
                "joint lag",
                run.get("lag_command_worst_ms"),
                limit,
                "ms",
                basis,
                scenario=scenario,
                group=GROUP,
                error=error,
            )
        )
        rows.append(
            target_row(
                "jumps (command > v_max·T)",
                run.get("jumps"),
                0,
                "",
                "lockstep replay of the relayed stream",
                scenario=scenario,
                group=GROUP,
                error=error,
            )
        )
        rows.append(
            target_row(
                "dead-man release → hold",
                run.get("deadman_hold_cycles"),
                2,
                "cycles",
                "from the release's adoption to every joint HOLD (replay)",
                scenario=scenario,
                group=GROUP,
                error=error,
            )
        )
    return rows


def format_teleop(report: dict[str, Any]) -> str:
    lines = ["TELEOP (two arm6 twins on loopback, the relay between them; leader: random moves, ~0.6 rad/s)"]
    for run in report["runs"]:
        if "error" in run:
            lines.append(f"  {run['run']}: error: {run['error']}{'' if run.get('judged', True) else ' (not judged)'}")
            continue
        s = run["samples"]
        note = "" if run.get("judged", True) else " (not judged)"
        lines.append(
            f"  {run['run']:<30}{note} lag measured {run['lag_measured_worst_ms']:g} ms,"
            f" command {run['lag_command_worst_ms']:g} ms"
            f" (worst joint); jumps {run['jumps']} (worst step {run['worst_step_of_vmax_T']} v_max·T);"
            f" dead-man → hold {run['deadman_hold_cycles']} cycles (release sent → status says hold:"
            f" {run['deadman_release_to_hold_status_ms']} ms); samples {s['leader']} leader,"
            f" {s['relayed']} relayed, {s['lost_seq']} lost; relay transit p50 {run['relay_ms']['p50']} ms,"
            f" p99 {run['relay_ms']['p99']} ms"
        )
    return "\n".join(lines)
