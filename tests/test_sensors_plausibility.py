"""Sensor plausibility (docs/safety.md, "Sensor plausibility"): each rule shown with a reading that fails it, on the
mock driver's settable sensors in lockstep."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.mock import MockHardware
from hild.cycle.engine import Engine
from tests.api.conftest import engine_from
from tests.conftest import mock_robot
from tests.helpers import component

STALE = 10  # safety.stale_feedback_cycles in these tests
FROZEN = 5


def sensor_engine(tmp_path: Path, noise: float = 0.01, **ft: Any) -> Engine:
    config = mock_robot()
    config["safety"] = {"stale_feedback_cycles": STALE}
    config["hardware"]["bus"]["sensors"] = {
        "ft": {
            "type": "force_torque",
            "frame_id": "tool",
            "params": {"values": [1.0, 2.0, 3.0, 0.1, 0.2, 0.3], "noise": noise},
            "frozen_cycles": FROZEN,
            **ft,
        },
        "imu": {"type": "imu", "frame_id": "base"},
    }
    engine = engine_from(config, tmp_path)
    engine.start()
    return engine


def mock(engine: Engine) -> MockHardware:
    return component(engine, MockHardware)


def ft(engine: Engine) -> np.ndarray:
    return engine.sensors.values[:6].copy()


def messages(engine: Engine) -> list[str]:
    return [e.message for e in engine.events.drain()]


def sensor_status(engine: Engine, name: str) -> dict[str, Any]:
    return next(s for s in engine.status()["sensors"] if s["name"] == name)


def assert_joints_untouched(engine: Engine) -> None:
    status = engine.status()
    assert status["mode"] == "hold"
    assert all(j["fault"] is None and j["mode"] == "hold" for j in status["joints"])


def test_a_plausible_reading_is_accepted_and_fresh(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    engine.run_cycles(3)
    assert engine.sensors.fresh.tolist() == [True, True]
    np.testing.assert_allclose(ft(engine), [1.0, 2.0, 3.0, 0.1, 0.2, 0.3], atol=0.05)
    assert sensor_status(engine, "ft") == {
        "name": "ft", "type": "force_torque", "frame_id": "tool", "hardware": "bus", "fault": None
    }  # fmt: skip


def test_a_non_finite_reading_is_replaced_by_the_last_accepted_one(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    engine.run_cycles(2)
    messages(engine)
    before = ft(engine)
    mock(engine).sensor_values["ft"][2] = math.nan
    engine.run_cycles(1)
    assert not engine.sensors.fresh[0] and engine.sensors.fresh[1]  # the other sensor is not concerned
    np.testing.assert_array_equal(ft(engine), before)
    assert any("sensor ft: reading rejected: non-finite value" in m for m in messages(engine))
    mock(engine).sensor_values["ft"][2] = 3.0
    engine.run_cycles(1)
    assert engine.sensors.fresh[0]
    assert any("sensor ft: readings plausible again after 1 rejected" in m for m in messages(engine))


def test_a_reading_beyond_its_range_is_rejected(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path, limits={"force": 100.0, "torque": 5.0})
    engine.run_cycles(2)
    messages(engine)
    before = ft(engine)
    mock(engine).sensor_values["ft"][4] = 7.0  # torque.y beyond ±5 N·m
    engine.run_cycles(3)
    assert not engine.sensors.fresh[0]
    np.testing.assert_array_equal(ft(engine), before)
    rejected = [m for m in messages(engine) if "reading rejected" in m]
    assert len(rejected) == 1 and "torque.y = 6.9" in rejected[0] and "beyond its range ±5" in rejected[0]


def test_a_frozen_reading_is_rejected_and_accepted_again_once_it_moves(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path, noise=0.0)  # no noise: every reading bit-identical to the one before
    engine.run_cycles(FROZEN - 2)  # with the start-up read: FROZEN - 1 identical readings
    assert engine.sensors.fresh[0]
    engine.run_cycles(1)
    assert not engine.sensors.fresh[0]
    assert any(f"bit-identical for {FROZEN} readings in a row (frozen)" in m for m in messages(engine))
    mock(engine).sensor_values["ft"][0] = 1.001
    engine.run_cycles(1)
    assert engine.sensors.fresh[0]
    assert ft(engine)[0] == 1.001


def test_a_sensor_without_an_accepted_reading_faults_without_faulting_a_joint(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    engine.run_cycles(2)
    messages(engine)
    mock(engine).sensor_silent.add("ft")
    engine.run_cycles(STALE - 1)
    assert sensor_status(engine, "ft")["fault"] is None
    seq = engine.change_seq
    engine.run_cycles(1)
    assert engine.change_seq > seq  # a new snapshot carries it
    assert sensor_status(engine, "ft")["fault"] == f"no accepted reading for {STALE} cycles"
    assert sensor_status(engine, "imu")["fault"] is None
    assert [m for m in messages(engine) if "fault" in m] == [f"sensor ft fault: no accepted reading for {STALE} cycles"]
    assert_joints_untouched(engine)
    engine.run_cycles(50)
    assert not [m for m in messages(engine) if "fault" in m]  # latched, reported once


def test_reset_clears_a_sensor_fault_and_a_still_silent_sensor_faults_again(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    mock(engine).sensor_silent.add("ft")
    engine.run_cycles(STALE + 1)
    assert sensor_status(engine, "ft")["fault"]
    mock(engine).sensor_silent.clear()
    reply = engine.reset()
    assert isinstance(reply, dict)
    assert f"sensor ft: no accepted reading for {STALE} cycles" in reply["cleared"]
    engine.run_cycles(STALE + 1)
    assert sensor_status(engine, "ft")["fault"] is None and engine.sensors.fresh[0]
    mock(engine).sensor_silent.add("ft")
    engine.reset()
    engine.run_cycles(STALE)
    assert sensor_status(engine, "ft")["fault"]


def test_a_rejected_reading_too_long_names_its_reason_in_the_fault(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    engine.run_cycles(1)
    mock(engine).sensor_values["ft"][0] = math.inf
    engine.run_cycles(STALE)
    fault = sensor_status(engine, "ft")["fault"]
    assert fault.startswith(f"no accepted reading for {STALE} cycles (last rejected: non-finite value")
    assert_joints_untouched(engine)


def test_read_sensors_failing_is_reported_once_and_faults_the_sensors_only(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    engine.run_cycles(1)
    messages(engine)
    mock(engine).sensor_error = "sensor bus timeout"
    engine.run_cycles(STALE)
    assert engine.sensors.fresh.tolist() == [False, False]
    got = messages(engine)
    assert [m for m in got if "reading its sensors failed" in m] == [
        "reading its sensors failed: HardwareError: sensor bus timeout"
    ]
    assert {s["name"] for s in engine.status()["sensors"] if s["fault"]} == {"ft", "imu"}
    assert_joints_untouched(engine)
    mock(engine).sensor_error = None
    engine.run_cycles(1)
    assert engine.sensors.fresh.tolist() == [True, True]
    assert "reading its sensors works again" in messages(engine)


def test_controllers_see_the_accepted_values_read_only(tmp_path: Path) -> None:
    engine = sensor_engine(tmp_path)
    engine.run_cycles(1)
    view = engine.controller_context("probe").sensors
    assert view.names == ("ft", "imu")
    assert view.interfaces[0] == "ft/force.x" and view.interfaces[-1] == "imu/linear_acceleration.z"
    assert view.index_of(["imu/orientation.w"]).tolist() == [9]
    assert view.sensor_index("imu/orientation.w") == 1
    with pytest.raises(ValueError):
        view.values[0] = 5.0
    with pytest.raises(ValueError):
        view.fresh[0] = False
    with pytest.raises(ValueError, match="no sensor provides"):
        view.index_of(["ft/force.w"])
    mock(engine).sensor_values["ft"][0] = 42.0
    engine.run_cycles(1)
    assert abs(view.values[0] - 42.0) < 0.1  # live: the engine's accepted values


def test_sensors_add_no_allocation_to_the_cycle(tmp_path: Path) -> None:
    """The raw values a driver writes are views of the gate's array: nothing is copied between them."""
    engine = sensor_engine(tmp_path)
    slot = engine.hardware[0]
    assert slot.sensors is not None
    assert np.shares_memory(slot.sensors.values, engine.sensor_gate.raw.values)
    assert np.shares_memory(engine.sensors.values, engine.sensor_gate.accepted)
