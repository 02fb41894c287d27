"""Virtual walls on the arm6 twin in lockstep (docs/safety.md, "Virtual walls"): a position command that would take
the tool through a wall is held inside it without a step, the measured tool passes the wall by at most 5 mm at full
joint speed, motion along the wall goes on, leaving releases it, a hold never fights it, and bad walls are refused
by ``hild check``."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.config import load_config
from hild.config.loader import ConfigError
from hild.config.model import WallsSection
from hild.config.stop_review import check_with_model
from hild.cycle.engine import Engine
from hild.cycle.walls import WallGuard, Walls
from hild.dynamics.tool import ToolPoint
from tests.conftest import CONFIGS
from tests.controllers.test_joint_trajectory import submit
from tests.test_engine import JumpGuard, send

TARGET = 0.005  # m: the measured tool never passes a wall by more than this (issue 28's target)
SAFE_MARGIN = 0.005  # m: the smallest margin docs/safety.md calls safe at full speed with the default lead_time
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
FLOOR = {"min": [-2.0, -2.0, 0.0], "max": [2.0, 2.0, 2.0]}  # the tool starts at z = 0.143 m (keyframe home)


def walled(walls: dict[str, Any]) -> Engine:
    """arm6 on its twin, lockstep, with ``safety.walls`` set (enabled), started."""
    loaded = load_config(CONFIGS / "arm6_twin.yaml")
    cfg = loaded.config
    spec = WallsSection.model_validate({"enabled": True, **walls})
    loaded.config = cfg.model_copy(
        update={
            "clock": cfg.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0}),
            "safety": cfg.safety.model_copy(update={"walls": spec}),
        }
    )
    engine = Engine(loaded)
    engine.start()
    return engine


def guard(engine: Engine) -> WallGuard:
    assert engine.walls is not None
    return engine.walls


def wall_events(engine: Engine) -> list[str]:
    return [e.message for e in engine.events.drain() if e.source == "walls"]


class Watch(JumpGuard):
    """The jump guard, plus the deepest the measured and the commanded tool went beyond the walls."""

    def __init__(self, engine: Engine) -> None:
        super().__init__(engine)
        self.measured = self.commanded = -np.inf
        self.fastest = 0.0  # rad/s: the fastest any joint moved
        self.commanded_speed = 0.0  # rad/s: the fastest any joint's commanded position moved
        self.last = engine.final.position.copy()

    def check(self) -> None:
        super().check()
        step = np.abs(self.engine.final.position - self.last).max() / self.engine.period
        self.commanded_speed = max(self.commanded_speed, float(step))
        self.last[:] = self.engine.final.position
        walls = guard(self.engine)
        self.measured = max(self.measured, walls.measured_depth(self.engine.state.position))
        self.commanded = max(self.commanded, walls.measured_depth(self.engine.final.position))
        self.fastest = max(self.fastest, float(np.abs(self.engine.state.velocity).max()))


def stream(engine: Engine, target: np.ndarray, cycles: int, watch: Watch) -> None:
    for _ in range(cycles):
        send(engine, "forward_position", target.tolist())
        watch.run(1)


def test_a_streamed_command_through_a_floor_is_held_on_it_without_a_step_and_engages_once() -> None:
    engine = walled({"box": FLOOR, "margin": 0.01})
    assert engine.switch(["forward_position"], []).ok
    wall_events(engine)
    watch = Watch(engine)  # asserts every cycle: no command step beyond velocity · dt
    down = engine.state.position + np.array([0.0, -0.8, 0.0, 0.0, 0.0, 0.0])  # the tool 0.2 m below the floor
    assert guard(engine).measured_depth(down) > 0.15
    stream(engine, down, 1000, watch)
    assert watch.commanded_speed == pytest.approx(engine.limits.velocity[1])  # commanded at full speed
    assert watch.fastest > 1.0  # rad/s: and the arm really went
    assert watch.measured <= TARGET
    assert watch.commanded <= -0.01 + 1e-4  # the command stays the margin inside
    tool = guard(engine).tool.position(engine.state.position)
    assert tool[2] == pytest.approx(0.01, abs=2e-3)  # resting on the floor, the margin above it
    texts = wall_events(engine)
    assert texts == ["virtual wall box z_min engaged: the tool's command (site tool) is held inside it"]
    status = engine.status()
    assert status["walls"] == {"tool": "site tool", "engaged": ["box z_min"], "self_collision": []}


def test_motion_along_the_wall_goes_on_and_leaving_it_releases_it() -> None:
    engine = walled({"box": FLOOR, "margin": 0.01})
    assert engine.switch(["forward_position"], []).ok
    home = engine.state.position.copy()
    watch = Watch(engine)
    stream(engine, home + np.array([0.0, -0.8, 0.0, 0.0, 0.0, 0.0]), 600, watch)
    wall_events(engine)
    start = guard(engine).tool.position(engine.state.position).copy()
    # Along the floor: turn the base while still pushing down. The tool sweeps round, z stays on the wall.
    stream(engine, home + np.array([1.2, -0.8, 0.0, 0.0, 0.0, 0.0]), 800, watch)
    end = guard(engine).tool.position(engine.state.position).copy()
    assert np.linalg.norm(end[:2] - start[:2]) > 0.3
    assert end[2] == pytest.approx(0.01, abs=2e-3)
    assert watch.measured <= TARGET
    assert wall_events(engine) == []  # still the same engagement: no event per cycle
    # Back up, away from the floor: released once, and the arm reaches the target.
    stream(engine, home + np.array([1.2, 0.0, 0.0, 0.0, 0.0, 0.0]), 1000, watch)
    assert wall_events(engine) == ["virtual wall box z_min released"]
    assert engine.status()["walls"]["engaged"] == []
    np.testing.assert_allclose(engine.state.position, home + np.array([1.2, 0, 0, 0, 0, 0]), atol=5e-3)


def test_a_trajectory_at_full_speed_with_the_smallest_safe_margin_passes_the_wall_by_at_most_5_mm() -> None:
    engine = walled({"box": {"min": [-2.0, -2.0, -0.15], "max": [2.0, 2.0, 2.0]}, "margin": SAFE_MARGIN})
    assert engine.switch(["joint_trajectory"], []).ok
    target = engine.state.position + np.array([2.5, -2.0, 0.8, 0.5, 0.0, 0.0])  # a full-speed move_to
    assert guard(engine).measured_depth(target) > 0.3
    # Path tolerance off: the wall holds the arm back from its path, which would otherwise abort the goal and stop it
    # where it is, short of the wall (joint_trajectory stops from the measured state after a path-tolerance abort);
    # here the goal keeps pressing its command into the wall for as long as it runs.
    unchecked = [{"name": joint, "position": -1} for joint in JOINTS]
    submit(engine, {"positions": target.tolist(), "path_tolerance": unchecked})
    watch = Watch(engine)
    normal_speed_on_wall = []
    walls = guard(engine)
    jac = np.zeros((3, 6))
    for _ in range(1500):
        watch.run(1)
        if walls.measured_depth(engine.final.position) > -SAFE_MARGIN - 1e-4:  # the command is on the wall
            walls.tool.jacobian(jac)
            normal_speed_on_wall.append(float(-(jac @ engine.final.velocity)[2]))  # toward z_min: -z
    assert watch.fastest >= engine.limits.velocity.max()  # the joints' full speed
    assert watch.measured <= TARGET
    assert normal_speed_on_wall and max(normal_speed_on_wall) <= 1e-6  # no feed-forward into the wall
    assert wall_events(engine)[:1] == [
        "virtual wall box z_min engaged: the tool's command (site tool) is held inside it"
    ]


def random_approaches(count: int, seed: int) -> list[tuple[np.ndarray, list[float], list[float]]]:
    """Seeded full-speed moves from home and a plane across each, halfway, facing the way the tool goes."""
    tool = ToolPoint(CONFIGS / "arm6.xml", JOINTS)
    home = np.array([0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0])  # arm6's keyframe home, where the twin starts
    rng = np.random.default_rng(seed)
    found = []
    while len(found) < count:
        delta = rng.uniform(-1.0, 1.0, 6) * np.array([2.5, 1.5, 1.5, 1.5, 1.5, 1.5])
        start, middle = tool.position(home).copy(), tool.position(home + 0.5 * delta).copy()
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        if normal @ (middle - start) < 0.0:
            normal = -normal
        if normal @ (middle - start) >= 0.05:  # the wall is at least 5 cm ahead
            found.append((delta, middle.tolist(), normal.tolist()))
    return found


@pytest.mark.parametrize(("delta", "point", "normal"), random_approaches(4, seed=7))
def test_random_full_speed_approaches_pass_a_plane_by_at_most_5_mm(
    delta: np.ndarray, point: list[float], normal: list[float]
) -> None:
    engine = walled({"planes": [{"point": point, "normal": normal}], "margin": SAFE_MARGIN})
    assert engine.switch(["joint_trajectory"], []).ok
    submit(engine, {"positions": (engine.state.position + delta).tolist()})
    watch = Watch(engine)
    watch.run(1500)
    assert guard(engine).corrections > 0  # the wall really was in the way
    assert watch.measured <= TARGET


def test_a_hold_never_fights_a_wall_and_a_command_beyond_one_may_only_come_back() -> None:
    # The arm starts 0.143 m above z = 0: a floor at 0.2 m leaves the tool beyond it from the start.
    engine = walled({"box": {"min": [-2.0, -2.0, 0.2], "max": [2.0, 2.0, 2.0]}, "margin": 0.0})
    start = engine.state.position.copy()
    walls = guard(engine)
    depth = walls.measured_depth(start)
    assert depth > 0.05
    watch = Watch(engine)
    watch.run(500)  # held where it is, beyond the wall: the hold is not moved
    np.testing.assert_allclose(engine.final.position, start, atol=1e-9)
    assert wall_events(engine) == []
    assert engine.switch(["forward_position"], []).ok
    stream(engine, start + np.array([0.0, -0.3, 0.0, 0.0, 0.0, 0.0]), 500, watch)  # deeper: refused
    assert watch.commanded <= depth + 1e-4
    assert depth - 0.01 < walls.measured_depth(engine.final.position) <= depth + 1e-4  # stopped: not deeper
    stream(engine, start + np.array([0.0, 0.4, 0.0, 0.0, 0.0, 0.0]), 1000, watch)  # back inside: allowed
    assert walls.measured_depth(engine.state.position) < -0.02


def test_walls_off_leave_the_command_alone() -> None:
    loaded = load_config(CONFIGS / "arm6_twin.yaml")
    assert not loaded.config.safety.walls.enabled
    cfg = loaded.config
    loaded.config = cfg.model_copy(update={"clock": cfg.clock.model_copy(update={"source": "sim"})})
    engine = Engine(loaded)
    assert engine.walls is None
    assert engine.status()["walls"] is None


def test_the_box_gives_six_walls_and_planes_are_normalised() -> None:
    spec = WallsSection.model_validate(
        {
            "box": FLOOR,
            "planes": [
                {"name": "table edge", "point": [0.5, 0, 0], "normal": [2, 0, 0]},
                {"point": [0, 0, 1], "normal": [0, 0, 3]},
            ],
        }
    )
    walls = Walls.of(spec)
    assert walls.names == (
        "box x_min", "box x_max", "box y_min", "box y_max", "box z_min", "box z_max", "table edge", "plane[1]"
    )  # fmt: skip
    np.testing.assert_allclose(np.linalg.norm(walls.normals, axis=1), 1.0)
    assert walls.depth(np.array([0.6, 0.0, 0.5])) == pytest.approx(0.1)  # beyond the table edge by 0.1
    assert walls.depth(np.array([0.0, 0.0, 0.5])) == pytest.approx(-0.5)
    assert walls.deepest(np.array([0.6, 0.0, 0.5])) == "table edge"


def test_the_tool_point_and_its_jacobian_agree_with_finite_differences() -> None:
    tool = ToolPoint(CONFIGS / "arm6.xml", JOINTS, offset=(0.0, 0.05, 0.0))
    assert tool.frame == "site tool"
    q = np.array([0.3, 1.0, -1.6, -0.9, 1.5, 0.4])
    point = tool.position(q).copy()
    jac = np.zeros((3, 6))
    tool.jacobian(jac)
    for i in range(6):
        dq = q.copy()
        dq[i] += 1e-6
        np.testing.assert_allclose((tool.position(dq) - point) / 1e-6, jac[:, i], atol=1e-5)
    by_body = ToolPoint(CONFIGS / "arm6.xml", JOINTS, body="wrist_3_link", offset=(0.0, 0.0823 + 0.05, 0.0))
    np.testing.assert_allclose(by_body.position(q), point, atol=1e-12)  # the site sits 0.0823 m along y
    assert ToolPoint(CONFIGS / "arm6.xml", JOINTS[:3]).frame == "site tool"


def test_the_tool_reach_bounds_every_jacobian_column() -> None:
    # The guard skips the measured-speed lead when even this bound cannot bring a wall near: it must hold.
    tool = ToolPoint(CONFIGS / "arm6.xml", JOINTS, offset=(0.0, 0.1, 0.05))
    jac = np.zeros((3, 6))
    for q in np.random.default_rng(3).uniform(-3.0, 3.0, (500, 6)):
        tool.position(q)
        tool.jacobian(jac)
        assert (np.linalg.norm(jac, axis=0) <= tool.reach + 1e-12).all()
    assert tool.reach[0] > tool.reach[5] > 0.0


@pytest.mark.parametrize(
    ("walls", "message"),
    [
        ("{enabled: true, site: flange9, box: {min: [-1, -1, 0], max: [1, 1, 1]}}", "no site 'flange9' for the tool"),
        ("{enabled: true, body: hand, box: {min: [-1, -1, 0], max: [1, 1, 1]}}", "no body 'hand' for the tool"),
        ("{enabled: true, box: {min: [-1, 1, 0], max: [1, 1, 1]}}", "the box is empty along y"),
        ("{enabled: true, planes: [{point: [0, 0, 0], normal: [0, 0, 0]}]}", "the normal must not be zero"),
        ("{enabled: true}", "walls are enabled but none is given"),
        ("{enabled: true, site: tool, body: wrist_3_link, planes: [{point: [0, 0, 0], normal: [0, 0, 1]}]}",
         "as a site or a body, not both"),
    ],
)  # fmt: skip
def test_hild_check_refuses_bad_walls(tmp_path: Path, walls: str, message: str) -> None:
    shutil.copy(CONFIGS / "arm6.xml", tmp_path / "arm6.xml")
    text = (CONFIGS / "arm6_twin.yaml").read_text()
    assert "  estop_action: hold\n" in text
    path = tmp_path / "walls.yaml"
    path.write_text(text.replace("  estop_action: hold\n", f"  estop_action: hold\n  walls: {walls}\n"))
    with pytest.raises(ConfigError) as caught:
        check_with_model(load_config(path))
    assert message in str(caught.value) and "safety.walls" in str(caught.value)


def test_hild_check_names_the_tool_frame_of_good_walls(tmp_path: Path) -> None:
    shutil.copy(CONFIGS / "arm6.xml", tmp_path / "arm6.xml")
    text = (CONFIGS / "arm6_twin.yaml").read_text()
    path = tmp_path / "walls.yaml"
    walls = "{enabled: true, box: {min: [-1, -1, 0], max: [1, 1, 1]}, margin: 0.005}"
    path.write_text(text.replace("  estop_action: hold\n", f"  estop_action: hold\n  walls: {walls}\n"))
    loaded = load_config(path)
    check_with_model(loaded)
    assert any("virtual walls: 6 on the tool at site tool" in note for note in loaded.notes)


FOLD3 = """<mujoco model="fold3">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.001" gravity="0 0 -9.81"/>
  <default>
    <joint type="hinge" axis="0 0 1" damping="0.05" armature="0.01" actuatorfrclimited="true"
           actuatorfrcrange="-20 20"/>
    <geom type="capsule" size="0.02"/>
  </default>
  <worldbody>
    <geom name="floor" type="plane" pos="0 0 -0.1" size="1 1 0.05"/>
    <body name="link1">
      <joint name="j1" range="-3 3"/>
      <geom fromto="0 0 0 0.3 0 0" mass="1"/>
      <body name="link2" pos="0.3 0 0">
        <joint name="j2" range="-3 3"/>
        <geom fromto="0 0 0 0.3 0 0" mass="0.5"/>
        <body name="link3" pos="0.3 0 0">
          <joint name="j3" range="-3 3"/>
          <geom fromto="0 0 0 0.3 0 0" mass="0.3"/>
          <site name="tool" pos="0.3 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

