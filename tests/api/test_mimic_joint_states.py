"""joint_states with mimic joints: appended after the robot's joints as ros2_control (Jazzy) reports them —
position = multiplier·q + offset, velocity = multiplier·q̇, effort NaN (JSON null: ros2_control computes none),
fresh the followed joint's."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hild.api.client import HildClient
from hild.arrays import JointState, MimicJoints, ServoCommand
from hild.config import load_config
from hild.controller import ControllerContext, JointLimitArrays
from hild.controllers.joint_state_broadcaster import BroadcasterParams, JointStateBroadcaster
from hild.crossing.ring import RingReader
from tests.api.conftest import ROBOT, engine_from, robot_config, running
from tests.helpers import wait_for

MIMIC_JOINTS = {
    "a_twin": {"joint": "a", "multiplier": -1.0, "offset": 0.05},
    "c_twin": {"joint": "c", "multiplier": 2.0},
}


def mimic_config() -> dict[str, Any]:
    config = robot_config()
    config["mimic_joints"] = MIMIC_JOINTS
    return config


@pytest.fixture
def mimic_client(tmp_path: Path) -> Iterator[HildClient]:
    with running(engine_from(mimic_config(), tmp_path)) as d, HildClient(ROBOT, connect=[d.endpoint], timeout=5.0) as c:
        yield c


def test_joint_states_json_appends_the_mimic_joints(mimic_client: HildClient) -> None:
    samples: list[dict[str, Any]] = []
    with mimic_client.subscribe("joint_states", samples.append):
        wait_for(lambda: len(samples) >= 3, what="joint states")
    last = samples[-1]
    assert last["name"] == ["a", "b", "c", "a_twin", "c_twin"]
    a, b, c = last["position"][:3]
    assert (a, b, c) == pytest.approx([0.1, -0.1, 0.0])
    assert last["position"][3:] == pytest.approx([-1.0 * a + 0.05, 2.0 * c])
    assert last["velocity"][3:] == pytest.approx([0.0, 0.0])
    assert last["effort"][3:] == [None, None]  # NaN on the wire: ros2_control gives a mimic joint no effort
    assert last["fresh"] == [1.0] * 5


def broadcaster(tmp_path: Path) -> JointStateBroadcaster:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(mimic_config(), sort_keys=False))
    cfg = load_config(path).config
    context = ControllerContext(
        robot=ROBOT,
        name="jsb",
        joints=tuple(cfg.joints),
        limits=JointLimitArrays.of(cfg),
        update_rate=cfg.update_rate,
        emit_event=lambda level, message: None,
        notify=lambda: None,
        mimic_joints=MimicJoints.of(cfg),
    )
    return JointStateBroadcaster(context, BroadcasterParams())


def test_each_sample_computes_the_mimic_joints_from_the_joints_they_follow(tmp_path: Path) -> None:
    jsb = broadcaster(tmp_path)
    state = JointState.zeros(3)
    state.position[:] = [0.3, 0.7, -0.2]
    state.velocity[:] = [1.5, 0.0, -0.5]
    state.effort[:] = [2.0, 3.0, 4.0]
    state.fresh[:] = [False, True, True]
    jsb.on_activate(state, ServoCommand.zeros(3))
    jsb.update(0.0, 0.002, state, ServoCommand.zeros(3))
    ((_, _, fields),) = RingReader(jsb.ring, start_at_head=False).read()
    np.testing.assert_allclose(fields["position"], [0.3, 0.7, -0.2, -0.3 + 0.05, -0.4])
    np.testing.assert_allclose(fields["velocity"], [1.5, 0.0, -0.5, -1.5, -1.0])
    assert fields["effort"][:3] == [2.0, 3.0, 4.0] and all(math.isnan(e) for e in fields["effort"][3:])
    assert fields["fresh"] == [0.0, 1.0, 1.0, 0.0, 1.0]  # a mimic joint is as fresh as the joint it follows
    assert jsb.ring.names == ["a", "b", "c", "a_twin", "c_twin"]
