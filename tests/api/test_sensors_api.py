"""Sensors over the JSON API: the wrench topic per broadcaster, sensors in status, list_interfaces, list_hardware."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from hild.api.client import HildClient
from tests.api.conftest import ROBOT, Daemon, engine_from, robot_config, running
from tests.helpers import wait_for


def sensor_config() -> dict[str, Any]:
    config = robot_config()
    config["hardware"]["bus"]["sensors"] = {
        "wrist_ft": {"type": "force_torque", "frame_id": "ft_link", "params": {"values": [1, 2, 3, 0.1, 0.2, 0.3]}},
        "hand_ft": {"type": "force_torque", "frame_id": "hand_link"},
    }
    for name, sensor in (("wrist_wrench", "wrist_ft"), ("hand_wrench", "hand_ft")):
        config["controllers"][name] = {
            "type": "force_torque_sensor_broadcaster",
            "params": {"sensor_name": sensor, "publish_rate": 100},
            "autostart": True,
        }
    return config


@pytest.fixture
def sensor_client(tmp_path: Path) -> Iterator[tuple[Daemon, HildClient]]:
    with (
        running(engine_from(sensor_config(), tmp_path)) as daemon,
        HildClient(ROBOT, connect=[daemon.endpoint], timeout=5.0) as client,
    ):
        yield daemon, client


class Inbox:
    def __init__(self) -> None:
        self.messages: list[dict[str, Any]] = []
        self.lock = threading.Lock()

    def __call__(self, message: dict[str, Any]) -> None:
        with self.lock:
            self.messages.append(message)

    def snapshot(self) -> list[dict[str, Any]]:
        with self.lock:
            return list(self.messages)


def test_two_broadcasters_publish_on_their_own_wrench_topics(sensor_client: tuple[Daemon, HildClient]) -> None:
    _, client = sensor_client
    wrist, hand = Inbox(), Inbox()
    with (
        client.subscribe_controller("wrist_wrench", "wrench", wrist),
        client.subscribe_controller("hand_wrench", "wrench", hand),
    ):
        wait_for(lambda: len(wrist.snapshot()) >= 3 and len(hand.snapshot()) >= 3, what="wrenches on both topics")
    message = wrist.snapshot()[-1]
    assert set(message) == {"stamp", "seq", "frame_id", "force", "torque", "fresh"}
    assert message["frame_id"] == "ft_link" and message["fresh"] is True
    assert message["force"] == pytest.approx({"x": 1.0, "y": 2.0, "z": 3.0}, abs=0.05)
    assert message["torque"] == pytest.approx({"x": 0.1, "y": 0.2, "z": 0.3}, abs=0.05)
    assert hand.snapshot()[-1]["frame_id"] == "hand_link"
    assert hand.snapshot()[-1]["force"] == pytest.approx({"x": 0.0, "y": 0.0, "z": 0.0}, abs=0.05)


def test_sensors_are_listed_in_status_hardware_and_interfaces(sensor_client: tuple[Daemon, HildClient]) -> None:
    _, client = sensor_client
    status = client.status()
    assert [(s["name"], s["fault"]) for s in status["sensors"]] == [("wrist_ft", None), ("hand_ft", None)]
    hardware = client.list_hardware()[0]
    assert [s["name"] for s in hardware["sensors"]] == ["wrist_ft", "hand_ft"]
    assert hardware["sensors"][0]["state_interfaces"][0] == "wrist_ft/force.x"
    reply = client.call("list_interfaces")
    assert reply["interfaces"] == client.list_interfaces()  # the command interfaces, as before
    state = reply["state_interfaces"]
    assert len(state) == 12 and state[5] == {"name": "wrist_ft/torque.z", "sensor": "wrist_ft", "available": True}
    controllers = {c["name"]: c for c in client.list_controllers()}
    assert controllers["hand_wrench"]["state_interfaces"][2] == "hand_ft/force.z"
    assert controllers["hand_wrench"]["claimed"] == []


def test_a_sensor_fault_shows_in_status_and_reset_clears_it(sensor_client: tuple[Daemon, HildClient]) -> None:
    daemon, client = sensor_client
    component = daemon.engine.hardware[0].component
    component.sensor_silent.add("hand_ft")  # type: ignore[attr-defined]
    wait_for(lambda: client.status()["sensors"][1]["fault"] is not None, what="the sensor fault in status")
    assert client.status()["mode"] == "hold"  # no joint faulted
    component.sensor_silent.clear()  # type: ignore[attr-defined]
    reply = client.call("reset")
    assert any(c.startswith("sensor hand_ft: no accepted reading") for c in reply["cleared"])
    wait_for(lambda: client.status()["sensors"][1]["fault"] is None, what="the fault cleared")
