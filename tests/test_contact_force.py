"""The Cartesian contact check (safety.contact.force) on the lockstep twin: the force at the tool that the joints'
external torques imply, its thresholds' validation, and a push that only the tool's threshold catches."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml

from drivers.mujoco.twin import MujocoTwin
from hild.config import load_config
from hild.config.loader import ConfigError
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from tests.helpers import component
from tests.test_contact import config

JOINT_LEVELS: dict[str, Any] = {"contact": 30.0, "collision": 40.0}  # joints alone never trip on 20 N at the tool
POSES = {  # elbow up, tool down (home); forearm reaching out; wrist turned
    "home": {},
    "reach": {"shoulder_lift": 0.5, "elbow": -0.9, "wrist_1": -1.2},
    "turned": {"shoulder_pan": 0.8, "wrist_2": 0.6, "wrist_3": 0.4},
}


def engine_at(tmp_path: Path, pose: dict[str, float], scale: float, **contact: Any) -> Engine:
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = config(tmp_path, {"enabled": True, **JOINT_LEVELS, **contact}, scale)
    raw = yaml.safe_load(path.read_text())
    raw["hardware"]["twin"]["params"]["initial_positions"] = pose
    path.write_text(yaml.safe_dump(raw))
    engine = Engine(load_config(path))
    engine.start()
    return engine


def push_at_tool(engine: Engine, force: np.ndarray) -> None:
    """``force`` (N, world) acting at the tool site: xfrc_applied acts at the body's centre of mass, so with the
    moment that moves it to the site."""
    twin = component(engine, MujocoTwin)
    m, d = twin.model, twin.data
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tool")
    body = int(m.site_bodyid[site])
    d.xfrc_applied[body, :3] = force
    d.xfrc_applied[body, 3:] = np.cross(d.site_xpos[site] - d.xipos[body], force)


@pytest.mark.parametrize("pose", list(POSES))
def test_a_20_newton_push_at_the_tool_reads_20_newtons_in_its_direction(tmp_path: Path, pose: str) -> None:
    """An exact model: the estimate is the push, in size and direction, once the observer has settled."""
    engine = engine_at(tmp_path, POSES[pose], 1.0, force={"contact": 900.0, "collision": 1000.0})
    engine.run_cycles(300)
    tool = engine.contact.tool_force  # type: ignore[union-attr]
    before = tool.force.copy()
    assert np.linalg.norm(before) < 2.0  # nothing pushes: (almost) nothing read
    push = np.array([12.0, -10.0, 12.6]) if pose != "turned" else np.array([-15.0, 5.0, -12.2])
    push *= 20.0 / np.linalg.norm(push)
    push_at_tool(engine, push)
    engine.run_cycles(100)  # 0.2 s at 500 Hz: both low-passes settled
    read = tool.force - before
    assert np.linalg.norm(read) == pytest.approx(20.0, rel=0.12)
    assert float(read @ push) / (np.linalg.norm(read) * 20.0) > 0.97  # within 14° of the push


def test_a_push_the_joints_miss_trips_the_tool_threshold(tmp_path: Path) -> None:
    """With the heavier plant: 20 N stays below every joint's 40 N·m, the tool's 10 N collision level catches it."""
    force = {"contact": 6.0, "collision": 10.0}
    joints_only = engine_at(tmp_path / "a", POSES["reach"], 1.1)
    at_tool = engine_at(tmp_path / "b", POSES["reach"], 1.1, force=force)
    push = np.array([0.0, 12.0, 16.0])
    for engine in (joints_only, at_tool):
        engine.run_cycles(300)
        assert not engine.supervisor.fault.any()
        push_at_tool(engine, push)
        engine.run_cycles(25)  # 50 ms at 500 Hz
    assert not joints_only.supervisor.fault.any()
    assert (at_tool.supervisor.fault == int(Fault.COLLISION)).all()
    assert "collision at the tool: external force" in at_tool.supervisor.fault_text[0]


def test_a_released_push_does_not_trip_again_after_reset(tmp_path: Path) -> None:
    engine = engine_at(tmp_path, POSES["home"], 1.1, force={"contact": 6.0, "collision": 10.0})
    engine.run_cycles(300)
    push_at_tool(engine, np.array([20.0, 0.0, 0.0]))
    engine.run_cycles(25)
    assert engine.supervisor.fault.any()
    push_at_tool(engine, np.zeros(3))
    engine.run_cycles(100)
    engine.reset()
    engine.run_cycles(300)
    assert not engine.supervisor.fault.any()


@pytest.mark.parametrize(
    ("force", "words"),
    [
        ({"contact": 12.0, "collision": 10.0}, "above the collision threshold"),
        ({"contact": 5.0}, "collision"),
        ({"contact": 0.0, "collision": 10.0}, "greater than 0"),
        ({"contact": 5.0, "collision": 10.0, "bandwidth": 600.0}, "bandwidth"),
    ],
)
def test_bad_force_thresholds_are_refused(tmp_path: Path, force: dict[str, Any], words: str) -> None:
    with pytest.raises((ConfigError, ValueError), match=words):
        Engine(load_config(config(tmp_path, {"enabled": True, "force": force})))


def test_the_jacobian_read_off_the_observer_is_the_tool_points_own() -> None:
    """The force check reads the tool's Jacobian off the observer's last reading instead of evaluating the model
    again: at the same q it must be the Jacobian ToolPoint computes itself."""
    from hild.dynamics.momentum import MomentumObserver
    from hild.dynamics.tool import ReadingJacobian, ToolPoint
    from tests.conftest import CONFIGS

    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    observer = MomentumObserver(CONFIGS / "arm6.xml", joints, 150.0, 0.001)
    rng = np.random.default_rng(4)
    for offset in ((0.0, 0.0, 0.0), (0.02, -0.01, 0.05)):
        tool = ToolPoint(CONFIGS / "arm6.xml", joints, offset=offset)
        read = ReadingJacobian(tool, observer)
        own = np.zeros((3, 6))
        observer.reset(rng.uniform(-2.0, 2.0, 6), np.zeros(6))
        for _ in range(5):
            q, qd = rng.uniform(-2.0, 2.0, 6), rng.normal(0.0, 1.0, 6)
            observer.update(q, qd, np.zeros(6), 0.001)
            tool.position(q)
            assert np.allclose(read.jacobian(q), tool.jacobian(own), rtol=0.0, atol=1e-12)
