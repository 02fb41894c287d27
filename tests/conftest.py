"""Shared fixtures: small robot configs written to tmp_path, and lockstep engines built from them."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from hild.config import load_config
from hild.engine import Engine

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
