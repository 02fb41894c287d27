"""configs/arm6.urdf and configs/arm6_gripper.urdf (what ROS tools see) are the same robots as configs/arm6.xml and
configs/arm6_gripper.xml (what the twin simulates): MuJoCo compiles both files of a pair, and joints, limits,
inertials, the gripper's mimic coupling and the pose of every link agree at random configurations."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import pytest

from hild.config import load_config
from tests.conftest import CONFIGS

ARM_LINKS = ["shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link"]
TOL = 1e-6


@dataclass(frozen=True)
class Pair:
    """One robot as MJCF and URDF, its twin config, the link each joint moves (joint order), the links without a
    joint of their own, and which URDF link stands for which MJCF site."""

    mjcf: str
    urdf: str
    config: str
    links: list[str]
    fixed_links: list[str]
    sites: dict[str, str]


PAIRS = [
    Pair("arm6.xml", "arm6.urdf", "arm6_twin.yaml", ARM_LINKS, [], {"tool": "tool0"}),
    Pair(
        "arm6_gripper.xml",
        "arm6_gripper.urdf",
        "arm6_gripper_twin.yaml",
        [*ARM_LINKS, "finger_left_link", "finger_right_link"],
        ["ft_sensor_link", "hand_link"],
        {"tool": "tool0", "ft_site": "ft_sensor_link", "tcp": "tcp"},
    ),
]


@pytest.fixture(scope="module", params=PAIRS, ids=lambda pair: pair.urdf)
def pair(request: pytest.FixtureRequest) -> Pair:
    chosen: Pair = request.param
    return chosen


@pytest.fixture(scope="module")
def models(pair: Pair) -> tuple[mujoco.MjModel, mujoco.MjModel]:
    return mujoco.MjModel.from_xml_path(str(CONFIGS / pair.mjcf)), mujoco.MjModel.from_xml_path(
        str(CONFIGS / pair.urdf)
    )


def _joints(model: mujoco.MjModel) -> list[str]:
    """The robot's joints: hinges and slides (the MJCF's free box is a prop, not part of the robot)."""
    scalar = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return [model.joint(i).name for i in range(model.njnt) if int(model.jnt_type[i]) in scalar]


def _ids(model: mujoco.MjModel, joints: list[str]) -> list[int]:
    return [model.joint(name).id for name in joints]


def _mimic_followers(model: mujoco.MjModel) -> list[str]:
    return [model.joint(int(model.eq_obj1id[e])).name for e in range(model.neq)]


def _inertia(model: mujoco.MjModel, body: str) -> np.ndarray[Any, Any]:
    """The body's inertia tensor in its own frame (MuJoCo stores principal axes, in an order of its choosing)."""
    b = model.body(body)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, b.iquat)
    r = rot.reshape(3, 3)
    return np.asarray(r @ np.diag(b.inertia) @ r.T)


def test_joints_axes_limits_and_damping_agree(pair: Pair, models: tuple[mujoco.MjModel, mujoco.MjModel]) -> None:
    mjcf, urdf = models
    joints = _joints(mjcf)
    assert _joints(urdf) == joints
    driven = [name for name in joints if name not in _mimic_followers(mjcf)]
    assert driven == list(load_config(CONFIGS / pair.config).config.joints)
    a, b = _ids(mjcf, joints), _ids(urdf, joints)
    np.testing.assert_array_equal(urdf.jnt_type[b], mjcf.jnt_type[a])
    np.testing.assert_allclose(urdf.jnt_axis[b], mjcf.jnt_axis[a], atol=TOL)
    np.testing.assert_allclose(urdf.jnt_range[b], mjcf.jnt_range[a], atol=TOL)
    assert urdf.jnt_limited[b].all() and mjcf.jnt_limited[a].all()
    np.testing.assert_allclose(urdf.jnt_actfrcrange[b], mjcf.jnt_actfrcrange[a], atol=TOL)  # <limit effort>
    np.testing.assert_allclose(urdf.dof_damping[urdf.jnt_dofadr[b]], mjcf.dof_damping[mjcf.jnt_dofadr[a]], atol=TOL)
    assert [urdf.joint(j).bodyid[0] for j in b] == [urdf.body(n).id for n in pair.links]
    assert [mjcf.joint(j).bodyid[0] for j in a] == [mjcf.body(n).id for n in pair.links]


