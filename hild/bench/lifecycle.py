"""The cycle's overruns while controllers are loaded, configured, unloaded and re-parametrised (issue [runtime]).

``hild run`` on the arm6 twin (configs/arm6_twin.yaml at ``--rate``, wall clock, the cycle in its own process);
a client alternates two kinds of window, ``--rounds`` times each, interleaved so the machine's own drift shows in
both:

* ``quiet``: five read-only queries (``list_controllers``, ``get_parameters``) per period;
* ``lifecycle``: per period, ``load_controller`` (a forward_command), ``configure_controller``, ``set_parameters``
  on joint_trajectory (``constraints.goal_time``) and on ``controller_manager`` (a hold gain), then
  ``unload_controller`` — each applied by the cycle between two cycles, after its write.

``--rate`` sequences per second (default 2: a tuning session or a spawner is slower); ``--rate 0`` sends them
back to back, a stress of the client domain as much as of the cycle (on two shared cores every query the
client domain serves takes CPU from the cycle: compare it with the quiet window at the same query rate).

Reported: overruns per 10 000 cycles in each kind of window (the daemon's own count: a cycle that ended after the
next one was due) and how many lifecycle operations ran. The target: lifecycle ≤ quiet + 1 per 10 000. A
benchmark, never a test: the numbers measure the machine as much as hild (docs/performance.md).

    python -m hild.bench.lifecycle                          # 1 kHz, 2 sequences/s, 3 rounds of 2 × 20 s
    python -m hild.bench.lifecycle --update-rate 500 --seconds 10 --rounds 2 --json lifecycle.json
    python -m hild.bench.lifecycle --rate 0                 # back to back
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hild.api.client import HildClient
from hild.bench.children import free_endpoint
from hild.bench.daemon import HildRun
from hild.bench.scenarios import arm6_config

JTC = "joint_trajectory"
WARMUP = 3.0  # s after start before the first window
TARGET_PER_10K = 1.0  # lifecycle may add at most this many overruns per 10 000 cycles


@dataclass
class Window:
    kind: str
    seconds: float
    cycles: int
    overruns: int
    operations: int  # lifecycle: load…unload sequences; quiet: read queries

    @property
    def per_10k(self) -> float:
        return 1e4 * self.overruns / max(1, self.cycles)


@dataclass
class Report:
    update_rate: float
    rate: float  # load…unload sequences (quiet: query batches) per second; 0: back to back
    seconds: float
    rounds: int
    priority: int = 0  # the cycle's SCHED_FIFO priority (0: normal scheduling)
    windows: list[Window] = field(default_factory=list)

    def total(self, kind: str) -> tuple[int, int, int]:
        chosen = [w for w in self.windows if w.kind == kind]
        return (sum(w.cycles for w in chosen), sum(w.overruns for w in chosen), sum(w.operations for w in chosen))

    def per_10k(self, kind: str) -> float:
        cycles, overruns, _ = self.total(kind)
        return 1e4 * overruns / max(1, cycles)

    @property
    def passed(self) -> bool:
        return self.per_10k("lifecycle") <= self.per_10k("quiet") + TARGET_PER_10K


def _loop(client: HildClient) -> tuple[int, int]:
    loop = client.status()["loop"]
    return int(loop["cycles"]), int(loop["overruns"])


def _lifecycle_round(client: HildClient, k: int, joints: list[str], kp: float) -> int:
    """One load … unload sequence: the queries a tuning session sends. Returns how many it sent."""
    name = f"bench_fwd_{k}"
    client.load_controller(name, "forward_command", {"joints": joints[:3], "command_timeout": 0.2})
    client.configure_controller(name)
    client.set_parameters(JTC, {"constraints.goal_time": 0.5 + 0.1 * (k % 2)})
    client.set_parameters("controller_manager", {f"joints.{joints[0]}.hold.kp": kp * (1.0 + 0.01 * (k % 2))})
    client.unload_controller(name)
    return 5


def _quiet_round(client: HildClient) -> int:
    for _ in range(2):
        client.list_controllers()
        client.get_parameters(JTC, ["constraints.goal_time"])
    client.list_controllers()
    return 5


def measure(update_rate: float, rate: float, seconds: float, rounds: int, priority: int = 0) -> Report:
    report = Report(update_rate, rate, seconds, rounds, priority)
    with tempfile.TemporaryDirectory(prefix="hild-lifecycle-") as tmp:
        config = Path(tmp) / "arm6.yaml"
        data = arm6_config("twin", update_rate)
        if priority:  # as on a robot PC (systemd grants it): the client domain's work cannot preempt the cycle
            data.setdefault("realtime", {})["priority"] = priority
        config.write_text(yaml.safe_dump(data, sort_keys=False))
        joints = list(data["joints"])
        kp = float(data["joints"][joints[0]]["hold"]["kp"])
        with HildRun(config, free_endpoint(), data["robot"]["name"]) as run, run.client(timeout=5.0) as client:
            time.sleep(WARMUP)
            k = 0
            for _ in range(rounds):
                for kind in ("quiet", "lifecycle"):
                    cycles0, overruns0 = _loop(client)
                    start = time.monotonic()
                    operations = 0
                    batches = 0
                    while time.monotonic() - start < seconds:
                        if kind == "lifecycle":
                            operations += _lifecycle_round(client, k, joints, kp)
                            k += 1
                        else:
                            operations += _quiet_round(client)
                        batches += 1
                        if rate > 0:  # on an absolute schedule, so a slow batch does not slow the rate after it
                            time.sleep(max(0.0, start + batches / rate - time.monotonic()))
                    cycles1, overruns1 = _loop(client)
                    elapsed = time.monotonic() - start
                    report.windows.append(Window(kind, elapsed, cycles1 - cycles0, overruns1 - overruns0, operations))
            run.stop()
    return report


def render(report: Report) -> str:
    pace = f"{report.rate:g} per second" if report.rate > 0 else "back to back"
    lines = [
        f"arm6 twin at {report.update_rate:g} Hz, {report.rounds} rounds of 2 × {report.seconds:g} s, "
        f"sequences (quiet: batches of 5 reads) {pace}, cycle "
        + (f"SCHED_FIFO {report.priority}" if report.priority else "at normal priority")
    ]
    for kind in ("quiet", "lifecycle"):
        cycles, overruns, operations = report.total(kind)
        lines.append(
            f"{kind:>9}: {overruns} overruns in {cycles} cycles = {report.per_10k(kind):.2f} /10k "
            f"({operations} queries{' in load…unload sequences of 5' if kind == 'lifecycle' else ''})"
        )
    verdict = "PASS" if report.passed else "MISS"
    lines.append(
        f"{verdict}: lifecycle {report.per_10k('lifecycle'):.2f} /10k vs quiet {report.per_10k('quiet'):.2f} "
        f"+ {TARGET_PER_10K:g} /10k"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update-rate", type=float, default=1000.0, help="the cycle's rate in Hz (default 1000)")
    parser.add_argument("--rate", type=float, default=2.0, help="sequences per second (default 2; 0: back to back)")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each window (default 20)")
    parser.add_argument("--rounds", type=int, default=3, help="quiet + lifecycle windows, interleaved (default 3)")
    parser.add_argument("--priority", type=int, default=0, help="realtime.priority for the cycle (default 0: normal)")
    parser.add_argument("--json", metavar="OUT", help="also write the report as JSON")
    args = parser.parse_args(argv)
    report = measure(args.update_rate, args.rate, args.seconds, args.rounds, args.priority)
    print(render(report))
    if args.json:
        data: dict[str, Any] = asdict(report)
        data["per_10k"] = {kind: report.per_10k(kind) for kind in ("quiet", "lifecycle")}
        Path(args.json).write_text(json.dumps(data, indent=2))
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
