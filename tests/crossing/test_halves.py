"""A controller split in two halves over the shared region: the API half (built by ``api_halves``, as the client
domain will) validates and plans, the cycle half (the engine's instance of the same controller, attached to the
region from the other side) adopts what crossed and drives the twin in lockstep. Everything the API half hands over
is pickled into shared memory and read back on the other side: these tests prove the controllers' code needs no
shared Python objects."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hild.action import GoalStatus
from hild.api.goals import GoalEndpoint
from hild.config import LoadedConfig, load_config
from hild.controller import Controller
from hild.crossing.mailboxes import Shared
from hild.crossing.region import Region
from hild.cycle.engine import Engine
from hild.daemon.halves import api_halves, configured_loads
from hild.motion.tables import SegmentTable
from tests.test_engine import events
from tests.test_twin_engine import CONFIGS

SIZE = 64 << 20


def lockstep() -> LoadedConfig:
    loaded = load_config(CONFIGS / "arm6_twin.yaml")
    cfg = loaded.config
    clock = cfg.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0})
    loaded.config = cfg.model_copy(update={"clock": clock})
    return loaded


class Split:
    def __init__(self) -> None:
        loaded = lockstep()
        self.region = Region(SIZE)
        self.api_events: list[tuple[str, str, str]] = []
        self.api = api_halves(
            loaded, configured_loads(loaded), Shared(self.region, create=True), lambda *e: self.api_events.append(e)
        )
        self.engine = Engine(loaded, Shared(Region.attach(self.region.fd, SIZE), create=False))
        self.engine.start()

    def half(self, name: str) -> Any:
        return self.api[name]

    def cycle_half(self, name: str) -> Controller:
        return self.engine.manager.records[name].instance

    def result(self, name: str, goal_id: str, seconds: float = 20.0) -> Any:
        for _ in range(int(seconds * self.engine.update_rate)):
            self.engine.run_cycles(1)
            for result in GoalEndpoint.of(self.half(name).action).collect():
                if result.goal_id == goal_id:
                    return result
        raise AssertionError(f"no result for {goal_id} in {seconds} s")


@pytest.fixture
def split() -> Split:
    return Split()


def test_the_halves_are_distinct_objects_that_share_only_cells(split: Split) -> None:
    for name in split.api:
        assert split.half(name) is not split.cycle_half(name)
    names = {cell for cell, _, _ in split.region.cells()}
    assert {"forward_position/active", "forward_position/commands", "joint_trajectory/goals", "servo/target"} <= names


def test_the_api_half_sees_activity_the_cycle_half_sets_and_refuses_inputs_while_inactive(split: Split) -> None:
    half = split.half("forward_position")
    with pytest.raises(ValueError, match="not active"):
        half.accept({"values": [0.0] * 6})
    assert split.engine.switch(["forward_position"], []).ok
    assert half.active
    target = split.engine.state.position.copy()
    target[0] += 0.05
    for _ in range(400):
        half.accept({"values": target.tolist()})
        split.engine.run_cycles(1)
    assert abs(split.engine.state.position[0] - target[0]) < 2e-3
    assert split.engine.switch([], ["forward_position"]).ok
    assert not half.active
    with pytest.raises(ValueError, match="not active"):
        half.accept({"values": target.tolist()})


def test_a_goal_planned_by_the_api_half_is_executed_by_the_cycle_half(split: Split) -> None:
    assert split.engine.switch(["joint_trajectory"], []).ok
    half = split.half("joint_trajectory")
    start = split.engine.state.position.copy()
    target = start + np.array([0.3, -0.2, 0.2, 0.0, 0.1, -0.1])
    move = GoalEndpoint.of(half.action).submit({"positions": target.tolist()})
    assert move["ok"], move
    split.engine.run_cycles(50)
    feedback = GoalEndpoint.of(half.action).feedback_messages()  # the cycle half wrote them into a shared ring
    assert feedback and {m["goal_id"] for m in feedback} == {move["goal_id"]}
    assert split.result("joint_trajectory", move["goal_id"]).status is GoalStatus.SUCCEEDED
    np.testing.assert_allclose(split.engine.state.position, target, atol=0.01)

    waypoints = [(start + k * np.array([0.05, 0.05, -0.05, 0.0, 0.0, 0.0])).tolist() for k in (1, 2, 3)]
    untimed = GoalEndpoint.of(half.action).submit(
        {"trajectory": {"joint_names": list(split.engine.joints), "points": [{"positions": w} for w in waypoints]}}
    )
    assert untimed["ok"], untimed
    result = split.result("joint_trajectory", untimed["goal_id"])
    assert result.status is GoalStatus.SUCCEEDED, result
    np.testing.assert_allclose(split.engine.state.position, waypoints[-1], atol=0.01)


def test_a_servo_target_crosses_and_is_reached(split: Split) -> None:
    assert split.engine.switch(["servo"], []).ok
    half = split.half("servo")
    target = split.engine.state.position.copy()
    target[2] -= 0.1
    for _ in range(100):
        half.accept({"positions": target.tolist()})
        split.engine.run_cycles(5)
    np.testing.assert_allclose(split.engine.state.position, target, atol=5e-3)


def test_a_clamped_servo_stream_drives_the_joints_as_it_does_in_one_process(split: Split) -> None:
    """Targets with velocities, clamped on the API side, cross as numeric records; the cycle half words the
    clamping event from them. Every command and event equals those of the same stream in one process."""
    alone = Engine(lockstep())
    alone.start()
    engines = (split.engine, alone)
    for engine in engines:
        assert engine.switch(["servo"], []).ok
        engine.events.drain()
    start = alone.state.position.copy()
    np.testing.assert_array_equal(split.engine.state.position, start)
    target = start + np.array([0.0, 0.0, 0.2, 0.0, 0.0, 0.0])
    target[1] = 5.0  # beyond shoulder_lift's soft limit
    velocities = [10.0, 0.0, 0.1, 0.0, 0.0, 0.0]  # shoulder_pan beyond its velocity limit
    inputs = (split.half("servo").accept, alone.manager.records["servo"].instance.accept)
    for k in range(600):  # 1.2 s of targets at 250 Hz, then silence until the servo stops
        if k < 300 and k % 2 == 0:
            for accept in inputs:
                accept({"positions": target.tolist(), "velocities": velocities})
        for engine in engines:
            engine.run_cycles(1)
        np.testing.assert_array_equal(split.engine.command.position, alone.command.position)
        np.testing.assert_array_equal(split.engine.command.velocity, alone.command.velocity)
    crossed, reference = (events(engine) for engine in engines)
    assert crossed == reference and split.api_events == []
    clamped = [e for e in crossed if "target clamped" in e]
    assert len(clamped) == 1, crossed
    assert clamped[0].startswith("warning:servo:target clamped: shoulder_pan velocity 10 → 3.14 (velocity limit)")
    assert "; shoulder_lift position 5 → 3.092 (soft limit)" in clamped[0]
    assert any("no target for 0.25 s" in e for e in crossed)
    assert not np.array_equal(alone.command.position, start)


def test_a_long_timed_goal_crosses_as_a_segment_table_and_is_executed(split: Split) -> None:
    assert split.engine.switch(["joint_trajectory"], []).ok
    half = split.half("joint_trajectory")
    start = split.engine.state.position.copy()
    times = np.linspace(0.2, 2.2, 2000)  # about 1 ms apart: more points than cycles (2 ms)
    offsets = 0.1 * np.sin(np.pi * (times - 0.2) / 4.0)[:, None] * np.array([1.0, -1.0, 1.0, 0.0, 0.5, -0.5])
    points = [
        {"positions": (start + d).tolist(), "time_from_start": float(t)} for d, t in zip(offsets, times, strict=True)
    ]
    goal = GoalEndpoint.of(half.action).submit(
        {"trajectory": {"joint_names": list(split.engine.joints), "points": points}}
    )
    assert goal["ok"], goal
    split.engine.run_cycles(2)
    track = split.cycle_half("joint_trajectory").goal_track
    assert track is not None
    (table,) = [s for s in track.trajectory.segments if isinstance(s, SegmentTable)]
    assert len(table) == len(times) - 1
    result = split.result("joint_trajectory", goal["goal_id"])
    assert result.status is GoalStatus.SUCCEEDED, result
    np.testing.assert_allclose(split.engine.state.position, start + offsets[-1], atol=0.01)
