"""The drivers' cycle path (preallocated frames, specialised codecs) against the reference codecs, frame by frame.

A driver with its link open and a plain virtual bus as the other end: every frame ``write`` sends must carry the
bytes the reference encoder builds for that cycle's command (stale bytes of earlier cycles included), and every value
``read`` reports must be the reference decoder's float, compared with ``==``.
"""

from __future__ import annotations

import math
import random
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.can.mit_driver import MitCanDriver
from drivers.can.odrive_driver import ODriveCanDriver
from drivers.can.params import MitCanParams, ODriveCanParams
from drivers.can.protocol import odrive as od
from drivers.can.protocol.flavours import FLAVOURS, MitReply
from drivers.can.protocol.mit import MitRanges, encode_command
from drivers.can.protocol.models import MODELS
from hild.arrays import JointState, ServoCommand
from hild.hardware import HardwareContext

CYCLES = 150
TAU = 2.0 * math.pi
MIT_MOTORS = {  # (model, motor ids); Damiao replies on per-motor reply ids 0x11..
    "damiao": ("DM4340", [1, 2, 0x23]),  # 0x23: only its low nibble is in the reply's D0
    "tmotor": ("AK80-9", [1, 2, 3]),
    "myactuator": ("motion_mode", [1, 2, 3]),
}


GAINS_AND_MODE = [  # kp > 0: position control; kp = 0, kd > 0: velocity; both 0: torque
    (30.0, 1.0, od.ControlMode.POSITION_CONTROL),
    (0.0, 1.0, od.ControlMode.VELOCITY_CONTROL),
    (0.0, 0.0, od.ControlMode.TORQUE_CONTROL),
]


def context(joints: tuple[str, ...]) -> HardwareContext:
    return HardwareContext("arm", joints, Path("."), 1000.0, "sim", lambda level, msg: None)


@pytest.fixture
def channel() -> Iterator[tuple[str, can.BusABC]]:
    name = f"codec-{uuid.uuid4().hex[:10]}"
    peer = can.Bus(interface="virtual", channel=name)
    yield name, peer
    peer.shutdown()


def received(peer: can.BusABC) -> list[can.Message]:
    frames = []
    while (msg := peer.recv(timeout=0)) is not None:
        frames.append(msg)
    return frames


def command_value(rng: random.Random, hi: float, signed: bool) -> float:
    """In range mostly; sometimes beyond it, at ±inf, or exactly at an end."""
    lo = -hi if signed else 0.0
    pick = rng.random()
    if pick < 0.7:
        return rng.uniform(lo, hi)
    if pick < 0.85:
        return rng.uniform(lo - hi, 2.0 * hi)
    return rng.choice([math.inf, -math.inf, lo, hi, -0.0])


def reply_data(rng: random.Random, flavour: str, motor: int) -> bytes:
    body = bytes(rng.getrandbits(8) for _ in range(7))
    if flavour == "damiao":  # a status the firmware sends: disabled, enabled or one of its faults
        status = rng.choice([0x0, 0x1, 0x1, 0x1, *FLAVOURS["damiao"].fault_names])
        return bytes([status << 4 | motor & 0xF]) + body
    if flavour == "tmotor" and rng.random() < 0.3:
        return bytes([motor]) + body[:5]  # older firmware: 6 bytes, no temperature or error byte
    return bytes([motor]) + body


