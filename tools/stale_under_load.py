"""Stale detection on a loaded host (issue [trust], finding 7): the loopback CAN rig under CPU hogs.

Starts ``hild emulate`` (Damiao drives, arm6 twin behind them) and ``hild run`` on a copy of
configs/arm6_can_loopback.yaml (free ports, 127.0.0.1 only), starts ``--hogs`` busy processes, runs back-and-forth
moves of every joint for ``--seconds``, and prints per joint the longest stretch without an accepted reading the
daemon saw (status ``longest_silence_ms``) and any fault, the goals' results, and where a gap could come from: the
emulator loop's worst lateness (its control ``status``) and the daemon cycle's worst period error. Then it cuts
``--silent-joint``'s transceiver (the hogs still running) and measures how long the daemon takes to fault it.

    python tools/stale_under_load.py                      # 2 hogs, 20 s of moves, then shoulder_lift silent
    python tools/stale_under_load.py --hogs 0             # the idle reference
    python tools/stale_under_load.py --stale-cycles 50 --stale-time 0   # the settings of the finding
    python tools/stale_under_load.py --emulator-priority 0              # the emulator at normal priority

Exit status 1 if a joint faulted during the moves (or the silenced joint was not detected). Every process it
starts is stopped on exit, Ctrl-C and SIGTERM included; the hogs also die with this process and end on their own
after the run's time bound.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from drivers.can.emulator.runtime import request
from hild.bench.daemon import CanProcesses
from hild.bench.hogs import start_hogs

MOVE = 0.4  # rad, every joint, back and forth
POLL = 0.005  # s between status polls while waiting for the silent joint's fault
DETECT_TIMEOUT = 5.0  # s: a silenced joint not faulted by then counts as not detected


@dataclass
class Report:
    """What one run measured."""

    hogs: int
    safety: dict[str, Any]
    realtime: dict[str, str]
    goals: Counter[str] = field(default_factory=Counter)
    goal_error: str = ""
    joints: list[dict[str, Any]] = field(default_factory=list)
    emulator_loop: dict[str, Any] = field(default_factory=dict)
    daemon_loop: dict[str, Any] = field(default_factory=dict)
    silent_joint: str = ""
    emulator_priority: str = ""
    detected_after: float | None = None
    detected_fault: str = ""

    @property
    def faulted(self) -> bool:
        return any(j["fault"] for j in self.joints)


def patch_config(path: Path, args: argparse.Namespace) -> None:
    """The run's overrides on the copy of the loopback config."""
    data = yaml.safe_load(path.read_text())
    if args.stale_cycles is not None:
        data["safety"]["stale_feedback_cycles"] = args.stale_cycles
    if args.stale_time is not None:
        data["safety"]["stale_feedback_time"] = args.stale_time
    if args.priority is not None:
        data.setdefault("realtime", {})["priority"] = args.priority
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def _emulator_priority(rigs: CanProcesses) -> str:
    """The emulator's scheduling, as the kernel has it."""
    pid = rigs.emulator.pid
    if os.sched_getscheduler(pid) == os.SCHED_FIFO:
        return f"SCHED_FIFO {os.sched_getparam(pid).sched_priority}"
    return "normal (SCHED_OTHER)"


def moves(client: Any, seconds: float) -> tuple[Counter[str], str]:
    """Back and forth by MOVE on every joint until ``seconds`` pass or a joint faults; the goals' results and the
    first failed goal's error."""
    client.switch(activate=["joint_trajectory"])
    start = list(client.next_message("joint_states", timeout=5.0)["position"])
    results: Counter[str] = Counter()
    deadline = time.monotonic() + seconds
    count, first_error = 0, ""
    while time.monotonic() < deadline and client.status()["mode"] != "fault":
        away = [p + MOVE for p in start] if count % 2 == 0 else start
        result = client.move_to("joint_trajectory", away, timeout=30.0)
        results[str(result.get("status"))] += 1
        first_error = first_error or str(result.get("error_string") or "")
        count += 1
    return results, first_error


def silent_detection(rigs: CanProcesses, client: Any, joint: str) -> tuple[float | None, str]:
    """Seconds from cutting ``joint``'s transceiver to its fault in status, and the fault's text."""
    names = [j["name"] for j in client.status()["joints"]]
    i = names.index(joint)
    start = time.monotonic()
    request(rigs.control, {"op": "set", "joint": joint, "silent": True})
    while time.monotonic() - start < DETECT_TIMEOUT:
        fault = client.status()["joints"][i]["fault"]
        if fault:
            return time.monotonic() - start, str(fault)
        time.sleep(POLL)
    return None, ""