def test_mimic_couplings_agree(pair: Pair, models: tuple[mujoco.MjModel, mujoco.MjModel]) -> None:
    """URDF's <mimic> (MuJoCo makes it a joint equality) and the MJCF's <equality><joint> couple the same joints
    the same way: follower = multiplier · leader + offset."""
    mjcf, urdf = models

    def couplings(model: mujoco.MjModel) -> list[tuple[str, str, list[float]]]:
        assert (model.eq_type == int(mujoco.mjtEq.mjEQ_JOINT)).all()
        return [
            (
                model.joint(int(model.eq_obj1id[e])).name,
                model.joint(int(model.eq_obj2id[e])).name,
                [*model.eq_data[e, :5]],
            )
            for e in range(model.neq)
        ]

    assert couplings(urdf) == couplings(mjcf)
    mimics = {
        j.get("name"): j.find("mimic")
        for j in ET.parse(CONFIGS / pair.urdf).getroot().iter("joint")
        if j.find("mimic") is not None
    }
    for follower, leader, coefficients in couplings(mjcf):
        mimic = mimics[follower]
        assert mimic is not None and mimic.get("joint") == leader
        assert coefficients == [float(mimic.get("offset", "0")), float(mimic.get("multiplier", "1")), 0.0, 0.0, 0.0]
    if pair.mjcf == "arm6_gripper.xml":
        assert couplings(mjcf) == [("gripper_mirror", "gripper", [0.0, 1.0, 0.0, 0.0, 0.0])]


def test_inertials_agree(pair: Pair, models: tuple[mujoco.MjModel, mujoco.MjModel]) -> None:
    mjcf, urdf = models
    for link in pair.links + pair.fixed_links:
        assert urdf.body(link).mass[0] == pytest.approx(mjcf.body(link).mass[0], abs=TOL), link
        np.testing.assert_allclose(urdf.body(link).ipos, mjcf.body(link).ipos, atol=TOL, err_msg=link)
        np.testing.assert_allclose(_inertia(urdf, link), _inertia(mjcf, link), atol=TOL, err_msg=link)


def test_forward_kinematics_agree_at_random_configurations(
    pair: Pair, models: tuple[mujoco.MjModel, mujoco.MjModel]
) -> None:
    mjcf, urdf = models
    a, b = mujoco.MjData(mjcf), mujoco.MjData(urdf)
    joints = _joints(mjcf)
    qa, qb = mjcf.jnt_qposadr[_ids(mjcf, joints)], urdf.jnt_qposadr[_ids(urdf, joints)]
    ranges = mjcf.jnt_range[_ids(mjcf, joints)]
    rng = np.random.default_rng(17)
    home = mjcf.key("home").qpos[qa]
    for q in [np.zeros(len(joints)), home, *(rng.uniform(ranges[:, 0], ranges[:, 1]) for _ in range(20))]:
        a.qpos[qa] = q
        b.qpos[qb] = q
        mujoco.mj_kinematics(mjcf, a)
        mujoco.mj_kinematics(urdf, b)
        for link in pair.links + pair.fixed_links:
            np.testing.assert_allclose(b.body(link).xpos, a.body(link).xpos, atol=TOL, err_msg=link)
            np.testing.assert_allclose(b.body(link).xmat, a.body(link).xmat, atol=TOL, err_msg=link)
            np.testing.assert_allclose(b.body(link).xipos, a.body(link).xipos, atol=TOL, err_msg=link)
        for site, link in pair.sites.items():  # the flange, the F/T sensor's frame, the grasp centre
            np.testing.assert_allclose(b.body(link).xpos, a.site(site).xpos, atol=TOL, err_msg=site)
            np.testing.assert_allclose(b.body(link).xmat, a.site(site).xmat, atol=TOL, err_msg=site)


def test_urdf_velocity_and_effort_limits_are_the_configs(pair: Pair) -> None:
    """What MoveIt plans with (the URDF's <limit>) is what hild enforces (the twin config's joint limits)."""
    joints = load_config(CONFIGS / pair.config).config.joints
    limits = {j.get("name"): j.find("limit") for j in ET.parse(CONFIGS / pair.urdf).getroot().iter("joint")}
    for name, joint in joints.items():
        limit = limits[name]
        assert limit is not None, name
        assert float(limit.get("velocity", "nan")) == joint.limits.velocity, name
        assert float(limit.get("effort", "nan")) == joint.limits.effort, name
        assert float(limit.get("lower", "nan")) == joint.limits.position.lower, name
        assert float(limit.get("upper", "nan")) == joint.limits.position.upper, name


def test_urdf_soft_limits_are_hilds(pair: Pair) -> None:
    """MoveIt bounds its plans by <safety_controller>'s soft limits: they are where hild's soft margin begins."""
    joints = load_config(CONFIGS / pair.config).config.joints
    urdf_joints = ET.parse(CONFIGS / pair.urdf).getroot().iter("joint")
    safety = {j.get("name"): j.find("safety_controller") for j in urdf_joints}
    for name, joint in joints.items():
        soft = safety[name]
        assert soft is not None, name
        margin = joint.limits.soft_margin
        assert float(soft.get("soft_lower_limit", "nan")) == pytest.approx(joint.limits.position.lower + margin), name
        assert float(soft.get("soft_upper_limit", "nan")) == pytest.approx(joint.limits.position.upper - margin), name
