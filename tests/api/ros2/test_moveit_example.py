"""docs/examples/moveit_arm6 (MoveIt 2 for the arm6 twin) cannot rot: every joint, group, limit, controller and action
name in it is read back and compared with configs/arm6.urdf and configs/arm6_twin_ros2.yaml, and a daemon started
as docs/ros2.md says serves the controller and action the example names to an independent rmw_zenoh client.

MoveIt itself is not run (it is not on PyPI): the files are checked as data, the launch file by its syntax tree."""

from __future__ import annotations

import ast
import asyncio
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml
import zenoh

from hild.config import load_config
from tests.api.conftest import WAIT
from tests.api.ros2.conftest import peer_config
from tests.conftest import CONFIGS, REPO
from tests.helpers import HildRun, free_endpoint

EXAMPLE = REPO / "docs" / "examples" / "moveit_arm6"
CONFIG = EXAMPLE / "config"
URDF = CONFIGS / "arm6.urdf"
ROBOT = CONFIGS / "arm6_twin_ros2.yaml"
ACTION_NS = "follow_joint_trajectory"  # ros2_control's JTC name, which the face keeps


def _yaml(name: str) -> Any:
    return yaml.safe_load((CONFIG / name).read_text())


def _srdf() -> ET.Element:
    return ET.parse(CONFIG / "arm6.srdf").getroot()


def _urdf() -> ET.Element:
    return ET.parse(URDF).getroot()


def _chain(base: str, tip: str) -> list[str]:
    """The movable joints from ``base`` to ``tip`` in the URDF, base first (what KDL builds its chain from)."""
    parent_joint = {j.find("child").get("link"): j for j in _urdf().iter("joint")}  # type: ignore[union-attr]
    joints, link = [], tip
    while link != base:
        joint = parent_joint[link]
        if joint.get("type") != "fixed":
            joints.append(joint.get("name"))
        link = joint.find("parent").get("link")  # type: ignore[union-attr]
    return joints[::-1]


def _controller() -> tuple[str, dict[str, Any]]:
    """The one controller moveit_controllers.yaml names, and its entry."""
    manager = _yaml("moveit_controllers.yaml")["moveit_simple_controller_manager"]
    (name,) = manager["controller_names"]
    return name, manager[name]


def test_the_planning_group_is_the_trajectory_controllers_joints() -> None:
    config = load_config(ROBOT).config
    name, entry = _controller()
    spec = config.controllers[name]
    assert spec.type == "joint_trajectory"
    joints = spec.params["joints"]
    (group,) = _srdf().iter("group")
    (chain,) = group.iter("chain")
    assert group.get("name") == "arm"
    assert _chain(chain.get("base_link", ""), chain.get("tip_link", "")) == joints == list(config.joints)
    assert entry["joints"] == joints


def test_home_is_the_twins_keyframe_and_free_of_checked_collisions() -> None:
    (state,) = _srdf().iter("group_state")
    assert (state.get("name"), state.get("group")) == ("home", "arm")
    home = {j.get("name"): float(j.get("value", "nan")) for j in state.iter("joint")}
    mjcf = mujoco.MjModel.from_xml_path(str(CONFIGS / "arm6.xml"))
    assert list(home) == list(load_config(ROBOT).config.joints)
    np.testing.assert_allclose(list(home.values()), mjcf.key("home").qpos, atol=1e-9)
    assert load_config(ROBOT).config.hardware["twin"].params["keyframe"] == "home"  # the twin starts there

    model = mujoco.MjModel.from_xml_path(str(URDF))
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_FILTERPARENT  # adjacent links count, as in MoveIt
    data = mujoco.MjData(model)
    data.qpos[:] = list(home.values())
    mujoco.mj_forward(model, data)
    skipped = {frozenset((d.get("link1"), d.get("link2"))) for d in _srdf().iter("disable_collisions")}
    links = {link.get("name") for link in _urdf().iter("link")}
    assert all(pair <= links for pair in skipped)
    touching = {
        frozenset((model.body(model.geom_bodyid[c.geom1]).name, model.body(model.geom_bodyid[c.geom2]).name))
        for c in data.contact[: data.ncon]
    }
    assert not touching - skipped, f"home collides: {touching - skipped}"


def test_kinematics_and_joint_limits_are_hilds() -> None:
    kinematics = _yaml("kinematics.yaml")
    assert set(kinematics) == {g.get("name") for g in _srdf().iter("group")}
    assert kinematics["arm"]["kinematics_solver"] == "kdl_kinematics_plugin/KDLKinematicsPlugin"
    config = load_config(ROBOT)
    params = config.controller_params[_controller()[0]]
    limits = _yaml("joint_limits.yaml")
    assert 0 < limits["default_velocity_scaling_factor"] <= 1 and 0 < limits["default_acceleration_scaling_factor"] <= 1
    assert set(limits["joint_limits"]) == set(config.config.joints)
    for joint, spec in config.config.joints.items():
        entry = limits["joint_limits"][joint]
        assert entry["has_velocity_limits"] and entry["has_acceleration_limits"], joint
        assert entry["max_velocity"] == pytest.approx(spec.limits.velocity * params.velocity_scale), joint
        assert entry["max_acceleration"] == pytest.approx(spec.limits.acceleration * params.acceleration_scale), joint