@pytest.mark.parametrize("flavour", sorted(MIT_MOTORS))
def test_mit_cycle_sends_reference_frames_and_reads_reference_values(
    flavour: str, channel: tuple[str, can.BusABC]
) -> None:
    name, peer = channel
    model, ids = MIT_MOTORS[flavour]
    joints = tuple(f"j{i}" for i in range(len(ids)))
    motors: dict[str, dict[str, Any]] = {j: {"id": m, "model": model} for j, m in zip(joints, ids, strict=True)}
    if flavour == "damiao":
        for k, j in enumerate(joints):
            motors[j]["reply_id"] = 0x11 + k
    raw = {"bus": {"interface": "virtual", "channel": name}, "flavour": flavour, "motors": motors}
    driver = MitCanDriver(context(joints), MitCanParams.model_validate(raw))
    r: MitRanges = MODELS[flavour][model]
    fl = FLAVOURS[flavour]
    n = len(ids)
    state, command = JointState.zeros(n), ServoCommand.zeros(n)
    rng = random.Random(f"mit-{flavour}")
    temperature = [math.nan] * n
    command_ids = [fl.command_id(m) for m in ids]
    driver.link.open()
    try:
        for _ in range(CYCLES):
            for k in range(n):
                command.position[k] = command_value(rng, r.p_max, True)
                command.velocity[k] = command_value(rng, r.v_max, True)
                command.kp[k] = command_value(rng, r.kp_max, False)
                command.kd[k] = command_value(rng, r.kd_max, False)
                command.effort[k] = command_value(rng, r.t_max, True)
            driver.write(0.0, 0.001, command)
            frames = received(peer)
            sent = [m for m in frames if m.arbitration_id in command_ids]
            assert [m.arbitration_id for m in sent] == command_ids
            for msg in frames:  # besides the commands, only MyActuator's status polls (0x9A on 0x140 + id)
                assert msg in sent or (msg.arbitration_id - 0x140 in ids and msg.data[0] == 0x9A)
            for k, msg in enumerate(sent):
                want = encode_command(
                    command.position[k], command.velocity[k], command.kp[k], command.kd[k], command.effort[k], r
                )
                assert bytes(msg.data) == want

            answering = [k for k in range(n) if rng.random() < 0.8]
            replies: dict[int, MitReply] = {}
            for k in answering:
                msg = can.Message(
                    arbitration_id=driver.motors[k].reply_id,
                    data=reply_data(rng, flavour, ids[k]),
                    is_extended_id=False,
                )
                peer.send(msg)
                replies[k] = fl.decode_reply(msg, r, ids[k])
            driver.read(0.0, 0.001, state)
            assert state.fresh.tolist() == [k in replies for k in range(n)]
            for k, reply in replies.items():
                assert (state.position[k], state.velocity[k], state.effort[k]) == (
                    reply.position,
                    reply.velocity,
                    reply.torque,
                )
                reported = [t for t in (reply.temperature_mos, reply.temperature_rotor) if t is not None]
                if reported:
                    temperature[k] = max(reported)
                assert state.fault[k] == reply.fault  # nothing is expected enabled here: no FAULT_DISABLED
            assert state.temperature.tolist() == pytest.approx(temperature, nan_ok=True)
        assert driver.bad_frames.total == 0
    finally:
        driver.on_cleanup()


def test_odrive_cycle_sends_reference_frames_and_reads_reference_values(channel: tuple[str, can.BusABC]) -> None:
    name, peer = channel
    nodes = [1, 2, 5]
    joints = tuple(f"j{i}" for i in range(len(nodes)))
    raw = {
        "bus": {"interface": "virtual", "channel": name},
        "axes": {j: {"node_id": node} for j, node in zip(joints, nodes, strict=True)},
    }
    driver = ODriveCanDriver(context(joints), ODriveCanParams.model_validate(raw))
    n = len(nodes)
    state, command = JointState.zeros(n), ServoCommand.zeros(n)
    rng = random.Random("odrive")
    modes = [-1] * n
    driver.link.open()
    try:
        for _ in range(CYCLES):
            want: list[can.Message] = []
            for k, node in enumerate(nodes):
                p, v, ff = rng.uniform(-20.0, 20.0), rng.uniform(-250.0, 250.0), rng.uniform(-40.0, 40.0)
                kp, kd, mode = rng.choice(GAINS_AND_MODE)
                command.position[k], command.velocity[k], command.effort[k] = p, v, ff
                command.kp[k], command.kd[k] = kp, kd
                if mode != modes[k]:
                    want.append(od.encode_set_controller_mode(node, mode, od.InputMode.PASSTHROUGH))
                    modes[k] = mode
                if mode == od.ControlMode.POSITION_CONTROL:
                    # torque_ff is int16 × 1e-3 N·m: the driver clamps to ±32.767 itself (and reports it)
                    want.append(od.encode_set_input_pos(node, p / TAU, v / TAU, max(-32.767, min(32.767, ff))))
                elif mode == od.ControlMode.VELOCITY_CONTROL:
                    want.append(od.encode_set_input_vel(node, v / TAU, ff))
                else:
                    want.append(od.encode_set_input_torque(node, ff))
                want.append(od.request(node, od.Cmd.GET_ENCODER_ESTIMATES))
            driver.write(0.0, 0.002, command)
            sent = received(peer)
            assert [(m.arbitration_id, m.is_remote_frame, bytes(m.data)) for m in sent] == [
                (m.arbitration_id, m.is_remote_frame, bytes(m.data)) for m in want
            ]

            estimates = {}
            for k, node in enumerate(nodes):
                if rng.random() < 0.8:
                    position, velocity = rng.uniform(-1e3, 1e3), rng.uniform(-50.0, 50.0)
                    msg = od.encode_encoder_estimates(node, position, velocity)
                    peer.send(msg)
                    estimates[k] = od.decode_encoder_estimates(msg.data)
                peer.send(od.encode_heartbeat(node, od.Heartbeat(0, od.AxisState.IDLE, 0, False)))
            driver.read(0.0, 0.002, state)
            assert state.fresh.tolist() == [k in estimates for k in range(n)]
            for k, est in estimates.items():
                assert (state.position[k], state.velocity[k]) == (est.position * TAU, est.velocity * TAU)
        assert driver.bad_frames.total == 0
    finally:
        driver.on_cleanup()
