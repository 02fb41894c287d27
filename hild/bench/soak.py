"""Soak: a real daemon for N minutes at 1 kHz under random trajectories, servo streams and injected faults.

    hild bench --only soak                                # arm6 twin at 1 kHz for 3 min (--quick 20 s, --seconds S)
    python -m hild.bench.soak --minutes 3                 # arm6 twin at 1 kHz, seed 1
    python -m hild.bench.soak --minutes 30 --seed 7 --json soak.json
    python -m hild.bench.soak --minutes 3 --backend can   # Damiao drives emulated in their own process (500 Hz)

``twin``: ``hild run`` on configs/arm6_twin.yaml at ``--rate`` (1 ms physics steps) on the wall clock. ``can``:
``hild emulate`` + ``hild run`` on configs/arm6_can_loopback.yaml (one bus of six motors carries 500 Hz at most),
both started by :mod:`hild.bench.daemon`.
Everything goes through the Zenoh client, as a user's program would, from one seeded random schedule:

* trajectory goals — move_to, timed and untimed trajectories around the start pose — waited for, some preempted by
  the next goal, some canceled;
* servo streams: 1–2 s of 100 Hz targets, then silence until servo's timeout stops the arm;
* faults, then recovery: e-stop and reset (mid-goal at times); a second client that sends a goal and disappears
  (its goal must be stopped and report so); on ``can`` also a random Damiao error on a random drive, cleared with
  reset and enable.

Reported: the daemon's memory (RSS after the warm-up, at the end, the largest, and the growth over the second half
per minute), its cycles and overruns, queries that got no reply ("missed"), queries refused, goals sent and how
each ended, and lost goals — accepted, but no result ever came. The daemon must still answer at the end and exit 0
on SIGINT. tests/faults/test_soak.py runs a short version in CI.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import math
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from drivers.can.emulator.runtime import request
from hild.api.client import GoalHandle, HildClient, HildError, HildUnreachable
from hild.bench.children import free_endpoint
from hild.bench.daemon import CanProcesses, HildRun
from hild.bench.scenarios import arm6_config

JTC, SERVO = "joint_trajectory", "servo"
WARMUP = 3.0  # s of goals before the memory baseline is taken
RESULT_TIMEOUT = 30.0  # s a goal may take to report after its motion should have ended
SPREAD = 0.35  # rad: random targets lie within this of the start pose
DAMIAO_ERRORS = (0x5, 0x6, 0x8, 0x9, 0xA, 0xB, 0xC, 0xE)


@dataclass
class Report:
    backend: str
    seconds: float
    rate: float
    seed: int
    cycles: int = 0
    overruns: int = 0
    queries: int = 0
    missed_replies: int = 0  # a query nobody answered (timeout, unreachable)
    refused: int = 0  # answered, ok: false
    goals_sent: int = 0
    goals_accepted: int = 0
    results: dict[str, int] = field(default_factory=dict)
    lost_goals: list[str] = field(default_factory=list)  # accepted, no result ever came
    servo_streams: int = 0
    estops: int = 0
    client_losses: int = 0
    drive_faults: int = 0
    unexpected_faults: list[str] = field(default_factory=list)  # found at a step's start (e.g. an overrun burst)
    rss_start_mb: float = 0.0
    rss_end_mb: float = 0.0
    rss_max_mb: float = 0.0
    rss_slope_mb_per_min: float = 0.0  # over the second half of the run
    alive_at_end: bool = False
    exit_code: int | None = None
    problems: list[str] = field(default_factory=list)

    @property
    def rss_growth_mb(self) -> float:
        return self.rss_end_mb - self.rss_start_mb

    @property
    def passed(self) -> bool:
        """Nothing lost, every query answered, the daemon alive at the end and exiting 0 on SIGINT."""
        return not self.lost_goals and not self.missed_replies and self.alive_at_end and self.exit_code == 0

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "rss_growth_mb": self.rss_growth_mb, "passed": self.passed}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Report:
        """The report ``as_dict`` gave (for the text of a JSON report)."""
        return cls(**{f.name: data[f.name] for f in fields(cls) if f.name in data})

    def text(self) -> str:
        ended = ", ".join(f"{k} {v}" for k, v in sorted(self.results.items())) or "none"
        lines = [
            f"soak: {self.seconds:g} s at {self.rate:g} Hz ({self.backend}), seed {self.seed}",
            f"cycles {self.cycles}, overruns {self.overruns}",
            f"goals: sent {self.goals_sent}, accepted {self.goals_accepted}, ended: {ended}; "
            f"lost {len(self.lost_goals)}",
            f"servo streams {self.servo_streams}, e-stops {self.estops}, clients lost {self.client_losses}, "
            f"drive faults {self.drive_faults}; faults nobody injected: {len(self.unexpected_faults)}",
            f"queries {self.queries}: missed replies {self.missed_replies}, refused {self.refused}",
            f"daemon RSS: {self.rss_start_mb:.1f} MB after warm-up → {self.rss_end_mb:.1f} MB "
            f"({self.rss_growth_mb:+.1f} MB; max {self.rss_max_mb:.1f} MB; second half "
            f"{self.rss_slope_mb_per_min:+.2f} MB/min)",
            f"daemon alive at the end: {self.alive_at_end}; exit code on SIGINT: {self.exit_code}",
        ]
        lines += [f"unexpected fault: {f}" for f in self.unexpected_faults]
        lines += [f"problem: {p}" for p in self.problems]
        return "\n".join(lines)


class Memory(threading.Thread):
    """Samples a process's resident set once a second."""

    def __init__(self, pid: int) -> None:
        super().__init__(name="soak-rss", daemon=True)
        self.pid = pid
        self.samples: list[tuple[float, float]] = []  # (monotonic s, MB)
        self.stop = threading.Event()

    def rss(self) -> float:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
        return math.nan

    def run(self) -> None:
        while not self.stop.is_set():
            with contextlib.suppress(OSError, ValueError):
                self.samples.append((time.monotonic(), self.rss()))
            self.stop.wait(1.0)


