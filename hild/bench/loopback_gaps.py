"""The README's loopback CAN pair beside everyday load: how long each emulated drive went without a command frame.

Starts ``hild emulate configs/arm6_can_loopback.yaml --serve-remote`` and ``hild run`` on a copy of that config
(free ports, 127.0.0.1 only: :class:`hild.bench.daemon.CanProcesses`) and ``hogs`` busy processes, then runs
back-and-forth moves of every joint (or holds) for ``seconds``, optionally SIGKILLing the client domain every
``restart_every`` s (``hild run`` starts another, as in tests/faults' ``client_sigkill``). It reports per drive:

* the longest silence its CAN watchdog saw (daemon → emulator: the emulator's ``longest_command_gap_ms``, since the
  drive was enabled) against the config's ``timeout_ms``;
* the longest stretch without an accepted reply the daemon saw (emulator → daemon: ``longest_silence_ms``);
* where a gap could come from: the emulator loop's worst lateness and the daemon cycle's worst period error.

The exit status is 1 when a drive faulted or came within ``margin`` of its watchdog. A benchmark, never a test:
the numbers measure the machine as much as hild (docs/performance.md).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from drivers.can.emulator.runtime import request
from hild.api.client import HildClient, HildError
from hild.bench.daemon import CanProcesses
from hild.bench.hogs import hogs

MOVE = 0.4  # rad, every joint, back and forth (a goal aborted for its tolerance still moved the arm)
GOAL_TIMEOUT = 30.0  # s for one move's result
RETRY = 0.2  # s between attempts while the client domain is being replaced


@dataclass
class Report:
    """What one run measured."""

    seconds: float
    hogs: int
    restarts: int
    watchdog_ms: float
    emulator: dict[str, Any] = field(default_factory=dict)
    daemon: dict[str, Any] = field(default_factory=dict)
    goals: dict[str, int] = field(default_factory=dict)
    load: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def drives(self) -> list[dict[str, Any]]:
        return list(self.emulator.get("joints", []))

    @property
    def longest_gap_ms(self) -> float:
        return max((float(d["longest_command_gap_ms"]) for d in self.drives), default=0.0)

    @property
    def faulted(self) -> bool:
        return any(d["fault"] for d in self.drives) or any(j["fault"] for j in self.daemon.get("joints", []))


def watchdog_ms(config: Path) -> float:
    data = yaml.safe_load(config.read_text())
    return float(data["hardware"]["arm"]["params"]["timeout_ms"])


def kill_client_domain(rigs: CanProcesses) -> None:
    """SIGKILL the client domain; ``hild run``'s main process starts another."""
    os.kill(rigs.client_process(), signal.SIGKILL)


def one_move(client: HildClient, start: list[float], away: bool, goals: dict[str, int]) -> None:
    """A move of every joint by ``MOVE`` (or back); a client domain replaced meanwhile counts as ``interrupted``."""
    target = [p + MOVE for p in start] if away else start
    try:
        result = client.move_to("joint_trajectory", target, timeout=GOAL_TIMEOUT)
        replaced = "client domain" in str(result.get("error_string"))
        status = "interrupted" if replaced else str(result.get("status"))
    except HildError:
        status = "interrupted"
        time.sleep(RETRY)
    goals[status] = goals.get(status, 0) + 1


def drive(rigs: CanProcesses, client: HildClient, args: argparse.Namespace, report: Report) -> None:
    """Moves (or holding) for ``args.seconds``, the client domain killed every ``args.restart_every`` s."""
    if args.moves:
        client.switch(activate=["joint_trajectory"])
        start = [float(p) for p in client.next_message("joint_states", timeout=5.0)["position"]]
    begin = time.monotonic()
    next_kill = begin + args.restart_every if args.restart_every else float("inf")
    count = 0
    while (now := time.monotonic()) - begin < args.seconds:
        if now >= next_kill:
            kill_client_domain(rigs)
            report.restarts += 1
            next_kill = now + args.restart_every
            rigs.wait(lambda: _answers(client), "the next client domain to answer", timeout=60.0)
        if args.moves and not _faulted(client):  # a faulted arm holds: nothing more to move
            one_move(client, start, count % 2 == 0, report.goals)
            count += 1
        else:
            time.sleep(min(0.5, max(0.0, next_kill - now)))


