"""Emulator on in-process python-can `virtual` buses: a host loop in lockstep with `Emulator.service`."""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Iterator

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.emulator import DamiaoFirmware, Emulator, MotorPlant, ODriveFirmware, TMotorFirmware
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol import odrive as od
from drivers.can.protocol.flavours import DAMIAO, TMOTOR, MitReply
from drivers.can.protocol.mit import MitRanges

DM4310 = MitRanges(12.5, 30.0, 10.0)
_channels = itertools.count()


def bus_pair() -> tuple[can.BusABC, can.BusABC]:
    channel = f"hild-test-{next(_channels)}"
    return can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)


@pytest.fixture
def buses() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    host, emu = bus_pair()
    yield host, emu
    host.shutdown()
    emu.shutdown()


def drain(bus: can.BusABC) -> list[can.Message]:
    frames = []
    while (msg := bus.recv(timeout=0)) is not None:
        frames.append(msg)
    return frames


def damiao_replies(bus: can.BusABC, esc: int = 1, mst: int = 0x11) -> list[MitReply]:
    return [DAMIAO.decode_reply(m, DM4310, esc, master_id=mst) for m in drain(bus)]


def test_host_loop_drives_a_damiao_motor_to_the_commanded_position(buses: tuple[can.BusABC, can.BusABC]) -> None:
    host, emu_bus = buses
    motor = DamiaoFirmware(1, 0x11, DM4310, timeout_counts=200)
    plant = MotorPlant(1, inertia=0.005, damping=0.05)
    emulator = Emulator(emu_bus, [motor], plant)

    host.send(DAMIAO.special(1, "enable"))
    emulator.service(0.0)
    (first,) = damiao_replies(host)
    assert first.enabled and first.position == pytest.approx(0.0, abs=1e-3)  # start-up reads where the arm is

    trace = []
    for k in range(1, 501):  # 0.5 s at 1 kHz
        host.send(DAMIAO.command(1, 1.0, 0.0, 20.0, 1.0, 0.0, DM4310))
        emulator.service(k * 0.001)
        (reply,) = damiao_replies(host)
        assert reply.enabled and reply.fault == 0
        trace.append(reply.position)
    assert trace[10] > 0.0 and trace[100] > trace[10]
    assert trace[-1] == pytest.approx(1.0, abs=2e-3)
    assert plant.positions[0] == pytest.approx(1.0, abs=2e-3)
    assert emulator.stats()["unknown"] == 0 and emulator.counters["sent"] == 501

    host.send(DAMIAO.special(1, "disable"))
    emulator.service(0.501)
    assert damiao_replies(host)[0].enabled is False


def test_commands_stopping_latch_lost_comm_and_the_arm_is_not_driven(buses: tuple[can.BusABC, can.BusABC]) -> None:
    host, emu_bus = buses
    motor = DamiaoFirmware(1, 0x11, DM4310, timeout_counts=100)  # 5 ms
    plant = MotorPlant(1, inertia=0.01, gravity=0.5, positions=0.5)  # gravity pulls it back toward 0
    emulator = Emulator(emu_bus, [motor], plant)
    host.send(DAMIAO.special(1, "enable"))
    emulator.service(0.0)
    for k in range(1, 21):
        host.send(DAMIAO.command(1, 0.5, 0.0, 30.0, 1.0, 0.0, DM4310))
        emulator.service(k * 0.001)
    drain(host)
    held = float(plant.positions[0])
    for k in range(21, 121):  # host stalls for 100 ms; the emulator keeps running
        emulator.service(k * 0.001)
    assert motor.fault == 0xD and not motor.enabled
    host.send(DAMIAO.command(1, 0.5, 0.0, 30.0, 1.0, 0.0, DM4310))
    emulator.service(0.121)
    (reply,) = damiao_replies(host)
    assert (reply.enabled, reply.fault) == (False, 0xD)
    # limp after 5 ms: gravity (a = -0.5 * sin(0.5) / 0.01 = -24 rad/s²) pulls it ~0.5 * 24 * 0.095² = 0.11 rad
    assert plant.positions[0] < held - 0.05