def test_the_controller_entry_is_what_moveit_needs() -> None:
    entry = _controller()[1]
    manager = _yaml("moveit_controllers.yaml")
    assert manager["moveit_controller_manager"] == "moveit_simple_controller_manager/MoveItSimpleControllerManager"
    assert (entry["type"], entry["action_ns"], entry["default"]) == ("FollowJointTrajectory", ACTION_NS, True)


def _launch_calls() -> dict[str, list[ast.Call]]:
    tree = ast.parse((EXAMPLE / "launch" / "arm6_moveit.launch.py").read_text())
    calls: dict[str, list[ast.Call]] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            calls.setdefault(name, []).append(node)
    return calls


def _strings(call: ast.Call) -> list[str]:
    return [n.value for n in ast.walk(call) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def test_the_launch_file_names_files_the_package_installs() -> None:
    package = ET.parse(EXAMPLE / "package.xml").getroot().findtext("name")
    calls = _launch_calls()
    (builder,) = calls["MoveItConfigsBuilder"]
    assert {k.arg: k.value.value for k in builder.keywords if isinstance(k.value, ast.Constant)} == {
        "package_name": package
    }
    named = [
        k.value.value
        for c in (call for calls_of in calls.values() for call in calls_of)
        for k in c.keywords
        if k.arg == "file_path" and isinstance(k.value, ast.Constant)
    ]
    assert len(named) == 5
    cmake = (EXAMPLE / "CMakeLists.txt").read_text()
    assert "install(DIRECTORY config launch" in cmake and '"${HILD_ROOT}/configs/arm6.urdf"' in cmake
    assert (EXAMPLE / "../../..").resolve() == REPO  # what HILD_ROOT resolves to
    for relative in named:
        assert (EXAMPLE / relative).is_file() or relative == "config/arm6.urdf", relative
    assert "config/moveit.rviz" in _strings(calls["Node"][2]) and (CONFIG / "moveit.rviz").is_file()
    assert any(k.arg == "pipelines" for k in calls["planning_pipelines"][0].keywords)
    wall = [n for n in calls["Node"] if "WALL_CLOCK" in ast.dump(n)]
    assert len(wall) == len(calls["Node"]) == 3  # every node on the wall clock: hild publishes no /clock


def test_rviz_plans_for_the_group_in_the_urdfs_root_frame() -> None:
    rviz = _yaml("moveit.rviz")["Visualization Manager"]
    (planning,) = [d for d in rviz["Displays"] if d["Class"] == "moveit_rviz_plugin/MotionPlanning"]
    assert planning["Planning Request"]["Planning Group"] == "arm"
    children = {j.find("child").get("link") for j in _urdf().iter("joint")}  # type: ignore[union-attr]
    (root,) = {link.get("name") for link in _urdf().iter("link")} - children
    assert rviz["Global Options"]["Fixed Frame"] == root


def test_the_daemon_serves_what_the_example_names(tmp_path: Path) -> None:
    """``hild run configs/arm6_twin_ros2.yaml`` (router mode, wall clock) with pyzeros as MoveIt's stand-in: the
    controller moveit_controllers.yaml names is listed as JTC, and a goal through its action namespace succeeds."""
    pyzeros = pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")
    import asyncio_for_robotics as afor

    from tests.api.ros2.test_against_pyzeros import _goal_session
    from tests.api.ros2.test_hild_run import _listing

    name, entry = _controller()
    home = [0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0]
    target = [h + d for h, d in zip(home, [0.1, -0.05, 0.05, 0.1, -0.1, 0.2], strict=True)]
    endpoint = free_endpoint()
    with HildRun(ROBOT, endpoint, "arm6", log=tmp_path / "daemon.log", cwd=tmp_path):
        session = zenoh.open(peer_config(endpoint))

        @afor.scoped
        async def main() -> dict[str, Any]:
            listing = await _listing()
            return {"listing": listing, **await _goal_session(target, name, tuple(entry["joints"]), entry["action_ns"])}

        try:
            with pyzeros.auto_context(node="moveit_stand_in", zenoh_session=session, domain_id=0):
                got = asyncio.run(asyncio.wait_for(main(), 4 * WAIT))
        finally:
            session.close()
    (state,) = [c for c in got["listing"].controller if c.name == name]
    assert state.type == "joint_trajectory_controller/JointTrajectoryController"
    # listed before the goal's switch: inactive, so it holds nothing yet but requires its joints' interfaces
    assert (state.state, list(state.claimed_interfaces)) == ("inactive", [])
    assert {f"{j}/position" for j in entry["joints"]} <= set(state.required_command_interfaces)
    assert list(state.required_state_interfaces) == [
        f"{j}/{f}" for j in entry["joints"] for f in ("position", "velocity")
    ]
    assert got["accepted"].accepted and (got["result"].status, got["result"].result.error_code) == (4, 0)
    assert list(got["state"].name) == entry["joints"]
    assert max(abs(p - t) for p, t in zip(got["state"].position, target, strict=True)) < 0.02