def _faulted(client: HildClient) -> bool:
    try:
        return bool(client.status()["mode"] == "fault")
    except HildError:
        return False


def _answers(client: HildClient) -> bool:
    try:
        client.status()
    except HildError:
        time.sleep(RETRY)
        return False
    return True


def measure(args: argparse.Namespace) -> Report:
    emulator_args = ["--priority", str(args.emulator_priority)]  # default 0: as the README starts it
    with tempfile.TemporaryDirectory(prefix="hild-loopback-") as tmp:
        rigs = CanProcesses(Path(tmp), emulator_args)
        try:
            report = Report(args.seconds, args.hogs, 0, watchdog_ms(rigs.config))
            client = rigs.start_daemon()
            try:
                with hogs(args.hogs, args.seconds + 120.0):
                    time.sleep(0.5)  # the hogs take their share before anything is measured
                    drive(rigs, client, args, report)
                    report.load = os.getloadavg()
                    rigs.wait(lambda: _answers(client), "the daemon to answer", timeout=60.0)
                    report.daemon = client.status()
                    report.emulator = request(rigs.control, {"op": "status"}, timeout=10.0)
            finally:
                client.close()
        finally:
            rigs.close()
    return report


def render(report: Report) -> str:
    lines = [
        f"{report.seconds:g} s beside {report.hogs} CPU hogs (load average at the end "
        f"{report.load[0]:.2f}), {report.restarts} client-domain restarts; goals {report.goals or 'none (holding)'}",
        f"  {'joint':<14} {'daemon→emulator':>16} {'emulator→daemon':>16}  fault (watchdog {report.watchdog_ms:g} ms)",
    ]
    silences = {j["name"]: j for j in report.daemon.get("joints", [])}
    for drive_ in report.drives:
        daemon_side = silences.get(drive_["name"], {})
        fault = (drive_["fault"] and f"drive 0x{drive_['fault']:x}") or daemon_side.get("fault") or "-"
        lines.append(
            f"  {drive_['name']:<14} {drive_['longest_command_gap_ms']:13.1f} ms "
            f"{daemon_side.get('longest_silence_ms', float('nan')):13.1f} ms  {fault}"
        )
    loop = report.emulator.get("loop", {})
    cycle = report.daemon.get("loop", {})
    period_error = cycle.get("period_error_us", {})
    lines.append(
        f"emulator loop: worst lateness {loop.get('max_late_ms', 0):.1f} ms, longest between two services "
        f"{loop.get('max_gap_ms', 0):.1f} ms, {loop.get('overruns', 0)} overruns in "
        f"{loop.get('services', 0)} services; daemon cycle: worst period error {period_error.get('max', 0) / 1000:.1f}"
        f" ms, {cycle.get('overruns', 0)} overruns"
    )
    return "\n".join(lines)


def _terminate(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt  # SIGTERM unwinds like Ctrl-C, through every cleanup


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="how long to run (default 60)")
    parser.add_argument("--hogs", type=int, default=2, help="busy processes beside the pair (default 2)")
    parser.add_argument("--hold", dest="moves", action="store_false", help="hold still instead of moving")
    parser.add_argument(
        "--restart-every", type=float, default=0.0, metavar="S", help="SIGKILL the client domain every S s (0: never)"
    )
    parser.add_argument("--emulator-priority", type=int, default=0, help="hild emulate --priority (default 0)")
    parser.add_argument(
        "--margin", type=float, default=0.5, help="fail when a gap exceeds this share of the watchdog (default 0.5)"
    )
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _terminate)
    report = measure(args)
    print(render(report))
    return 1 if report.faulted or report.longest_gap_ms > args.margin * report.watchdog_ms else 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print("interrupted: every process it started is stopped", file=sys.stderr)
        sys.exit(130)
