#!/usr/bin/env python3
"""Measure the whole daemon: run ``hild run CONFIG`` with a Zenoh client streaming commands, read its loop stats.

    python tools/daemon_stats.py configs/arm6_twin.yaml --rates 500 1000 --seconds 12

Per rate: starts the daemon on a free loopback port (a temporary copy of the config beside the original, with
``update_rate`` changed), activates ``forward_position``, streams its current pose at ``--stream-hz`` from a
client process for ``--seconds``, then prints the daemon's own loop statistics from ``srv/status``. Unlike
``tools/cycle_stats.py`` this includes everything that shares the process and the machine with the cycle: the
Zenoh threads, the asyncio side, the broadcaster at 100 Hz and the client.
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from hild.api.client import HildClient, HildUnreachable
from hild.stats import format_loop_table


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def measure(config: Path, rate: float, seconds: float, controller: str, stream_hz: float) -> dict[str, Any]:
    data = yaml.safe_load(config.read_text())
    data["update_rate"] = rate
    copy = config.with_name(f".{config.stem}.{rate:g}hz.yaml")
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hild.cli", "run", str(copy), "--listen", endpoint, "--log-level", "warning"]
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                arm = HildClient(connect=[endpoint], timeout=5.0)
                break
            except HildUnreachable:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"the daemon did not come up (exit {proc.poll()})") from None
                time.sleep(0.2)
        with arm:
            arm.wait_alive(30)
            names = [c["name"] for c in arm.list_controllers()]
            if controller not in names:
                raise SystemExit(f"no controller {controller!r} in {config} (loaded: {names})")
            arm.switch(activate=[controller])
            pose: list[float] = []
            sub = arm.subscribe("joint_states", lambda m: pose.__setitem__(slice(None), m["position"]))
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                if pose:
                    arm.send(controller, pose)
                time.sleep(1.0 / stream_hz)
            sub.close()
            status = arm.status()
        return {"rate_hz": rate, **status["loop"], "realtime": status["realtime"]}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        copy.unlink(missing_ok=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", type=Path)
    parser.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0])
    parser.add_argument("--seconds", type=float, default=12.0)
    parser.add_argument("--controller", default="forward_position")
    parser.add_argument("--stream-hz", type=float, default=100.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = [measure(args.config, r, args.seconds, args.controller, args.stream_hz) for r in args.rates]
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(format_loop_table(results))
    print("(from the daemon's srv/status: the last 10k cycles)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