# ---- the daemon ---------------------------------------------------------------------------------------------------
class TwinDaemon:
    """``hild run`` on the arm6 twin at ``rate`` (1 ms physics steps), in ``directory``."""

    def __init__(self, directory: Path, rate: float) -> None:
        config = directory / "soak.yaml"
        config.write_text(json.dumps(arm6_config("twin", rate), indent=1))  # JSON is YAML
        self.run = HildRun(config, free_endpoint(), "arm6", cwd=directory)
        self.endpoint = self.run.endpoint

    def start(self) -> HildClient:
        return self.run.connected()

    def inject_drive_fault(self, rng: random.Random) -> str | None:
        return None  # the twin has no drives to fault

    def close(self) -> None:
        self.run.close()


class CanDaemon:
    """``hild emulate`` and ``hild run`` on configs/arm6_can_loopback.yaml (:class:`hild.bench.daemon.CanProcesses`)."""

    def __init__(self, directory: Path, rate: float) -> None:
        self.processes = CanProcesses(directory)
        if rate != 500.0:
            text = self.processes.config.read_text().replace("update_rate: 500", f"update_rate: {rate:g}")
            self.processes.config.write_text(text)
        self.endpoint = self.processes.endpoint

    @property
    def run(self) -> HildRun:
        assert self.processes.run is not None
        return self.processes.run

    def start(self) -> HildClient:
        return self.processes.start_daemon()

    def inject_drive_fault(self, rng: random.Random) -> str | None:
        joint = rng.choice([j["name"] for j in self.processes.drives()])
        reply = request(self.processes.control, {"op": "fault", "joint": joint, "code": rng.choice(DAMIAO_ERRORS)})
        return joint if reply.get("ok") else None

    def close(self) -> None:
        self.processes.close()


