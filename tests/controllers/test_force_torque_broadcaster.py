"""force_torque_sensor_broadcaster in lockstep on the mock's settable sensors: rate, message, frame, filter, fresh."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from drivers.mock import MockHardware
from hild.controllers.force_torque_sensor_broadcaster import ForceTorqueSensorBroadcaster
from hild.crossing.requests import SetParams
from hild.crossing.ring import RingReader
from hild.cycle.engine import Engine
from tests.api.conftest import engine_from
from tests.conftest import mock_robot

WRENCH = [1.0, -2.0, 9.81, 0.1, -0.2, 0.3]


def engine_with(tmp_path: Path, params: dict[str, Any], noise: float = 0.0) -> Engine:
    config = mock_robot()
    config["hardware"]["bus"]["sensors"] = {
        "wrist_ft": {
            "type": "force_torque",
            "frame_id": "ft_link",
            "params": {"values": WRENCH, "noise": noise},
            "frozen_cycles": 100_000,  # these tests hold values still on purpose
        },
        "imu": {"type": "imu", "frame_id": "base"},
    }
    config["controllers"]["ftb"] = {"type": "force_torque_sensor_broadcaster", "params": params, "autostart": True}
    engine = engine_from(config, tmp_path)
    engine.start()
    return engine


def broadcaster(engine: Engine) -> ForceTorqueSensorBroadcaster:
    instance = engine.controllers()["ftb"]
    assert isinstance(instance, ForceTorqueSensorBroadcaster)
    return instance


def mock(engine: Engine) -> MockHardware:
    component = engine.hardware[0].component
    assert isinstance(component, MockHardware)
    return component


def messages(engine: Engine, reader: RingReader) -> list[dict[str, Any]]:
    b = broadcaster(engine)
    return [b.wrench_message(seq, stamp, fields) for seq, stamp, fields in reader.read()]


def test_it_publishes_the_sensors_wrench_at_its_rate_in_the_sensors_frame(tmp_path: Path) -> None:
    engine = engine_with(tmp_path, {"sensor_name": "wrist_ft", "publish_rate": 50})
    reader = RingReader(broadcaster(engine).ring, start_at_head=False)
    engine.run_cycles(100)  # 0.2 s at 500 Hz
    got = messages(engine, reader)
    assert len(got) == 10
    assert [round(m["stamp"], 6) for m in got[:3]] == [0.002, 0.022, 0.042]
    last = got[-1]
    assert set(last) == {"stamp", "seq", "frame_id", "force", "torque", "fresh"}
    assert last["frame_id"] == "ft_link"
    assert last["force"] == {"x": 1.0, "y": -2.0, "z": 9.81}
    assert last["torque"] == {"x": 0.1, "y": -0.2, "z": 0.3}
    assert last["fresh"] is True


def test_it_claims_nothing_and_lists_the_sensor_interfaces_it_reads(tmp_path: Path) -> None:
    engine = engine_with(tmp_path, {"sensor_name": "wrist_ft", "frame_id": "tool0"})
    info = next(c for c in engine.snapshot().controllers if c["name"] == "ftb")
    assert info["state"] == "active" and info["claimed"] == []
    assert info["state_interfaces"] == [
        f"wrist_ft/{v}" for v in ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")
    ]
    assert broadcaster(engine).frame_id == "tool0"  # a frame_id given wins over the sensor's
    engine.estop()
    reader = RingReader(broadcaster(engine).ring)
    engine.run_cycles(10)
    assert messages(engine, reader)  # still publishing under e-stop


def test_interface_names_pick_components_and_leave_the_others_zero(tmp_path: Path) -> None:
    params = {"interface_names": {"force": {"z": "wrist_ft/force.z"}, "torque": {"x": "imu/angular_velocity.x"}}}
    engine = engine_with(tmp_path, params)
    reader = RingReader(broadcaster(engine).ring)
    engine.run_cycles(5)
    last = messages(engine, reader)[-1]
    assert last["frame_id"] == "ft_link"  # the frame of the sensor of the first interface named
    assert last["force"] == {"x": 0.0, "y": 0.0, "z": 9.81}
    torque = last["torque"]
    assert 0.0 < abs(torque["x"]) < 0.05  # the IMU's angular_velocity.x: 0 at rest plus the mock's noise
    assert torque["y"] == torque["z"] == 0.0
    assert next(c for c in engine.snapshot().controllers if c["name"] == "ftb")["state_interfaces"] == [
        "wrist_ft/force.z",
        "imu/angular_velocity.x",
    ]


def test_the_low_pass_filter_follows_a_step_as_a_first_order_lag(tmp_path: Path) -> None:
    cutoff = 5.0
    engine = engine_with(tmp_path, {"sensor_name": "wrist_ft", "low_pass_cutoff": cutoff, "publish_rate": 500})
    engine.run_cycles(10)
    reader = RingReader(broadcaster(engine).ring)
    mock(engine).sensor_values["wrist_ft"][2] = 19.81  # a 10 N step on force.z
    tau = 1.0 / (2 * math.pi * cutoff)
    cycles = round(tau * 500)
    engine.run_cycles(cycles)
    z = messages(engine, reader)[-1]["force"]["z"]
    expected = 9.81 + 10.0 * (1.0 - math.exp(-cycles / 500 / tau))  # 63 % of the step after one time constant
    assert abs(z - expected) < 0.05, (z, expected)


def test_publish_rate_and_cutoff_change_while_it_runs(tmp_path: Path) -> None:
    engine = engine_with(tmp_path, {"sensor_name": "wrist_ft", "publish_rate": 10, "low_pass_cutoff": 1.0})
    b = broadcaster(engine)
    new = b.params.model_copy(update={"publish_rate": 100.0, "low_pass_cutoff": 0.0})
    future = engine.request(SetParams("ftb", new, ("publish_rate", "low_pass_cutoff")))
    engine.run_cycles(1)
    assert future.result(0)["changed"] == ["publish_rate", "low_pass_cutoff"]
    reader = RingReader(b.ring)
    mock(engine).sensor_values["wrist_ft"][2] = 19.81
    engine.run_cycles(100)
    got = messages(engine, reader)
    stamps = [m["stamp"] for m in got]
    assert stamps[0] == 0.102  # the sample the old rate (10 Hz) had already scheduled
    assert len(stamps) == 11 and np.allclose(np.diff(stamps), 0.01)  # then 100 Hz
    assert got[0]["force"]["z"] == 19.81  # no filter: the step at once


def test_a_stale_sensor_is_published_with_fresh_false_and_its_last_accepted_values(tmp_path: Path) -> None:
    engine = engine_with(tmp_path, {"sensor_name": "wrist_ft", "publish_rate": 500}, noise=0.01)
    engine.run_cycles(5)
    reader = RingReader(broadcaster(engine).ring)
    engine.run_cycles(1)
    last_good = messages(engine, reader)[-1]
    mock(engine).sensor_silent.add("wrist_ft")
    engine.run_cycles(3)
    stale = messages(engine, reader)
    assert [m["fresh"] for m in stale] == [False, False, False]
    assert all(m["force"] == last_good["force"] for m in stale)
    mock(engine).sensor_values["wrist_ft"][0] = np.nan  # a rejected reading: the same as a missing one
    mock(engine).sensor_silent.clear()
    engine.run_cycles(1)
    assert messages(engine, reader)[-1]["fresh"] is False
