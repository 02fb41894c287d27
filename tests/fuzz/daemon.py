"""A real daemon for bad-input tests: ``hild run`` as a subprocess on a free loopback port, reached only over Zenoh.

The robot is six mock joints on the wall clock with every kind of endpoint live at once: ``joint_trajectory`` on
a, b (goal/cancel/result), ``servo`` on c, d (streamed targets), ``fwd`` on e, f (streamed commands) and the
joint-state broadcaster. The mock mirrors commands exactly, so a held joint's position never changes by a bit:
any motion in ``joint_states`` is a command that got through.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
import zenoh

from hild.api.client import HildClient
from tests.helpers import HildRun, free_endpoint, wait_for

ROBOT = "fuzz6"
JOINTS = ("a", "b", "c", "d", "e", "f")
START = {"a": 0.1, "b": -0.2, "c": 0.3, "d": -0.1, "e": 0.2, "f": 0.0}
LOWER, UPPER, SOFT_MARGIN, VELOCITY = -1.0, 1.0, 0.05, 2.0
CONTROLLERS = {"joint_trajectory": ("a", "b"), "servo": ("c", "d"), "fwd": ("e", "f")}


def robot_config() -> dict[str, Any]:
    joint = {
        "limits": {
            "position": {"lower": LOWER, "upper": UPPER},
            "soft_margin": SOFT_MARGIN,
            "velocity": VELOCITY,
            "acceleration": 8.0,
            "jerk": 80.0,
            "effort": 50.0,
        },
        "hold": {"kp": 100.0, "kd": 5.0},
    }
    return {
        "robot": {"name": ROBOT},
        "update_rate": 500,
        "clock": {"source": "wall"},
        "hardware": {
            "bus": {"driver": "mock", "params": {"initial_positions": START}, "joints": {j: {} for j in JOINTS}}
        },
        "joints": {j: joint for j in JOINTS},
        "controllers": {
            "jsb": {"type": "joint_state_broadcaster", "params": {"publish_rate": 50}, "autostart": True},
            "joint_trajectory": {
                "type": "joint_trajectory",
                "params": {"joints": list(CONTROLLERS["joint_trajectory"])},
                "autostart": True,
            },
            "servo": {
                "type": "servo",
                "params": {"joints": list(CONTROLLERS["servo"]), "command_timeout": 0.2},
                "autostart": True,
            },
            "fwd": {
                "type": "forward_command",
                "params": {"joints": list(CONTROLLERS["fwd"]), "interface": "position", "command_timeout": 0.2},
                "autostart": True,
            },
        },
    }


class Motion:
    """Every ``joint_states`` sample, reduced to what the tests ask: how far any joint strayed from a baseline."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.samples = 0
        self.latest: list[float] = []
        self._baseline: list[float] | None = None
        self.max_deviation = 0.0

    def __call__(self, message: dict[str, Any]) -> None:
        position = [float(p) for p in message["position"]]
        with self._lock:
            self.samples += 1
            self.latest = position
            if self._baseline is not None:
                worst = max(abs(p - b) for p, b in zip(position, self._baseline, strict=True))
                self.max_deviation = max(self.max_deviation, worst)

    def arm(self) -> list[float]:
        """Take the current position as the baseline and forget earlier deviations."""
        with self._lock:
            self._baseline = list(self.latest)
            self.max_deviation = 0.0
            return list(self._baseline)

    def count(self) -> int:
        with self._lock:
            return self.samples


@dataclass(frozen=True)
class Snapshot:
    mode: str
    joint_modes: tuple[str, ...]
    faults: tuple[str | None, ...]
    cycles: int
    overruns: int
    rss_kb: int


