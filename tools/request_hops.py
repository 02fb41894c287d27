#!/usr/bin/env python3
"""Which of hild's files one request runs through, in every process of ``hild run`` (the hop table of [layout]).

Runs ``hild run configs/arm6_twin.yaml`` under coverage.py with its ``subprocess`` and ``_exit`` patches, so the
main process, the client domain and the cycle process are all measured, and sends one request from this process
(the Python client, not counted). A request's files are those with lines run in its run that the run of its
baseline (the same start, wait and stop; for a goal or a servo stream, with the controller switched on) did not
run. What a request shares with the baseline (the query handler a switch also uses …) is not counted, so a file
listed is one the request needs of its own.

    pip install coverage                             # 7.10 or newer: [run] patch = subprocess
    python tools/request_hops.py                     # this tree
    python tools/request_hops.py --tree ../old       # another checkout of hild (its package, this interpreter)
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

TARGET = [0.3, 1.0, -1.6, -0.97, 1.57, 0.2]
HOME = [0.0, 1.0, -1.6, -0.97, 1.57, 0.0]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def estop(arm: Any) -> None:
    arm.estop()


def switch_jtc(arm: Any) -> None:
    arm.switch(activate=["joint_trajectory"])


def switch_servo(arm: Any) -> None:
    arm.switch(activate=["servo"])


def goal(arm: Any) -> None:
    switch_jtc(arm)
    arm.move_to("joint_trajectory", TARGET, timeout=30.0)


def servo(arm: Any) -> None:
    switch_servo(arm)
    stream = arm.servo_stream("servo")
    for k in range(50):
        stream.send([h + 0.002 * k for h in HOME])
        time.sleep(0.01)


def idle(arm: Any) -> None:
    pass


# request → (what it does, what its baseline does)
REQUESTS: dict[str, tuple[Callable[[Any], None], Callable[[Any], None]]] = {
    "estop": (estop, idle),
    "switch": (switch_jtc, idle),
    "trajectory goal": (goal, switch_jtc),
    "servo stream": (servo, switch_servo),
}


def measure(tree: Path, action: Callable[[Any], None]) -> dict[str, set[int]]:
    """Lines run per file (relative to ``tree``) in one ``hild run`` that serves ``action``."""
    from hild.client import HildClient

    with tempfile.TemporaryDirectory() as tmp:
        rc = Path(tmp) / "coveragerc"
        rc.write_text(
            f"[run]\nparallel = true\npatch = subprocess, _exit\ndata_file = {tmp}/.coverage\n"
            f"source = {tree / 'hild'}, {tree / 'drivers'}\n"
        )
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        env = {**os.environ, "PYTHONPATH": str(tree)}
        command = [sys.executable, "-m", "coverage", "run", "--rcfile", str(rc), "-m", "hild.cli", "run"]
        daemon = subprocess.Popen(
            [*command, "configs/arm6_twin.yaml", "--listen", endpoint],
            cwd=tree,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            with connect(HildClient, endpoint, daemon) as arm:
                arm.wait_alive(timeout=60.0)
                time.sleep(1.0)
                action(arm)
                time.sleep(1.0)
        finally:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(60)
        subprocess.run([sys.executable, "-m", "coverage", "combine", "--rcfile", str(rc), "-q"], cwd=tmp, check=True)
        import coverage

        data = coverage.CoverageData(basename=f"{tmp}/.coverage")
        data.read()
        return {str(Path(f).relative_to(tree)): set(data.lines(f) or ()) for f in data.measured_files()}


def connect(client: Any, endpoint: str, daemon: subprocess.Popen[bytes], timeout: float = 120.0) -> Any:
    """A client of the daemon starting at ``endpoint``, once it listens (coverage slows its start)."""
    from hild.client import HildUnreachable

    deadline = time.monotonic() + timeout
    while True:
        try:
            return client("arm6", connect=[endpoint], timeout=10.0)
        except HildUnreachable:
            if daemon.poll() is not None or time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def touched(run: dict[str, set[int]], baseline: dict[str, set[int]]) -> list[str]:
    return sorted(f for f, lines in run.items() if lines - baseline.get(f, set()))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1], help="a hild checkout")
    args = parser.parse_args()
    tree = args.tree.resolve()
    runs: dict[str, dict[str, set[int]]] = {}
    for name, (action, baseline) in REQUESTS.items():
        for what in (baseline, action):
            if what.__name__ not in runs:
                runs[what.__name__] = measure(tree, what)
        files = touched(runs[action.__name__], runs[baseline.__name__])
        print(f"{name}: {len(files)} files")
        for path in files:
            print(f"    {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
