"""/joint_states on the ROS 2 face names the mimic joints after the robot's joints, as joint_state_broadcaster
does with ros2_control's mimic joints (Jazzy): position multiplier·q + offset, effort NaN."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import zenoh

from hild.api.ros2 import types, wire
from tests.api.conftest import engine_from, running
from tests.api.ros2.conftest import peer_config, ros_robot_config
from tests.api.ros2.test_face import JOINT_STATE, Inbox
from tests.helpers import wait_for


def test_joint_state_carries_the_mimic_joints(tmp_path: Path) -> None:
    config = ros_robot_config(tmp_path)
    config["mimic_joints"] = {"a_twin": {"joint": "a", "multiplier": -1.0, "offset": 0.05}}
    with running(engine_from(config, tmp_path)) as daemon:
        peer = zenoh.open(peer_config(daemon.endpoint))
        try:
            inbox = Inbox()
            sub = peer.declare_subscriber(wire.data_key(0, "/joint_states", JOINT_STATE), inbox)
            wait_for(lambda: len(inbox) >= 2, what="two joint states")
            msg = types.decode(inbox.last().payload.to_bytes(), JOINT_STATE)
            sub.undeclare()
        finally:
            peer.close()
    assert list(msg.name) == ["a", "b", "c", "a_twin"]
    np.testing.assert_allclose(msg.position, [0.1, -0.1, 0.0, -0.1 + 0.05], atol=1e-6)
    np.testing.assert_allclose(msg.velocity, 0.0, atol=1e-9)
    assert len(msg.effort) == 4 and math.isnan(msg.effort[3])
