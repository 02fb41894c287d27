"""Shared fixtures: small robot configs written to tmp_path, and lockstep engines built from them."""

from __future__ import annotations

import copy
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from hild.config import load_config
from hild.cycle.engine import Engine

REPO = Path(__file__).resolve().parent.parent
CONFIGS = REPO / "configs"


def joint(lower: float = -1.0, upper: float = 1.0, velocity: float = 2.0, effort: float = 50.0) -> dict[str, Any]:
    return {
        "limits": {
            "position": {"lower": lower, "upper": upper},
            "soft_margin": 0.05,
            "velocity": velocity,
            "effort": effort,
        },
        "hold": {"kp": 100.0, "kd": 5.0},
    }


def mock_robot() -> dict[str, Any]:
    """Three mock joints at 500 Hz on the sim clock, a broadcaster and a forward position controller."""
    return {
        "robot": {"name": "mock3"},
        "update_rate": 500,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {
            "bus": {
                "driver": "mock",
                "params": {"initial_positions": {"a": 0.1, "b": -0.2, "c": 0.3}},
                "joints": {"a": {}, "b": {}, "c": {}},
            }
        },
        "joints": {"a": joint(), "b": joint(), "c": joint()},
        "controllers": {
            "jsb": {"type": "joint_state_broadcaster", "params": {"publish_rate": 100}, "autostart": True},
            "fwd": {
                "type": "forward_command",
                "params": {"joints": ["a", "b", "c"], "interface": "position", "command_timeout": 0.2},
            },
        },
    }


def with_trajectory(config: dict[str, Any], *names: str, joints: tuple[str, ...] = ("a", "b", "c")) -> dict[str, Any]:
    """``config`` (changed in place, and returned) with the acceleration and jerk limits a planner needs on every
    joint, and a joint_trajectory controller on ``joints`` for each of ``names``."""
    for joint in config["joints"].values():
        joint["limits"].update(acceleration=10.0, jerk=100.0)
    for name in names:
        config["controllers"][name] = {"type": "joint_trajectory", "params": {"joints": list(joints)}}
    return config


def merge(base: dict[str, Any], patch: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for key, value in patch.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


@pytest.fixture
def write_config(tmp_path: Path) -> Callable[..., Path]:
    def write(data: dict[str, Any] | str, name: str = "robot.yaml") -> Path:
        path = tmp_path / name
        path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
        return path

    return write


@pytest.fixture
def make_engine(write_config: Callable[..., Path]) -> Callable[..., Engine]:
    """Build and start a lockstep engine from the mock robot, optionally patched."""

    def make(patch: dict[str, Any] | None = None, start: bool = True) -> Engine:
        engine = Engine(load_config(write_config(merge(mock_robot(), patch or {}))))
        if start:
            engine.start()
        return engine

    return make


# ---- a fake systemd (NOTIFY_SOCKET) --------------------------------------------------------------------------
@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A fake systemd: a datagram socket bound to a path; yields it and the NOTIFY_SOCKET value."""
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    try:
        yield sock, str(path)
    finally:
        sock.close()


def receive(sock: socket.socket, timeout: float = 2.0) -> str:
    sock.settimeout(timeout)
    return sock.recv(4096).decode()


class Systemd:
    """Reads the fake NOTIFY_SOCKET continuously, as systemd does (an unread unix datagram socket queues only
    ``net.unix.max_dgram_qlen`` messages, 10 by default, and then the sender's sends fail), stamping each message."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.lock = threading.Lock()
        self.messages: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self.sock.settimeout(0.05)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            with self.lock:
                self.messages.append((time.monotonic(), data.decode()))

    def between(self, start: float, end: float = float("inf")) -> list[str]:
        with self.lock:
            return [m for t, m in self.messages if start <= t < end]

    def wait_for(self, prefix: str, timeout: float, alive: Callable[[], bool] = lambda: True) -> tuple[float, str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and alive():
            with self.lock:
                for t, m in self.messages:
                    if m.startswith(prefix):
                        return t, m
            time.sleep(0.01)
        raise AssertionError(f"no {prefix!r} message within {timeout} s (or the sender died)")

    def close(self) -> None:
        self._stop.set()
        self.thread.join(2.0)


@pytest.fixture
def systemd(listener: tuple[socket.socket, str]) -> Iterator[tuple[Systemd, str]]:
    fake = Systemd(listener[0])
    try:
        yield fake, listener[1]
    finally:
        fake.close()
