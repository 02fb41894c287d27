"""The fault-injection hooks of the CAN emulator: replies cut short, a bus that goes off, the drive-side jump guard,
and the same through ``hild emulate``'s control channel."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
import yaml

from drivers.can.bus import ERR_BUS_OFF, ERR_RESTARTED
from drivers.can.emulator import DamiaoFirmware, Emulator, MotorPlant
from drivers.can.emulator.runtime import RuntimeOptions, build_runtime
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.flavours import DAMIAO
from drivers.can.protocol.models import MODELS
from hild.config import load_config
from tests.faults.rigs import can_robot

DM4310 = MODELS["damiao"]["DM4310"]


@pytest.fixture
def rig() -> Iterator[tuple[Emulator, can.BusABC, DamiaoFirmware]]:
    channel = f"hooks-{uuid.uuid4().hex[:8]}"
    emulator_bus = can.Bus(interface="virtual", channel=channel)
    host = can.Bus(interface="virtual", channel=channel)
    firmware = DamiaoFirmware(1, 0x11, DM4310)
    emulator = Emulator(emulator_bus, [firmware], MotorPlant(1, positions=0.3))
    yield emulator, host, firmware
    emulator_bus.shutdown()
    host.shutdown()


def received(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=0)) is not None:
        out.append(msg)
    return out


def test_corrupted_replies_arrive_one_byte_short_then_whole(rig: tuple[Emulator, can.BusABC, DamiaoFirmware]) -> None:
    emulator, host, firmware = rig
    firmware.corrupt_replies = 2
    for k in range(3):
        host.send(reg.refresh_request(1))
        emulator.service(0.001 * (k + 1))
    lengths = [len(m.data) for m in received(host)]
    assert lengths == [7, 7, 8]
    assert firmware.counters["corrupted"] == 2 and firmware.corrupt_replies == 0


def test_bus_off_sends_the_error_frame_then_nothing_passes_until_it_restarts(
    rig: tuple[Emulator, can.BusABC, DamiaoFirmware],
) -> None:
    emulator, host, firmware = rig
    emulator.service(0.0)
    emulator.bus_off(0.0, 0.005)
    (error,) = received(host)
    assert error.is_error_frame and error.arbitration_id == ERR_BUS_OFF
    for k in range(4):  # requests during the outage are lost, and nothing is answered
        host.send(reg.refresh_request(1))
        emulator.service(0.001 * (k + 1))
    assert received(host) == [] and emulator.counters["lost_bus_off"] == 4
    assert firmware.counters["handled"] == 0
    emulator.service(0.006)  # back: the restart notice first
    (restart,) = received(host)
    assert restart.is_error_frame and restart.arbitration_id == ERR_RESTARTED
    host.send(reg.refresh_request(1))
    emulator.service(0.007)
    (reply,) = received(host)
    assert not reply.is_error_frame and len(reply.data) == 8
    with pytest.raises(ValueError):
        emulator.bus_off(0.0, 0.0)


def test_the_drive_measures_every_command_step_the_first_from_the_shaft(
    rig: tuple[Emulator, can.BusABC, DamiaoFirmware],
) -> None:
    emulator, host, firmware = rig
    emulator.service(0.0)
    host.send(DAMIAO.special(1, "enable"))
    emulator.service(0.001)
    assert firmware.enabled and firmware.command_step == 0.0
    for k, p in enumerate((0.3, 0.302, 0.31, 0.2)):  # 0 (at the shaft), 2 mrad, 8 mrad, 110 mrad
        host.send(DAMIAO.command(1, p, 0.0, 20.0, 1.0, 0.0, DM4310))
        emulator.service(0.002 + 0.001 * k)
        if k == 2:
            assert firmware.command_step == pytest.approx(0.008, abs=1e-3)
    assert firmware.command_step == pytest.approx(0.11, abs=1e-3)
    host.send(DAMIAO.command(1, 0.9, 0.0, 0.0, 1.0, 0.0, DM4310))  # kp 0: no position command, no step
    emulator.service(0.01)
    assert firmware.command_step == pytest.approx(0.11, abs=1e-3)
    host.send(DAMIAO.special(1, "disable"))
    host.send(DAMIAO.special(1, "enable"))
    emulator.service(0.011)
    assert firmware.command_step == 0.0  # counted again from the next enable


def test_the_control_channel_corrupts_replies_and_takes_the_bus_off(tmp_path: Path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(can_robot("damiao", 2, f"ctl-{uuid.uuid4().hex[:8]}", 1000.0)))
    runtime = build_runtime(load_config(path), RuntimeOptions(plant="motors"))
    runtime.open()
    try:
        reply = runtime.handle({"op": "set", "joint": "j1", "corrupt_replies": 3})
        assert reply == {"ok": True, "joints": ["j1"], "corrupt_replies": 3}
        assert runtime.joints[0].firmware.corrupt_replies == 3
        assert runtime.handle({"op": "set", "corrupt_replies": -1})["ok"] is False
        runtime.service(1.0)
        assert runtime.handle({"op": "bus_off", "duration": 0.01}) == {
            "ok": True,
            "buses": [runtime.rigs[0].spec.name],
            "duration": 0.01,
        }
        emulator = runtime.rigs[0].emulator
        assert emulator is not None and emulator.down_until == pytest.approx(1.01)
        assert "positive" in runtime.handle({"op": "bus_off", "duration": "long"})["error"]
        assert "command_step" in runtime.status()["joints"][0]
    finally:
        runtime.close()