FOLD3_CONFIG = """robot: {name: fold3, model: fold3.xml}
update_rate: 500
clock: {source: sim, real_time_factor: 0}
hardware:
  twin: {driver: mujoco, params: {model: fold3.xml, substeps: 2}, joints: {j1: {}, j2: {}, j3: {}}}
joints:
  j1: {limits: {position: {lower: -3, upper: 3}, velocity: 3, effort: 20}, hold: {kp: 50, kd: 2}}
  j2: {limits: {position: {lower: -3, upper: 3}, velocity: 3, effort: 20}, hold: {kp: 50, kd: 2}}
  j3: {limits: {position: {lower: -3, upper: 3}, velocity: 3, effort: 20}, hold: {kp: 50, kd: 2}}
controllers:
  forward_position:
    type: forward_command
    params: {joints: [j1, j2, j3], interface: position, command_timeout: 5.0}
safety:
  walls: {enabled: true, self_collision: true}
"""


def test_self_collision_refuses_a_folding_command_holds_the_last_safe_one_and_lets_it_out(tmp_path: Path) -> None:
    (tmp_path / "fold3.xml").write_text(FOLD3)
    (tmp_path / "fold3.yaml").write_text(FOLD3_CONFIG)
    loaded = load_config(tmp_path / "fold3.yaml")
    check_with_model(loaded)
    assert any("self-collision checked" in note for note in loaded.notes)
    engine = Engine(loaded)
    engine.start()
    walls = guard(engine)
    assert walls.collision is not None
    assert walls.collision.touching(np.array([0.0, 2.6, 2.0])) == ("link1", "link3")  # the fold below
    assert walls.collision.touching(np.array([0.0, 2.6, 0.0])) is None
    assert engine.switch(["forward_position"], []).ok
    watch = JumpGuard(engine)

    def go(target: list[float], cycles: int) -> None:
        for _ in range(cycles):
            send(engine, "forward_position", target)
            watch.run(1)
            assert walls.collision is not None and walls.collision.touching(engine.final.position) is None

    go([0.0, 2.6, 0.0], 1000)  # folded, link3 pointing away: no contact
    wall_events(engine)
    go([0.0, 2.6, 2.0], 1000)  # swinging link3 into link1: stopped short of the touch, every cycle
    assert walls.refusals > 0
    stopped = engine.final.position.copy()
    assert 0.5 < stopped[2] < 2.0
    assert wall_events(engine) == [
        "self-collision: link1 and link3 would touch at the commanded pose; the command is refused and the joints "
        "hold the last safe command"
    ]
    assert engine.status()["walls"]["self_collision"] == ["link1", "link3"]
    go([0.0, 2.6, 0.0], 1000)  # back out: accepted, released once
    np.testing.assert_allclose(engine.state.position, [0.0, 2.6, 0.0], atol=5e-3)
    assert wall_events(engine) == ["self-collision: commands are accepted again"]
    assert engine.status()["walls"]["self_collision"] == []