def run_lossy_scenario(seed: int) -> tuple[list[tuple[int, bytes]], float, dict[str, int]]:
    host, emu_bus = bus_pair()
    motor = DamiaoFirmware(1, 0x11, DM4310, seed=seed)
    motor.drop_replies = 0.3
    emulator = Emulator(emu_bus, [motor], MotorPlant(1, inertia=0.005, damping=0.05))
    host.send(DAMIAO.special(1, "enable"))
    emulator.service(0.0)
    received = []
    for k in range(1, 201):
        host.send(DAMIAO.command(1, 0.3 * math.sin(k * 0.01), 0.0, 20.0, 1.0, 0.0, DM4310))
        emulator.service(k * 0.001)
        received += [(m.arbitration_id, bytes(m.data)) for m in drain(host)]
    stats = emulator.stats()
    final = float(emulator.plant.positions[0])
    host.shutdown()
    emu_bus.shutdown()
    return received, final, stats


def test_service_is_deterministic_including_seeded_drops() -> None:
    first, second, other_seed = run_lossy_scenario(7), run_lossy_scenario(7), run_lossy_scenario(8)
    assert first == second
    received, _, stats = first
    assert 0 < stats["dropped"] < 201 and len(received) == 201 - stats["dropped"]
    assert 0.2 < stats["dropped"] / 201 < 0.4
    assert other_seed[0] != first[0]


def test_reply_delay_and_silence(buses: tuple[can.BusABC, can.BusABC]) -> None:
    host, emu_bus = buses
    motor = TMotorFirmware(2, MitRanges(12.5, 50.0, 18.0))
    emulator = Emulator(emu_bus, [motor], MotorPlant(1))
    motor.reply_delay = 0.0025
    host.send(TMOTOR.special(2, "enable"))
    emulator.service(0.0)
    assert drain(host) == []
    emulator.service(0.002)
    assert drain(host) == []
    emulator.service(0.003)
    (late,) = drain(host)
    assert TMOTOR.decode_reply(late, motor.ranges, 2).motor_id == 2
    motor.reply_delay = 0.0
    motor.silent = True
    host.send(TMOTOR.special(2, "disable"))
    emulator.service(0.004)
    assert drain(host) == [] and motor.enabled  # a silent drive neither hears nor answers
    motor.silent = False
    host.send(TMOTOR.special(2, "disable"))
    emulator.service(0.005)
    assert len(drain(host)) == 1 and not motor.enabled
    assert emulator.stats()["unheard"] == 1


def test_odrive_behind_the_emulator(buses: tuple[can.BusABC, can.BusABC]) -> None:
    host, emu_bus = buses
    axis = ODriveFirmware(3, heartbeat_period=0.1, encoder_period=0.01, pos_gain=20.0, vel_gain=0.2)
    plant = MotorPlant(1, inertia=0.002, damping=0.01)
    emulator = Emulator(emu_bus, [axis], plant)
    host.send(od.encode_set_axis_state(3, od.AxisState.CLOSED_LOOP_CONTROL))
    host.send(od.encode_set_input_pos(3, 0.25))
    frames = []
    for k in range(1001):
        emulator.service(k * 0.001)
        frames += drain(host)
    kinds = [od.split_id(f.arbitration_id) for f in frames]
    assert kinds.count((3, od.Cmd.HEARTBEAT)) == 11 and kinds.count((3, od.Cmd.GET_ENCODER_ESTIMATES)) == 101
    *_, last = (od.decode_encoder_estimates(f.data) for f, k in zip(frames, kinds, strict=True) if k[1] == 0x09)
    assert last.position == pytest.approx(0.25, abs=1e-3) and axis.enabled
    assert plant.positions[0] == pytest.approx(0.25 * 2 * math.pi, abs=5e-3)


