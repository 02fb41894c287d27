"""The client domain's memory under sessions that send large payloads (issue [layout], item 8.1).

Runs ``hild run CONFIG --listen tcp/127.0.0.1:<free port>`` and measures the client domain's USS (unique set size:
``Private_Clean + Private_Dirty`` of ``/proc/<pid>/smaps_rollup``) at rest, then after each round of load:

- ``storm``: ``--storm-seconds`` of bad input (garbage and oversized JSON of 100 B … 8 KB to every service, goal
  endpoint and controller input) from ``--storm-sessions`` fresh Zenoh sessions, ``--storms`` times;
- ``sessions``: ``--sessions`` short sessions, one after the other, each sending ``--per-session`` ~4 KB payloads
  to the services and closing.

Zenoh's defaults move payloads of 3 KB and more through a 16 MiB shared-memory pool per sending session, which the
receiving session maps and keeps after the sender is gone: that is what this script catches. ``--secure`` runs the
config with configs/secure/zenoh-server.json5 over TCP (passwords and access control, no TLS, as
tests/api/test_security.py does) and sends as the read-only ``observer``: only ``srv/status`` and the list_*
services answer it, the rest is denied by Zenoh.

    .venv/bin/python tools/client_memory.py configs/arm6_twin.yaml
    .venv/bin/python tools/client_memory.py configs/arm6_twin.yaml --storms 0 --sessions 30
    .venv/bin/python tools/client_memory.py configs/arm6_twin.yaml --secure --storms 0 --sessions 10
"""

from __future__ import annotations

import argparse
import json
import random
import secrets
import sys
import tempfile
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
import zenoh

from hild.api.client import HildClient
from hild.api.keys import SERVICES, Keys
from hild.api.session import client_config, server_config
from hild.bench.children import free_endpoint
from hild.bench.daemon import HildRun
from hild.config import load_config
from hild.config.model import ZenohSection

SECURE = Path(__file__).resolve().parents[1] / "configs" / "secure"
MIB = 1 << 20
SETTLE = 3.0  # s after a round before measuring: replies drained, sessions' leases gone


def uss(pid: int) -> int:
    """Bytes private to ``pid``: what ending it would give back."""
    fields = {}
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()[1:]:
        name, value = line.split(":", 1)
        fields[name] = int(value.split()[0]) * 1024
    return fields["Private_Clean"] + fields["Private_Dirty"]


