"""docs/contributing.md's worked examples (docs/examples/) run as written: the driver holds and follows, the
controller sweeps from where the joints are, and its input is validated and taken."""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from hild import plugins
from hild.config import load_config
from hild.cycle.engine import Engine
from tests.conftest import REPO, joint

EXAMPLES = REPO / "docs" / "examples"


def _module(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"hild_examples_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, type]]:
    """The examples registered under the names docs/contributing.md gives them, as their entry points would."""
    classes = {"lag_motor": _module("lag_motor").LagMotor, "sine_sweep": _module("sine_sweep").SineSweep}
    installed = plugins.load

    def load(group: str, name: str) -> Any:
        return classes[name] if name in classes else installed(group, name)

    monkeypatch.setattr(plugins, "load", load)
    yield classes


@pytest.fixture
def engine(registered: dict[str, type], write_config: Callable[..., Path]) -> Engine:
    config = {
        "robot": {"name": "example"},
        "update_rate": 500,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {
            "motors": {"driver": "lag_motor", "params": {"time_constant": 0.02}, "joints": {"a": {}, "b": {}}}
        },
        "joints": {"a": joint(), "b": joint()},
        "controllers": {"sweep": {"type": "sine_sweep", "params": {"joints": ["a", "b"], "frequency": 1.0}}},
    }
    engine = Engine(load_config(write_config(config)))
    engine.start()
    return engine


def run(engine: Engine, seconds: float) -> None:
    for _ in range(round(seconds * engine.update_rate)):
        engine.step(engine.t + engine.period, engine.period)


def test_the_example_driver_holds_where_it_is_until_a_controller_commands(engine: Engine) -> None:
    run(engine, 0.5)
    assert engine.status()["mode"] == "hold"
    assert np.abs(engine.state.position).max() < 1e-9


def test_the_example_controller_sweeps_from_where_the_joints_are_and_takes_its_input(engine: Engine) -> None:
    (entry,) = engine.snapshot().controllers
    assert (entry["claimed"], entry["state_interfaces"]) == (["a/position", "b/position"], ["a/position", "b/position"])
    assert engine.switch(["sweep"], []).ok
    sweep = engine.controllers()["sweep"]
    run(engine, 0.25)  # a quarter period at 1 Hz: the crest of the default 0.1 rad
    assert engine.state.position == pytest.approx([0.1, 0.1], abs=0.02)  # the motors lag their command a little
    with pytest.raises(ValueError, match=r"amplitude must be a number in \[0, 0.5\]"):
        sweep.inputs()["amplitude"]({"amplitude": 2.0})
    sweep.inputs()["amplitude"]({"amplitude": 0.3})
    run(engine, 1.0)  # one more period: the same phase, the new amplitude
    assert engine.state.position == pytest.approx([0.3, 0.3], abs=0.05)
    assert all(j["owner"] == "sweep" for j in engine.status()["joints"])
    assert math.isfinite(engine.state.velocity[0])