# ---- the schedule -------------------------------------------------------------------------------------------------
class Soak:
    def __init__(self, daemon: TwinDaemon | CanDaemon, client: HildClient, report: Report, rng: random.Random) -> None:
        self.daemon = daemon
        self.client = client
        self.report = report
        self.rng = rng
        self.results: collections.Counter[str] = collections.Counter()
        self._states: dict[str, Any] = {}
        self._subscription = client.subscribe("joint_states", self._states.update)
        self.home = self.positions()
        self.names: list[str] = list(self._states["name"])

    # ---- queries, counted -----------------------------------------------------------------------------------------
    def ask(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """One query; a reply that never comes is a missed reply, ok: false a refusal. Returns None then."""
        self.report.queries += 1
        try:
            return fn(*args, **kwargs)
        except HildUnreachable as exc:
            self.report.missed_replies += 1
            self.report.problems.append(f"missed reply: {exc}")
        except HildError:
            self.report.refused += 1
        return None

    def positions(self) -> list[float]:
        deadline = time.monotonic() + 10.0
        while "position" not in self._states:
            if time.monotonic() > deadline:
                raise RuntimeError("no joint_states from the daemon")
            time.sleep(0.01)
        return list(self._states["position"])

    def status(self) -> dict[str, Any]:
        return self.ask(self.client.status) or {}

    def wait_mode(self, *modes: str, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.status().get("mode") in modes:
                return True
            time.sleep(0.05)
        self.report.problems.append(f"the daemon never reached mode {' or '.join(modes)}")
        return False

    def ensure_trajectory(self) -> None:
        controllers = {c["name"]: c["state"] for c in self.ask(self.client.list_controllers) or []}
        if controllers.get(JTC) != "active":
            self.ask(
                self.client.switch, activate=[JTC], deactivate=[n for n in (SERVO,) if controllers.get(n) == "active"]
            )

    # ---- goals ------------------------------------------------------------------------------------------------
    def target(self) -> list[float]:
        return [h + self.rng.uniform(-SPREAD, SPREAD) for h in self.home]

    def random_goal(self) -> dict[str, Any]:
        kind = self.rng.random()
        if kind < 0.4:
            goal: dict[str, Any] = {"positions": self.target()}
            if self.rng.random() < 0.3:
                goal["duration"] = self.rng.uniform(0.5, 2.0)
            return goal
        count = self.rng.randint(2, 5)
        points: list[dict[str, Any]] = [{"positions": self.target()} for _ in range(count)]
        if kind < 0.75:  # timed: slow enough for the limits
            for k, point in enumerate(points):
                point["time_from_start"] = 1.0 + 0.8 * k
        return {"trajectory": {"joint_names": self.names, "points": points}}

    def send(self, goal: dict[str, Any], client: HildClient | None = None, watched: bool = True) -> GoalHandle | None:
        self.report.goals_sent += 1
        handle = self.ask((client or self.client).send_goal, JTC, goal, watched=watched)
        if handle is not None:
            self.report.goals_accepted += 1
        return handle

    def settle(self, handle: GoalHandle) -> None:
        """Wait for the goal's result; none within the timeout makes it a lost goal."""
        try:
            result = handle.wait(RESULT_TIMEOUT)
        except HildUnreachable as exc:
            self.report.missed_replies += 1
            self.report.problems.append(f"missed reply while waiting for goal {handle.goal_id}: {exc}")
            self.report.lost_goals.append(handle.goal_id)
        except HildError:
            self.report.lost_goals.append(handle.goal_id)
        else:
            self.results[str(result.get("status"))] += 1
        finally:
            handle.close()

    def goal(self) -> None:
        self.ensure_trajectory()
        handle = self.send(self.random_goal())
        if handle is None:
            return
        roll = self.rng.random()
        if roll < 0.15:  # preempted by the next goal
            time.sleep(self.rng.uniform(0.05, 0.5))
            second = self.send({"positions": self.target()})
            self.settle(handle)
            if second is not None:
                self.settle(second)
            return
        if roll < 0.3:
            time.sleep(self.rng.uniform(0.05, 0.5))
            self.ask(handle.cancel)
        self.settle(handle)

    # ---- servo ------------------------------------------------------------------------------------------------
    def servo_stream(self) -> None:
        controllers = {c["name"]: c["state"] for c in self.ask(self.client.list_controllers) or []}
        deactivate = [JTC] if controllers.get(JTC) == "active" else []
        if self.ask(self.client.switch, activate=[SERVO], deactivate=deactivate) is None:
            return
        self.report.servo_streams += 1
        stream = self.client.servo_stream(SERVO)
        start, phase = self.positions(), self.rng.uniform(0, math.tau)
        amplitude, frequency = self.rng.uniform(0.05, 0.3), self.rng.uniform(0.2, 1.0)
        began = time.monotonic()
        length = self.rng.uniform(1.0, 2.0)
        while (t := time.monotonic() - began) < length:
            offset = amplitude * (math.sin(math.tau * frequency * t + phase) - math.sin(phase))
            stream.send([p + offset for p in start])
            time.sleep(0.01)
        time.sleep(0.6)  # silence: servo's command_timeout (0.25 s) stops the arm, jerk-limited
        self.ensure_trajectory()

    # ---- faults -----------------------------------------------------------------------------------------------
    def estop(self) -> None:
        self.ensure_trajectory()
        handle = self.send({"positions": self.target()}) if self.rng.random() < 0.5 else None
        time.sleep(self.rng.uniform(0.05, 0.4))
        if self.ask(self.client.estop) is None:
            return
        self.report.estops += 1
        self.wait_mode("estop")
        if handle is not None:
            self.settle(handle)  # aborted: its controller was deactivated
        self.ask(self.client.reset)
        self.wait_mode("hold")
        self.ensure_trajectory()

    def client_loss(self) -> None:
        self.ensure_trajectory()
        other = HildClient("arm6", connect=[self.daemon.endpoint], timeout=5.0)
        handle = self.send({"positions": self.target(), "duration": 3.0}, client=other)
        if handle is None:
            other.close()
            return
        handle.close()
        time.sleep(self.rng.uniform(0.1, 0.5))
        other.close()  # gone mid-goal: the daemon must stop the goal and say so
        self.report.client_losses += 1
        deadline = time.monotonic() + RESULT_TIMEOUT
        while time.monotonic() < deadline:
            result = self.ask(self.client.goal_result, JTC, handle.goal_id)
            if result is not None and result.get("status") != "executing":
                self.results[str(result["status"])] += 1
                if result["status"] not in ("aborted", "succeeded"):
                    self.report.problems.append(f"a lost client's goal ended {result['status']}")
                return
            time.sleep(0.05)
        self.report.lost_goals.append(handle.goal_id)

    def drive_fault(self) -> None:
        joint = self.daemon.inject_drive_fault(self.rng)
        if joint is None:
            return
        self.report.drive_faults += 1
        self.wait_mode("fault")
        for _ in range(3):  # in-flight replies can re-report the error once (docs/safety.md)
            self.ask(self.client.reset)
            time.sleep(0.3)
            faults = [j["fault"] or "" for j in self.status().get("joints", [])]
            if all(not f or "disabled" in f for f in faults):
                break
        time.sleep(0.5)  # an operator's pause before enabling
        self.ask(self.client.call, "enable")
        self.wait_mode("hold", "active")
        self.ensure_trajectory()

    # ---- the run ----------------------------------------------------------------------------------------------
    def recover_unexpected(self) -> None:
        """A fault nobody injected (an overrun burst on a loaded machine): note it, reset, carry on."""
        status = self.status()
        if status.get("mode") != "fault":
            return
        texts = sorted({j["fault"] for j in status.get("joints", []) if j.get("fault")})
        self.report.unexpected_faults.append("; ".join(texts))
        self.ask(self.client.reset)
        self.wait_mode("hold", "active")

    def step(self) -> None:
        self.recover_unexpected()
        roll = self.rng.random()
        if roll < 0.6:
            self.goal()
        elif roll < 0.75:
            self.servo_stream()
        elif roll < 0.85:
            self.estop()
        elif roll < 0.93 or isinstance(self.daemon, TwinDaemon):
            self.client_loss()
        else:
            self.drive_fault()
        self.status()

    def close(self) -> None:
        self.report.results = dict(self.results)
        self._subscription.close()


def run_soak(seconds: float, rate: float = 1000.0, backend: str = "twin", seed: int = 1) -> Report:
    report = Report(backend, seconds, rate, seed)
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory(prefix="hild-soak-") as tmp:
        daemon: TwinDaemon | CanDaemon = (
            TwinDaemon(Path(tmp), rate) if backend == "twin" else CanDaemon(Path(tmp), rate)
        )
        try:
            client = daemon.start()
            memory = Memory(daemon.run.pid)
            memory.start()
            try:
                soak = Soak(daemon, client, report, rng)
                warm_until = time.monotonic() + WARMUP
                while time.monotonic() < warm_until:
                    soak.goal()
                baseline = memory.rss()
                first = soak.status().get("loop", {})
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    soak.step()
                last = soak.status()
                soak.close()
                report.alive_at_end = daemon.run.process.poll() is None and bool(last.get("ok"))
                loop = last.get("loop", {})
                report.cycles = int(loop.get("cycles", 0)) - int(first.get("cycles", 0))
                report.overruns = int(loop.get("overruns", 0)) - int(first.get("overruns", 0))
                report.rss_start_mb, report.rss_end_mb = baseline, memory.rss()
            finally:
                memory.stop.set()
                memory.join(5.0)
                client.close()
            samples = [(t, mb) for t, mb in memory.samples if not math.isnan(mb)]
            report.rss_max_mb = max((mb for _, mb in samples), default=math.nan)
            report.rss_slope_mb_per_min = _slope(samples[len(samples) // 2 :]) * 60.0
            try:
                report.exit_code = daemon.run.stop(30.0, signal.SIGINT)
            except subprocess.TimeoutExpired:
                report.problems.append("the daemon did not exit within 30 s of SIGINT")
            if report.exit_code != 0:
                report.problems.append(f"daemon log:\n{daemon.run.log[-4000:]}")
        finally:
            daemon.close()
    return report


def _slope(samples: list[tuple[float, float]]) -> float:
    """Least-squares MB per second over the samples (0 with fewer than two)."""
    if len(samples) < 2:
        return 0.0
    t, mb = np.array(samples).T
    return float(np.polyfit(t - t[0], mb, 1)[0])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=3.0)
    parser.add_argument("--rate", type=float, default=None, help="Hz (default: 1000 on twin, 500 on can)")
    parser.add_argument("--backend", choices=["twin", "can"], default="twin")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    rate = args.rate or (1000.0 if args.backend == "twin" else 500.0)
    report = run_soak(args.minutes * 60.0, rate, args.backend, args.seed)
    print(report.text())
    if args.json:
        args.json.write_text(json.dumps(report.as_dict(), indent=2))
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
