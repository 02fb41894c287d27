"""The shipped twin configs, run by the engine in lockstep: hold under gravity, switches, limits, e-stop."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hild.config import load_config
from hild.config.model import PlausibilitySection
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from tests.conftest import CONFIGS
from tests.test_engine import JumpGuard, events, modes, send


def twin(name: str, safety: dict[str, Any] | None = None) -> Engine:
    """A shipped config on the sim clock (lockstep), started."""
    loaded = load_config(CONFIGS / name)
    cfg = loaded.config
    update: dict[str, Any] = {"clock": cfg.clock.model_copy(update={"source": "sim", "real_time_factor": 0.0})}
    if safety:
        update["safety"] = cfg.safety.model_copy(update=safety)
    loaded.config = cfg.model_copy(update=update)
    engine = Engine(loaded)
    engine.start()
    return engine


def stream(engine: Engine, controller: str, target: np.ndarray, cycles: int, guard: JumpGuard) -> None:
    for _ in range(cycles):
        send(engine, controller, target.tolist())
        guard.run(1)


def test_arm6_holds_within_a_milliradian_for_ten_seconds_under_gravity() -> None:
    engine = twin("arm6_twin.yaml")
    start = engine.state.position.copy()
    guard = JumpGuard(engine)
    worst = 0.0
    for _ in range(500):  # 10 s at 500 Hz, checked every 10 cycles
        guard.run(10)
        worst = max(worst, float(np.abs(engine.state.position - start).max()))
    assert worst < 1e-3
    shoulder_lift = engine.joints.index("shoulder_lift")
    assert abs(engine.state.effort[shoulder_lift]) > 10.0  # gravity is really there and really countered
    assert modes(engine) == ["hold"] * 6


def test_without_gravity_feed_forward_the_hold_gains_alone_sag() -> None:
    engine = twin("arm6_twin.yaml", {"gravity_compensation": False})
    start = engine.state.position.copy()
    engine.run_cycles(2500)
    assert np.abs(engine.state.position - start).max() > 0.01


def test_released_mid_motion_the_arm_holds_at_its_latched_position() -> None:
    engine = twin("arm6_twin.yaml")
    assert engine.switch(["forward_position"], []).ok
    guard = JumpGuard(engine)
    target = engine.state.position + np.array([0.6, -0.3, 0.4, 0.3, 0.3, 0.3])
    stream(engine, "forward_position", target, 150, guard)
    assert np.abs(engine.state.velocity).max() > 1.0  # really moving
    assert engine.switch([], ["forward_position"]).ok
    guard.run(1)
    latched = engine.supervisor.latched.copy()
    guard.run(500)  # settle for 1 s
    for _ in range(450):  # then 9 s within a milliradian of the latched position
        guard.run(10)
        assert np.abs(engine.state.position - latched).max() < 1e-3
    assert modes(engine) == ["hold"] * 6


def test_switch_between_controllers_mid_motion_produces_no_command_step() -> None:
    engine = twin("arm6_twin.yaml")
    joints = list(engine.joints)
    engine.load_controller("forward_b", "forward_command", {"joints": joints, "command_timeout": 0.5})
    engine.switch(["forward_position"], [])
    guard = JumpGuard(engine)
    start = engine.state.position.copy()
    stream(engine, "forward_position", start + 0.5, 100, guard)
    result = engine.switch(["forward_b"], ["forward_position"])
    assert result.ok and result.activated == ["forward_b"]
    guard.run(50)  # forward_b has no command yet: held, no step
    stream(engine, "forward_b", start - 0.2, 1000, guard)
    np.testing.assert_allclose(engine.state.position, start - 0.2, atol=5e-3)


def test_position_beyond_the_hard_limit_trips_a_latched_fault() -> None:
    # No margin: the joint may not rest beyond its hard limit at all (the default margin tolerates an end stop).
    no_margin = PlausibilitySection(margin=0.0)
    engine = twin("rrbot_twin.yaml", {"gravity_compensation": False, "plausibility": no_margin})
    # The twin starts at 0; push joint1 with a constant torque until it leaves its range.
    engine.load_controller("push", "forward_command", {"joints": ["joint1"], "interface": "effort"})
    engine.switch(["push"], [])
    guard = JumpGuard(engine)
    for _ in range(3000):
        send(engine, "push", [30.0])
        guard.run(1)
        if engine.status()["joints"][0]["mode"] == "fault":  # joint2 may fault too: the impact whips it
            break
    joint1 = engine.status()["joints"][0]
    assert joint1["mode"] == "fault" and "outside the hard limits" in joint1["fault"]
    assert engine.supervisor.fault[0] == Fault.POSITION_LIMIT
    assert any("joint joint1 fault" in e for e in events(engine))
    # Held at the last accepted reading, inside the limit: never latched beyond it.
    assert engine.supervisor.latched[0] <= engine.limits.upper[0]


def test_soft_limit_clamps_a_command_beyond_it_and_reports() -> None:
    engine = twin("arm6_twin.yaml")
    engine.switch(["forward_position"], [])
    events(engine)
    guard = JumpGuard(engine)
    target = engine.state.position.copy()
    target[0] = 6.26  # shoulder_pan: beyond the soft limit (6.2332), inside the hard limit (6.2832)
    stream(engine, "forward_position", target, 1500, guard)
    assert engine.final.position[0] == pytest.approx(6.2832 - 0.05)
    assert engine.state.position[0] == pytest.approx(6.2332, abs=1e-3)
    pan = engine.status()["joints"][0]
    assert pan["fault"] is None and pan["limits"] == ["position"]
    assert any("joint shoulder_pan: position limit engaged" in e for e in events(engine))


def test_estop_mid_motion_holds_and_reset_restores_control() -> None:
    engine = twin("rrbot_twin.yaml")
    engine.switch(["forward_position"], [])
    guard = JumpGuard(engine)
    stream(engine, "forward_position", np.array([1.0, -1.0]), 100, guard)
    engine.submit(engine.estop)
    guard.run(1)  # effective on the next cycle
    assert engine.status()["mode"] == "estop"
    guard.run(1000)
    stopped = engine.state.position.copy()
    guard.run(500)
    np.testing.assert_allclose(engine.state.position, stopped, atol=1e-3)
    future = engine.submit(engine.reset)
    guard.run(1)
    assert future.result(timeout=0)["cleared"] == ["e-stop"]
    assert engine.switch(["forward_position"], []).ok
    stream(engine, "forward_position", np.array([0.5, 0.5]), 1000, guard)
    np.testing.assert_allclose(engine.state.position, [0.5, 0.5], atol=5e-3)