def targets(robot: str, controllers: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """(query keys, put keys): every service and goal endpoint; every controller's ``commands`` input."""
    keys = Keys(robot)
    goals = [keys.input(name, "goal") for name, c in controllers.items() if c.type == "joint_trajectory"]
    queries = [keys.service(s) for s in SERVICES] + goals
    puts = [keys.input(name, "commands") for name in controllers]
    return queries, puts


def bad_payload(rng: random.Random) -> bytes:
    size = rng.choice((100, 1000, 3000, 4096, 8192))
    kind = rng.randrange(3)
    if kind == 0:
        return bytes(rng.getrandbits(8) for _ in range(size))  # not JSON
    if kind == 1:
        return json.dumps({f"k{i}": i for i in range(size // 10)}).encode()[:size]  # unknown keys, maybe cut
    return json.dumps({"activate": ["x" * 40] * (size // 44)}).encode()  # too many unknown names


@dataclass(frozen=True)
class Station:
    """How a client session is opened: a Zenoh file and overrides (a role's password, TCP)."""

    endpoint: str
    config_file: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)

    def open(self) -> zenoh.Session:
        return zenoh.open(client_config([self.endpoint], self.config_file, self.overrides))


class StationRun(HildRun):
    """``hild run`` whose readiness is asked as ``station`` (a secure daemon answers no anonymous client)."""

    def __init__(self, station: Station, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.station = station

    def client(self, timeout: float = 5.0) -> HildClient:
        s = self.station
        return HildClient(self.robot, [s.endpoint], timeout, zenoh_config=s.config_file, zenoh_overrides=s.overrides)


def secure(config: Path, directory: Path) -> tuple[Path, dict[str, Any]]:
    """``config`` with the committed secure server file over TCP, in ``directory``; the observer's overrides."""
    passwords = {role: secrets.token_hex(8) for role in ("operator", "observer", "estop")}
    users = directory / "users.txt"
    users.write_text("".join(f"{user}:{password}\n" for user, password in passwords.items()))
    committed = server_config(ZenohSection(config_file=str(SECURE / "zenoh-server.json5")))
    subjects = [
        {"id": s["id"], "usernames": s["usernames"]}
        for s in json.loads(committed.get_json("access_control"))["subjects"]
    ]
    for model in config.parent.iterdir():  # the robot's model files, beside the config as it names them
        if model.suffix in (".xml", ".urdf"):
            (directory / model.name).symlink_to(model)
    data = yaml.safe_load(config.read_text())
    data["zenoh"] = {
        "config_file": str(SECURE / "zenoh-server.json5"),
        "config": {
            "transport.link.protocols": ["tcp"],
            "transport.auth.usrpwd.dictionary_file": str(users),
            "access_control.subjects": subjects,
        },
    }
    secured = directory / config.name
    secured.write_text(yaml.safe_dump(data, sort_keys=False))
    observer = {"transport.auth.usrpwd.password": passwords["observer"], "transport.link.protocols": ["tcp"]}
    return secured, observer


def storm(station: Station, queries: list[str], puts: list[str], seconds: float) -> int:
    """One session sending bad input for ``seconds``; returns how many messages it sent."""
    rng = random.Random()
    sent = 0
    with station.open() as session:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            payload = bad_payload(rng)
            if puts and rng.random() < 0.3:
                session.put(rng.choice(puts), payload)
            else:
                for _ in session.get(rng.choice(queries), payload=payload, timeout=1.0):
                    pass
            sent += 1
    return sent


def short_session(station: Station, queries: list[str], count: int) -> None:
    payload = json.dumps({"note": "x" * 4000}).encode()  # ~4 KB: over Zenoh's 3 KB shared-memory threshold
    with station.open() as session:
        for i in range(count):
            for _ in session.get(queries[i % len(queries)], payload=payload, timeout=2.0):
                pass


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config", type=Path)
    parser.add_argument("--storms", type=int, default=4)
    parser.add_argument("--storm-seconds", type=float, default=30.0)
    parser.add_argument("--storm-sessions", type=int, default=2, help="concurrent sessions per storm")
    parser.add_argument("--sessions", type=int, default=30)
    parser.add_argument("--per-session", type=int, default=20, help="~4 KB queries per short session")
    parser.add_argument("--secure", action="store_true", help="access control and passwords; send as observer")
    parser.add_argument("--args", default="", help="extra arguments for hild run")
    args = parser.parse_args()
    endpoint = free_endpoint()
    loaded = load_config(args.config)
    robot = loaded.config.robot.name
    queries, puts = targets(robot, loaded.config.controllers)
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "daemon.log"
        config, station = args.config.resolve(), Station(endpoint)
        if args.secure:
            config, observer = secure(config, Path(tmp))
            station = Station(endpoint, str(SECURE / "zenoh-observer.json5"), observer)
        with StationRun(station, config, endpoint, robot, log=log, args=args.args.split()) as run:
            pid = run.client_process()
            time.sleep(SETTLE)
            base = uss(pid)
            print(f"client domain pid {pid}: USS at rest {base / MIB:.1f} MiB", flush=True)
            for n in range(args.storms):
                load = (station, queries, puts, args.storm_seconds)
                threads = [threading.Thread(target=storm, args=load) for _ in range(args.storm_sessions)]
                for thread in threads:
                    thread.start()
                for thread in threads:
                    thread.join()
                time.sleep(SETTLE)
                pid = run.client_process()
                print(f"after storm {n + 1}: USS {uss(pid) / MIB:.1f} MiB (pid {pid})", flush=True)
            for n in range(args.sessions):
                short_session(station, queries, args.per_session)
                if (n + 1) % 10 == 0 or n + 1 == args.sessions:
                    time.sleep(SETTLE)
                    pid = run.client_process()
                    print(f"after {n + 1} sessions: USS {uss(pid) / MIB:.1f} MiB (pid {pid})", flush=True)
            pid = run.client_process()
            final = uss(pid)
            print(f"growth: {(final - base) / MIB:+.1f} MiB (pid {pid})", flush=True)
            restarts = run.log.count("the client domain ended unexpectedly")
            if restarts:
                print(f"the client domain was restarted {restarts} time(s)")
            assert run.stop() == 0, run.log
    return 0 if final - base <= 10 * MIB else 1


if __name__ == "__main__":
    sys.exit(main())
