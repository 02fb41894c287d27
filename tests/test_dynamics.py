"""hild.dynamics: model loading and the gravity feed-forward used by hold and controllers."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from hild.dynamics.gravity import GravityModel
from hild.dynamics.inspection import body_contacts
from hild.dynamics.model import load_model

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
ARM6 = CONFIGS / "arm6.xml"
RRBOT = CONFIGS / "rrbot.urdf"
ARM6_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
RRBOT_JOINTS = ("joint1", "joint2")
G = 9.81


def bias_at_rest(model: mujoco.MjModel, names: tuple[str, ...], q: np.ndarray) -> np.ndarray:
    """Reference: qfrc_bias from a full mj_forward at qvel = 0, other joints at qpos0."""
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    for name, value in zip(names, q, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = value
    data.qvel[:] = 0.0
    mujoco.mj_forward(model, data)
    return np.array([data.qfrc_bias[model.joint(name).dofadr[0]] for name in names])


def random_poses(model: mujoco.MjModel, names: tuple[str, ...], count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = np.array([max(model.joint(n).range[0], -math.pi) for n in names])
    hi = np.array([min(model.joint(n).range[1], math.pi) for n in names])
    return rng.uniform(lo, hi, size=(count, len(names)))


# ---------------------------------------------------------------------------------------------- load_model


def test_load_model_reads_mjcf_and_urdf() -> None:
    arm = load_model(ARM6)
    rrbot = load_model(RRBOT)
    assert [arm.joint(i).name for i in range(arm.njnt)] == list(ARM6_JOINTS)
    assert [rrbot.joint(i).name for i in range(rrbot.njnt)] == list(RRBOT_JOINTS)


def test_load_model_missing_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"nothere\.xml"):
        load_model(tmp_path / "nothere.xml")


def test_load_model_broken_file_names_it_with_mujoco_message(tmp_path: Path) -> None:
    bad = tmp_path / "broken.xml"
    bad.write_text('<mujoco><worldbody><body><joint type="hinge" range="1"/></body></worldbody></mujoco>')
    with pytest.raises(ValueError, match=r"broken\.xml") as info:
        load_model(bad)
    assert "MuJoCo" in str(info.value)
    assert "range" in str(info.value)  # MuJoCo's own complaint is carried along


OVERLAPPING = """<mujoco><worldbody>
  <body name="base"><geom type="box" size="0.1 0.1 0.1"/>
    <body name="arm" pos="0 0 0.15"><joint name="lift" type="slide" axis="0 0 1" range="-0.1 0.1"/>
      <geom type="box" size="0.05 0.05 0.06"/></body></body>
  <body name="post" pos="1 0 0"><joint name="slide" type="slide" axis="1 0 0"/><geom type="sphere" size="0.1"/></body>
</worldbody></mujoco>"""


def test_contacts_at_a_pose_and_excluded_pairs(tmp_path: Path) -> None:
    path = tmp_path / "overlap.xml"
    path.write_text(OVERLAPPING)
    (touching,) = body_contacts(path, {})  # the arm sits 1 cm into its base (a world-welded parent: not filtered)
    assert (touching.first, touching.second) == ("base", "arm") and touching.depth == pytest.approx(0.01)
    assert body_contacts(path, {"lift": 0.05}) == []
    assert [(c.first, c.second) for c in body_contacts(path, {"lift": 0.05, "slide": -0.9})] == [("base", "post")]
    model = load_model(path, [("base", "arm")])
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.ncon == 0
    with pytest.raises(ValueError, match=r"exclude_contacts names bodies it does not have: nope"):
        load_model(path, [("base", "nope")])


def test_load_model_rejects_other_formats(tmp_path: Path) -> None:
    other = tmp_path / "arm.sdf"
    other.write_text("<sdf/>")
    with pytest.raises(ValueError, match=r"arm\.sdf"):
        load_model(other)


# ---------------------------------------------------------------------------------------------- GravityModel


@pytest.mark.parametrize(("path", "names"), [(ARM6, ARM6_JOINTS), (RRBOT, RRBOT_JOINTS)])
def test_gravity_equals_qfrc_bias_at_random_poses(path: Path, names: tuple[str, ...]) -> None:
    gravity = GravityModel(path, names)
    out = np.empty(len(names))
    for q in random_poses(gravity.model, names, count=50, seed=7):
        gravity.compute(q, out)
        np.testing.assert_allclose(out, bias_at_rest(gravity.model, names, q), rtol=1e-9, atol=1e-9)


def test_gravity_in_any_joint_order_and_subset() -> None:
    """Names out of model order (take/put path) and a subset (other joints stay at qpos0)."""
    names = ("wrist_1", "elbow", "shoulder_lift")
    gravity = GravityModel(ARM6, names)
    out = np.empty(3)
    for q in random_poses(gravity.model, names, count=20, seed=3):
        gravity.compute(q, out)
        np.testing.assert_allclose(out, bias_at_rest(gravity.model, names, q), rtol=1e-9, atol=1e-9)


def test_gravity_matches_hand_computed_torques() -> None:
    """Independent of MuJoCo's own bias: lever arms × weights of the links, from the model files' numbers."""
    arm = GravityModel(ARM6, ARM6_JOINTS)
    out = np.empty(6)
    arm.compute(np.zeros(6), out)  # stretched out along +x
    upper, fore, wrists = 8.393 * 0.2125, 2.275 * (0.425 + 0.196), (1.219 + 1.219 + 0.1879) * (0.425 + 0.392)
    assert out[1] == pytest.approx(G * (upper + fore + wrists), rel=1e-6)  # shoulder_lift holds everything
    assert out[2] == pytest.approx(G * (2.275 * 0.196 + (1.219 + 1.219 + 0.1879) * 0.392), rel=1e-6)
    assert out[0] == pytest.approx(0.0, abs=1e-9)  # the pan axis is vertical

    rrbot = GravityModel(RRBOT, RRBOT_JOINTS)
    out2 = np.empty(2)
    rrbot.compute(np.array([math.pi / 2, 0.0]), out2)  # both links horizontal along +x
    assert out2 == pytest.approx([-G * (0.45 + 1.35), -G * 0.45], rel=1e-6)
    rrbot.compute(np.zeros(2), out2)  # straight up: no gravity torque
    assert out2 == pytest.approx([0.0, 0.0], abs=1e-9)


def test_gravity_compute_has_no_memory_between_calls() -> None:
    gravity = GravityModel(ARM6, ARM6_JOINTS)
    q1, q2 = random_poses(gravity.model, ARM6_JOINTS, count=2, seed=11)
    first, again, other = np.empty(6), np.empty(6), np.empty(6)
    gravity.compute(q1, first)
    gravity.compute(q2, other)
    gravity.compute(q1, again)
    assert np.array_equal(first, again)
    assert not np.allclose(first, other)


def test_gravity_unknown_names_list_missing_and_model_joints() -> None:
    with pytest.raises(ValueError) as info:
        GravityModel(ARM6, ("shoulder_pan", "elbo", "wrist_9"))
    message = str(info.value)
    assert "elbo" in message
    assert "wrist_9" in message
    assert "shoulder_lift" in message  # the model's joints are listed
    assert "arm6.xml" in message