def test_several_motors_routing_unknown_and_error_frames(buses: tuple[can.BusABC, can.BusABC]) -> None:
    host, emu_bus = buses
    motors = [DamiaoFirmware(1, 0x11, DM4310), DamiaoFirmware(2, 0x12, DM4310)]
    emulator = Emulator(emu_bus, motors, MotorPlant(2, positions=[0.1, -0.2]))
    host.send(reg.read_request(2, reg.TMAX))
    host.send(DAMIAO.special(1, "enable"))
    host.send(can.Message(arbitration_id=0x555, data=b"\x01", is_extended_id=False))
    host.send(can.Message(arbitration_id=0x1, is_error_frame=True))
    emulator.service(0.0)
    frames = drain(host)
    assert reg.decode_register_reply(frames[0]) == (2, reg.TMAX, 10.0) and frames[0].arbitration_id == 0x12
    assert DAMIAO.decode_reply(frames[1], DM4310, 1).enabled and not motors[1].enabled
    assert (emulator.counters["unknown"], emulator.counters["error_frames"], emulator.counters["received"]) == (1, 1, 4)
    with pytest.raises(ValueError, match="2 joints for 1 motors"):
        Emulator(emu_bus, motors[:1], MotorPlant(2))


frames_strategy = st.lists(
    st.builds(
        lambda arb, data, ext, rtr: can.Message(
            arbitration_id=arb, data=None if rtr else data, is_extended_id=ext, is_remote_frame=rtr, dlc=len(data)
        ),
        st.integers(0, 0x7FF),
        st.binary(max_size=8),
        st.booleans(),
        st.booleans(),
    ),
    max_size=30,
)


@settings(max_examples=60, deadline=None)
@given(frames=frames_strategy)
def test_random_frames_never_crash_and_are_all_accounted_for(frames: list[can.Message]) -> None:
    host, emu_bus = bus_pair()
    try:
        motors = [
            DamiaoFirmware(1, 0x11, DM4310, timeout_counts=20),
            TMotorFirmware(2, MitRanges(12.5, 50.0, 18.0)),
            ODriveFirmware(5),
        ]
        emulator = Emulator(emu_bus, motors, MotorPlant(3))
        for msg in frames:
            host.send(msg)
        emulator.service(0.0)
        emulator.service(0.01)
        stats = emulator.stats()
        assert stats["received"] == len(frames)
        assert stats["received"] == stats["unknown"] + stats["error_frames"] + stats["handled"] + stats["garbled"]
        assert np.all(np.isfinite(emulator.plant.positions))
    finally:
        host.shutdown()
        emu_bus.shutdown()


def test_motor_plant_physics() -> None:
    plant = MotorPlant(2, inertia=[0.1, 0.1], gravity=[1.0, 0.0], constant_load=[0.0, 0.2], positions=[0.3, 0.0])
    torques = np.zeros(2)
    plant.step(torques, 0.001)
    # joint 0: a = -1.0 * sin(0.3) / 0.1 = -2.955; joint 1: a = 0.2 / 0.1 = 2
    assert plant.velocities == pytest.approx([-2.955202e-3, 2e-3], rel=1e-5)
    stiff = MotorPlant(1, inertia=0.001, damping=100.0, velocities=10.0)
    stiff.step(np.zeros(1), 0.01)  # explicit damping would overshoot wildly (b·dt/J = 1000)
    assert 0.0 < stiff.velocities[0] < 10.0 / 1000
    with pytest.raises(ValueError, match="inertia"):
        MotorPlant(1, inertia=0.0)


def test_run_serves_on_the_wall_clock(buses: tuple[can.BusABC, can.BusABC]) -> None:
    host, emu_bus = buses
    emulator = Emulator(emu_bus, [DamiaoFirmware(1, 0x11, DM4310)], MotorPlant(1))
    stop = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop, 0.001), daemon=True)
    thread.start()
    try:
        host.send(DAMIAO.special(1, "enable"))
        reply = host.recv(timeout=5.0)  # waits for the answer, not for a fixed time
        assert reply is not None and DAMIAO.decode_reply(reply, DM4310, 1).enabled
    finally:
        stop.set()
        thread.join(timeout=5.0)
    assert not thread.is_alive()
