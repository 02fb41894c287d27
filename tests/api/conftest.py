"""A daemon in miniature: a mock engine stepped by a thread, an ApiServer on its own asyncio loop, a client.

Everything listens on a free loopback port with scouting off, so tests never see each other or the network.
Tests wait on conditions (``wait_for``) with generous timeouts; no assertion depends on a sleep.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from hild.api.client import HildClient
from hild.api.server import ApiServer
from hild.config import load_config
from hild.config.model import ZenohSection
from hild.cycle.engine import Engine
from tests.conftest import with_trajectory
from tests.helpers import free_endpoint

ROBOT = "mock3"
WAIT = 10.0  # s: generous; conditions are normally met in milliseconds


def joint() -> dict[str, Any]:
    return {
        "limits": {"position": {"lower": -1, "upper": 1}, "velocity": 2, "effort": 50},
        "hold": {"kp": 100, "kd": 5},
    }


def robot_config() -> dict[str, Any]:
    return {
        "robot": {"name": ROBOT},
        "update_rate": 500,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {
            "bus": {
                "driver": "mock",
                "params": {"initial_positions": {"a": 0.1, "b": -0.2}},
                "joints": {"a": {}, "b": {"reduction": 2.0}, "c": {"direction": -1}},
            }
        },
        "joints": {"a": joint(), "b": joint(), "c": joint()},
        "controllers": {
            "jsb": {"type": "joint_state_broadcaster", "params": {"publish_rate": 100}, "autostart": True},
            "fwd": {"type": "forward_command", "params": {"joints": ["a", "b", "c"], "interface": "position"}},
            "fwd_a": {"type": "forward_command", "params": {"joints": ["a"], "interface": "position"}},
        },
    }


class Stepper(threading.Thread):
    """Plays the cycle thread: one lockstep cycle about every millisecond while ``running`` is set."""

    def __init__(self, engine: Engine) -> None:
        super().__init__(name="test-cycle", daemon=True)
        self.engine = engine
        self.running = threading.Event()
        self.running.set()
        self.stopped = threading.Event()

    def run(self) -> None:
        while not self.stopped.is_set():
            if self.running.is_set():
                self.engine.run_cycles(1)
            time.sleep(0.001)


class Daemon:
    """Engine + stepper + ApiServer on a background asyncio loop, wired like hild.daemon.daemon (coalesced wake-ups)."""

    def __init__(
        self, engine: Engine, endpoint: str, settings: ZenohSection | None = None, *, recorder: Any = None
    ) -> None:
        self.engine = engine
        self.endpoint = endpoint
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="test-asyncio", daemon=True)
        self.server = ApiServer(engine, settings or ZenohSection(), [endpoint], request_timeout=0.5, recorder=recorder)
        self.stepper = Stepper(engine)
        self.published_events: list[dict[str, Any]] = []
        self._pending = False

    def _wake_from_cycle(self) -> None:
        if not self._pending:
            self._pending = True
            self.loop.call_soon_threadsafe(self._wake)

    def _wake(self) -> None:
        self._pending = False
        events = self.engine.events.drain()
        self.published_events += [e.as_dict() for e in events]
        self.server.publish(events)

    def run(self, coro: Any, timeout: float = WAIT) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def start(self) -> None:
        self.thread.start()
        self.engine.wake_client = self._wake_from_cycle
        self.engine.start()
        self.run(self.server.start())
        self.loop.call_soon_threadsafe(self._wake)
        self.stepper.start()

    def stop(self) -> None:
        self.stepper.stopped.set()
        self.stepper.join(WAIT)
        self.engine.wake_client = lambda: None
        self.run(self.server.close())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(WAIT)
        self.loop.close()
        self.engine.stop()

    def events_with(self, text: str) -> list[dict[str, Any]]:
        return [e for e in list(self.published_events) if text in e["message"]]


def engine_from(config: dict[str, Any], tmp_path: Path) -> Engine:
    """An engine for ``config``, loaded from ``tmp_path/robot.yaml`` as the daemon loads its file."""
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return Engine(load_config(path))


def engine_with_trajectory(tmp_path: Path) -> Engine:
    """The test robot plus a joint_trajectory controller ``traj`` (its planner needs acceleration and jerk)."""
    return engine_from(with_trajectory(robot_config(), "traj"), tmp_path)


@contextlib.contextmanager
def running(engine: Engine, *, recorder: Any = None) -> Iterator[Daemon]:
    """``engine`` served by a daemon on a free loopback port, stopped on leaving; ``recorder``: what the record
    services ask (None: recording disabled)."""
    d = Daemon(engine, free_endpoint(), recorder=recorder)
    d.start()
    try:
        yield d
    finally:
        d.stop()


@pytest.fixture
def engine(tmp_path: Path) -> Engine:
    return engine_from(robot_config(), tmp_path)


@pytest.fixture
def daemon(engine: Engine) -> Iterator[Daemon]:
    with running(engine) as d:
        yield d


@pytest.fixture
def client(daemon: Daemon) -> Iterator[HildClient]:
    with HildClient(ROBOT, connect=[daemon.endpoint], timeout=5.0) as c:
        yield c
