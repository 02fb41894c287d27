"""odrive_can's per-cycle estimates path: well-formed frames update the axis, malformed ones are counted by kind."""

from __future__ import annotations

import math
import struct
import uuid
from pathlib import Path

import can

from drivers.can.odrive_driver import ODriveCanDriver
from drivers.can.params import ODriveCanParams
from drivers.can.protocol import odrive as od
from hild.arrays import JointState
from hild.hardware import HardwareContext


def test_estimates_of_a_wrong_length_or_not_finite_are_counted_not_used() -> None:
    channel = f"est-{uuid.uuid4().hex[:10]}"
    params = ODriveCanParams.model_validate(
        {"bus": {"interface": "virtual", "channel": channel}, "axes": {"a": {"node_id": 4}}}
    )
    driver = ODriveCanDriver(HardwareContext("arm", ("a",), Path("."), 500.0, "sim", lambda *_: None), params)
    peer = can.Bus(interface="virtual", channel=channel)
    driver.link.open()
    try:
        estimates_id = od.arbitration_id(4, od.Cmd.GET_ENCODER_ESTIMATES)
        for data in (bytes(6), struct.pack("<ff", math.nan, 0.0)):
            peer.send(can.Message(arbitration_id=estimates_id, data=data, is_extended_id=False))
        peer.send(od.encode_encoder_estimates(4, 0.5, -1.0))
        state = JointState.zeros(1)
        driver.read(0.0, 0.002, state)
        assert driver.bad_frames.totals == {"wrong length": 1, "corrupted": 1}
        assert (state.position[0], state.velocity[0], driver.estimates[0]) == (math.pi, -2.0 * math.pi, 1)
    finally:
        driver.on_cleanup()
        peer.shutdown()
