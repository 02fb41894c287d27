"""configs/arm6.urdf (what ROS tools see) is the same arm as configs/arm6.xml (what the twin simulates): MuJoCo
compiles both, and joints, limits, inertials and the pose of every link agree at random configurations."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

import mujoco
import numpy as np
import pytest

from hild.config import load_config
from tests.conftest import CONFIGS

LINKS = ["shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link"]
TOL = 1e-6


@pytest.fixture(scope="module")
def models() -> tuple[mujoco.MjModel, mujoco.MjModel]:
    return mujoco.MjModel.from_xml_path(str(CONFIGS / "arm6.xml")), mujoco.MjModel.from_xml_path(
        str(CONFIGS / "arm6.urdf")
    )


def _joints(model: mujoco.MjModel) -> list[str]:
    return [model.joint(i).name for i in range(model.njnt)]


def _inertia(model: mujoco.MjModel, body: str) -> np.ndarray[Any, Any]:
    """The body's inertia tensor in its own frame (MuJoCo stores principal axes, in an order of its choosing)."""
    b = model.body(body)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, b.iquat)
    r = rot.reshape(3, 3)
    return np.asarray(r @ np.diag(b.inertia) @ r.T)


def test_joints_axes_limits_and_damping_agree(models: tuple[mujoco.MjModel, mujoco.MjModel]) -> None:
    mjcf, urdf = models
    assert _joints(urdf) == _joints(mjcf) == list(load_config(CONFIGS / "arm6_twin.yaml").config.joints)
    np.testing.assert_allclose(urdf.jnt_axis, mjcf.jnt_axis, atol=TOL)
    np.testing.assert_allclose(urdf.jnt_range, mjcf.jnt_range, atol=TOL)
    assert urdf.jnt_limited.all() and mjcf.jnt_limited.all()
    np.testing.assert_allclose(urdf.jnt_actfrcrange, mjcf.jnt_actfrcrange, atol=TOL)  # <limit effort>
    np.testing.assert_allclose(urdf.dof_damping, mjcf.dof_damping, atol=TOL)
    assert [urdf.joint(j).bodyid[0] for j in range(6)] == [urdf.body(n).id for n in LINKS]


def test_inertials_agree(models: tuple[mujoco.MjModel, mujoco.MjModel]) -> None:
    mjcf, urdf = models
    for link in LINKS:
        assert urdf.body(link).mass[0] == pytest.approx(mjcf.body(link).mass[0], abs=TOL), link
        np.testing.assert_allclose(urdf.body(link).ipos, mjcf.body(link).ipos, atol=TOL, err_msg=link)
        np.testing.assert_allclose(_inertia(urdf, link), _inertia(mjcf, link), atol=TOL, err_msg=link)


def test_forward_kinematics_agree_at_random_configurations(models: tuple[mujoco.MjModel, mujoco.MjModel]) -> None:
    mjcf, urdf = models
    a, b = mujoco.MjData(mjcf), mujoco.MjData(urdf)
    rng = np.random.default_rng(17)
    home = mjcf.key("home").qpos
    for q in [np.zeros(6), home, *(rng.uniform(mjcf.jnt_range[:, 0], mjcf.jnt_range[:, 1]) for _ in range(20))]:
        a.qpos[:] = q
        b.qpos[:] = q
        mujoco.mj_kinematics(mjcf, a)
        mujoco.mj_kinematics(urdf, b)
        for link in LINKS:
            np.testing.assert_allclose(b.body(link).xpos, a.body(link).xpos, atol=TOL, err_msg=link)
            np.testing.assert_allclose(b.body(link).xmat, a.body(link).xmat, atol=TOL, err_msg=link)
            np.testing.assert_allclose(b.body(link).xipos, a.body(link).xipos, atol=TOL, err_msg=link)
        np.testing.assert_allclose(b.body("tool0").xpos, a.site("tool").xpos, atol=TOL)  # the flange


def test_urdf_velocity_and_effort_limits_are_the_configs() -> None:
    """What MoveIt plans with (the URDF's <limit>) is what hild enforces (arm6_twin.yaml's joint limits)."""
    joints = load_config(CONFIGS / "arm6_twin.yaml").config.joints
    limits = {j.get("name"): j.find("limit") for j in ET.parse(CONFIGS / "arm6.urdf").getroot().iter("joint")}
    for name, joint in joints.items():
        limit = limits[name]
        assert limit is not None, name
        assert float(limit.get("velocity", "nan")) == joint.limits.velocity, name
        assert float(limit.get("effort", "nan")) == joint.limits.effort, name
        assert float(limit.get("lower", "nan")) == joint.limits.position.lower, name
        assert float(limit.get("upper", "nan")) == joint.limits.position.upper, name


def test_urdf_soft_limits_are_hilds() -> None:
    """MoveIt bounds its plans by <safety_controller>'s soft limits: they are where hild's soft margin begins."""
    joints = load_config(CONFIGS / "arm6_twin.yaml").config.joints
    urdf_joints = ET.parse(CONFIGS / "arm6.urdf").getroot().iter("joint")
    safety = {j.get("name"): j.find("safety_controller") for j in urdf_joints}
    for name, joint in joints.items():
        soft = safety[name]
        assert soft is not None, name
        margin = joint.limits.soft_margin
        assert float(soft.get("soft_lower_limit", "nan")) == pytest.approx(joint.limits.position.lower + margin), name
        assert float(soft.get("soft_upper_limit", "nan")) == pytest.approx(joint.limits.position.upper - margin), name
