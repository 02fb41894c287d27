"""Stale detection on a loaded host (issue [trust], finding 7): the loopback CAN rig under CPU hogs.

Starts ``hild emulate`` (Damiao drives, arm6 twin behind them) and ``hild run`` on a copy of
configs/arm6_can_loopback.yaml (free ports, 127.0.0.1 only), starts ``--hogs`` busy processes, runs back-and-forth
moves of every joint for ``--seconds``, and reports per joint the longest stretch without an accepted reading the
daemon saw (status ``longest_silence_ms``), whether any joint faulted, and the goals' results. Then, with
``--silent-joint J``, cuts that drive's transceiver and measures how long the daemon takes to fault it.

    python tools/stale_under_load.py                      # 2 hogs, 20 s of moves, then shoulder_lift silent
    python tools/stale_under_load.py --hogs 0             # the idle reference
    python tools/stale_under_load.py --stale-cycles 50 --stale-time 0   # the settings of the finding

Exit status 1 if a joint faulted during the moves. Every process it starts is stopped on exit.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from drivers.can.emulator.runtime import request
from tests.faults.processes import CanProcesses

MOVE = 0.4  # rad, every joint, back and forth


def hogs(count: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def patch_config(path: Path, stale_cycles: int | None, stale_time: float | None) -> None:
    data = yaml.safe_load(path.read_text())
    if stale_cycles is not None:
        data["safety"]["stale_feedback_cycles"] = stale_cycles
    if stale_time is not None:
        data["safety"]["stale_feedback_time"] = stale_time
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def moves(client: Any, seconds: float) -> list[str]:
    """Back and forth by MOVE on every joint until ``seconds`` pass or a joint faults; the goals' results."""
    client.switch(activate=["joint_trajectory"])
    start = list(client.next_message("joint_states", timeout=5.0)["position"])
    results: list[str] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and client.status()["mode"] != "fault":
        away = [p + MOVE for p in start] if len(results) % 2 == 0 else start
        result = client.move_to("joint_trajectory", away, timeout=30.0)
        results.append(f"{result.get('status')} {result.get('error_string') or ''}".strip())
    return results


def silent_detection(rigs: CanProcesses, client: Any, joint: str) -> float:
    """Seconds from cutting ``joint``'s transceiver to its fault in status (polled every 5 ms)."""
    names = [j["name"] for j in client.status()["joints"]]
    i = names.index(joint)
    start = time.monotonic()
    request(rigs.control, {"op": "set", "joint": joint, "silent": True})
    while time.monotonic() - start < 5.0:
        if client.status()["joints"][i]["fault"]:
            return time.monotonic() - start
        time.sleep(0.005)
    return float("inf")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hogs", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--stale-cycles", type=int, default=None, help="override safety.stale_feedback_cycles")
    parser.add_argument("--stale-time", type=float, default=None, help="override safety.stale_feedback_time (s)")
    parser.add_argument("--silent-joint", default="shoulder_lift")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="hild-stale-") as tmp:
        rigs = CanProcesses(Path(tmp))
        busy: list[subprocess.Popen[bytes]] = []
        try:
            patch_config(rigs.config, args.stale_cycles, args.stale_time)
            client = rigs.start_daemon()
            safety = yaml.safe_load(rigs.config.read_text())["safety"]
            busy = hogs(args.hogs)
            results = moves(client, args.seconds)
            status = client.status()
            faulted = {j["name"]: j["fault"] for j in status["joints"] if j["fault"]}
            print(
                f"{args.hogs} hogs; stale_feedback_cycles {safety['stale_feedback_cycles']}, "
                f"stale_feedback_time {safety.get('stale_feedback_time', 0)} s; {len(results)} moves: "
                f"{', '.join(sorted(set(results)))}"
            )
            for j in status["joints"]:
                print(f"  {j['name']:<14} longest silence {j['longest_silence_ms']:7.1f} ms  fault: {j['fault']}")
            if not faulted:
                client.switch(deactivate=["joint_trajectory"])
                seconds = silent_detection(rigs, client, args.silent_joint)
                print(f"  {args.silent_joint} silenced: faulted after {seconds * 1000:.0f} ms")
            client.close()
            return 1 if faulted else 0
        finally:
            for proc in busy:
                proc.kill()
            rigs.close()


if __name__ == "__main__":
    sys.exit(main())