class FuzzDaemon:
    """``hild run`` in a subprocess plus one client session that can send raw bytes to any key."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.endpoint = free_endpoint()
        self.config = workdir / "fuzz6.yaml"
        self.config.write_text(yaml.safe_dump(robot_config(), sort_keys=False))
        self.log = workdir / "daemon.log"
        self.run: HildRun | None = None
        self.client: HildClient | None = None
        self.motion = Motion()
        self.events: list[dict[str, Any]] = []
        self.deaths = 0
        self.idle_modes: tuple[str, ...] = ()

    # ---- lifecycle -------------------------------------------------------------------------------------------
    def start(self) -> None:
        self.run = HildRun(self.config, self.endpoint, ROBOT, log=self.log, cwd=self.workdir)
        self.client = self.run.connected()
        self.client.subscribe("joint_states", self.motion)
        self.client.subscribe("events", self.events.append)
        wait_for(lambda: self.motion.count() > 0, what="joint_states")
        self.idle_modes = self.snapshot().joint_modes

    def quiesce(self) -> Snapshot:
        """Wait until every joint is back in its idle mode (a streamed command's controller timed out)."""
        return wait_for(
            lambda: (s := self.snapshot()).joint_modes == self.idle_modes and s, what=f"joint modes {self.idle_modes}"
        )

    def stop(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.run is not None:
            self.run.end(10.0)

    @property
    def session(self) -> Any:
        assert self.client is not None
        return self.client.session

    @property
    def pid(self) -> int:
        assert self.run is not None
        return self.run.pid

    def alive(self) -> bool:
        assert self.run is not None
        if self.run.process.poll() is None:
            return True
        self.deaths += 1
        return False

    # ---- raw traffic -----------------------------------------------------------------------------------------
    def key(self, suffix: str) -> str:
        return f"hild/{ROBOT}/{suffix}"

    def query(self, suffix: str, raw: bytes, timeout: float = 10.0) -> tuple[dict[str, Any], int]:
        """One query with a raw payload: the decoded reply and its size in bytes (exactly one reply expected)."""
        replies = list(self.session.get(self.key(suffix), payload=raw, timeout=timeout))
        assert len(replies) == 1, f"{suffix}: expected one reply, got {len(replies)}"
        reply = replies[0].ok if replies[0].ok is not None else replies[0].err
        assert replies[0].ok is not None, f"{suffix}: error reply {reply.payload.to_bytes()[:200]!r}"
        body = reply.payload.to_bytes()
        return json.loads(body), len(body)

    def put(self, suffix: str, raw: bytes) -> None:
        """Publish ``raw`` once; BLOCK so a huge sample is delivered, not dropped by our own congested queue."""
        self.session.put(self.key(suffix), raw, congestion_control=zenoh.CongestionControl.BLOCK)

    # ---- state ---------------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        assert self.client is not None
        return self.client.status()

    def rss_kb(self) -> int:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        raise AssertionError("no VmRSS")

    def snapshot(self) -> Snapshot:
        status = self.status()
        return Snapshot(
            mode=status["mode"],
            joint_modes=tuple(j["mode"] for j in status["joints"]),
            faults=tuple(j["fault"] for j in status["joints"]),
            cycles=int(status["loop"]["cycles"]),
            overruns=int(status["loop"]["overruns"]),
            rss_kb=self.rss_kb(),
        )

    def still(self) -> None:
        """Wait until no joint moves between two batches of joint states (a servo target has been reached)."""

        def unchanged() -> bool:
            before = list(self.motion.latest)
            self.settle(5)
            return self.motion.latest == before

        wait_for(unchanged, what="the joints to stand still")

    def settle(self, samples: int = 10) -> None:
        """Wait until ``samples`` more joint states have arrived: whatever was sent before has had its effect."""
        target = self.motion.count() + samples
        wait_for(lambda: self.motion.count() >= target, what=f"{samples} more joint_states")

    def drop_events(self, suffix: str) -> list[dict[str, Any]]:
        key = self.key(suffix)
        return [e for e in list(self.events) if e.get("message", "").startswith(f"dropped command on {key}")]