def measure(rigs: CanProcesses, args: argparse.Namespace) -> Report:
    """Moves under the hogs, the figures of the gap's possible sources, then the silent joint."""
    client = rigs.start_daemon()
    try:
        status = client.status()
        safety = yaml.safe_load(rigs.config.read_text())["safety"]
        report = Report(args.hogs, safety, dict(status.get("realtime", {})), silent_joint=args.silent_joint)
        busy = start_hogs(args.hogs, args.seconds + DETECT_TIMEOUT + 30.0)
        try:
            time.sleep(0.5)  # let the hogs take their share before the first move
            report.emulator_priority = _emulator_priority(rigs)
            report.goals, report.goal_error = moves(client, args.seconds)
            status = client.status()
            report.joints = status["joints"]
            report.realtime = dict(status.get("realtime", {}))
            report.daemon_loop = status["loop"]
            report.emulator_loop = request(rigs.control, {"op": "status"})["loop"]
            if not report.faulted and args.silent_joint:
                client.switch(deactivate=["joint_trajectory"])
                report.detected_after, report.detected_fault = silent_detection(rigs, client, args.silent_joint)
        finally:
            for proc in busy:
                proc.kill()
                proc.wait()
        return report
    finally:
        client.close()


def render(report: Report) -> str:
    """The table, one line per joint, then the sources and the detection."""
    s = report.safety
    lines = [
        f"{report.hogs} CPU hogs; stale_feedback_cycles {s['stale_feedback_cycles']}, "
        f"stale_feedback_time {s.get('stale_feedback_time', 0)} s; daemon cycle "
        f"{report.realtime.get('priority', '?')}, emulator {report.emulator_priority}",
        "goals: "
        + ", ".join(f"{n} {status}" for status, n in sorted(report.goals.items()))
        + (f" (first error: {report.goal_error})" if report.goal_error else ""),
        f"  {'joint':<14} {'longest silence':>16}  fault",
    ]
    for j in report.joints:
        lines.append(f"  {j['name']:<14} {j['longest_silence_ms']:13.1f} ms  {j['fault'] or '-'}")
    period_error = report.daemon_loop.get("period_error_us", {})
    emu = report.emulator_loop
    lines.append(
        f"emulator loop: worst lateness {emu.get('max_late_ms', 0):.1f} ms, {emu.get('overruns', 0)} overruns "
        f"in {emu.get('services', 0)} services; daemon cycle: worst period error "
        f"{period_error.get('max', 0) / 1000:.1f} ms, {report.daemon_loop.get('overruns', 0)} overruns"
    )
    if report.detected_after is not None:
        lines.append(
            f"{report.silent_joint} silenced: faulted after {report.detected_after * 1000:.0f} ms "
            f"({report.detected_fault}; status polled every {POLL * 1000:g} ms)"
        )
    elif report.silent_joint and not report.faulted:
        lines.append(f"{report.silent_joint} silenced: NOT detected within {DETECT_TIMEOUT:g} s")
    return "\n".join(lines)


def _terminate(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt  # SIGTERM unwinds like Ctrl-C, through every cleanup below


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hogs", type=int, default=2, help="busy processes beside the rig (default 2)")
    parser.add_argument("--seconds", type=float, default=20.0, help="how long to run moves (default 20)")
    parser.add_argument("--stale-cycles", type=int, default=None, help="override safety.stale_feedback_cycles")
    parser.add_argument("--stale-time", type=float, default=None, help="override safety.stale_feedback_time (s)")
    parser.add_argument("--priority", type=int, default=None, help="override realtime.priority (daemon cycle)")
    parser.add_argument(
        "--emulator-priority", type=int, default=0, help="hild emulate --priority (SCHED_FIFO; default 0: normal)"
    )
    parser.add_argument("--silent-joint", default="shoulder_lift", help="joint to silence after the moves ('' skips)")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _terminate)

    with tempfile.TemporaryDirectory(prefix="hild-stale-") as tmp:
        rigs = CanProcesses(Path(tmp), ["--priority", str(args.emulator_priority)])
        try:
            patch_config(rigs.config, args)
            report = measure(rigs, args)
        finally:
            rigs.close()
    print(render(report))
    detected = report.detected_after is not None or not args.silent_joint
    return 1 if report.faulted or not detected else 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print("interrupted: every process it started is stopped", file=sys.stderr)
        sys.exit(130)
