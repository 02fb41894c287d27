"""``home``: a drive's own homing on an operator's command, on the mock driver's homing simulation, in lockstep.

The mock homes joint b from -0.2 to its switch at 0.4 over 0.5 s (250 cycles at 500 Hz), where it then reads 0.05.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest

from drivers.mock import MockHardware
from hild.crossing.requests import Home, Refused
from hild.cycle.engine import Engine
from hild.hardware import Homing
from tests.helpers import component
from tests.test_engine import MakeEngine, events, send

HOMING = {"duration": 0.5, "switch": {"b": 0.4}, "home_offset": 0.05}
CYCLES = 250  # the homing's duration in cycles


def homing_engine(make_engine: MakeEngine, patch: dict[str, Any] | None = None) -> Engine:
    engine = make_engine({"hardware": {"bus": {"params": {"homing": HOMING}}}, **(patch or {})})
    engine.run_cycles(5)
    return engine


def mock(engine: Engine) -> MockHardware:
    return component(engine, MockHardware)


def entry(engine: Engine, joint: str = "b") -> dict[str, Any]:
    return next(h for h in engine.status()["homing"] if h["joint"] == joint)


def test_homing_follows_the_drive_and_latches_the_new_position(make_engine: MakeEngine) -> None:
    engine = homing_engine(make_engine)
    assert engine.status()["homing"] == []
    assert engine.home("b") == {"joint": "b", "attempt": 1, "state": "running"}
    assert mock(engine).homing_started == ["b"]
    assert entry(engine) == {"joint": "b", "state": "running", "attempt": 1, "detail": None, "position": None}
    readings = []
    for _ in range(CYCLES - 1):
        engine.run_cycles(1)
        b = 1
        # no pull back: hold commands where the drive has taken the joint, with no spring
        assert engine.final.position[b] == engine.state.position[b] and engine.final.kp[b] == 0.0
        readings.append(float(engine.state.position[b]))
        assert entry(engine)["state"] == "running"
    assert readings[0] == -0.2 and readings[-1] > 0.39  # the drive moved it up to its switch by itself,
    assert (np.diff(readings) > 0.0).all()  # steadily, never pulled back
    np.testing.assert_allclose(engine.state.position[[0, 2]], [0.1, 0.3])  # the other joints held
    engine.run_cycles(2)
    done = entry(engine)
    assert done["state"] == "attained" and done["detail"] is None and done["position"] == pytest.approx(0.05)
    assert any("homing b: attained" in e and "0.05 rad" in e for e in events(engine))
    engine.run_cycles(500)  # past the settle window: hold latched where it stopped, in the drive's new frame
    assert engine.supervisor.latched[1] == pytest.approx(0.05)
    assert engine.final.position[1] == pytest.approx(0.05) and engine.final.kp[1] == 100.0
    assert [j["mode"] for j in engine.status()["joints"]] == ["hold"] * 3
    assert engine.switch(["fwd"], []).ok  # controllers may claim it again


@pytest.mark.parametrize(
    ("joint", "prepare", "reason"),
    [
        ("nope", None, "unknown joint 'nope'"),
        ("b", "claim", "is commanded by controller fwd"),
        ("b", "move", "moves at 0.5 rad/s: homing needs it still"),
        ("b", "fault", "is in fault (bus: drive fault code 0x7)"),
        ("b", "estop", "while the e-stop is engaged"),
    ],
)
def test_home_is_refused_unless_the_joint_is_held_and_still(
    make_engine: MakeEngine, joint: str, prepare: str | None, reason: str
) -> None:
    engine = homing_engine(make_engine)
    if prepare == "claim":  # claimed, not yet written: the supervisor still holds it, but fwd commands it
        assert engine.switch(["fwd"], []).ok
    if prepare == "move":
        engine.state.velocity[1] = 0.5  # as read this cycle
    if prepare == "fault":
        mock(engine).fault_codes[1] = 7
        engine.run_cycles(1)
    if prepare == "estop":
        engine.estop()
    with pytest.raises(Refused, match=re.escape(reason)):
        engine.apply(Home(joint))
    assert mock(engine).homing_started == []
    assert engine.status()["homing"] == []


def test_while_homing_no_controller_may_claim_the_joint_and_set_zero_and_home_are_refused(
    make_engine: MakeEngine,
) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(10)
    result = engine.switch(["fwd"], [])
    assert not result.ok and "b is being homed (hild ctl home)" in result.error
    assert "fwd" not in [c["name"] for c in engine.status()["controllers"] if c["state"] == "active"]
    best_effort = engine.switch(["fwd"], [], strict=False)
    assert best_effort.activated == [] and "fwd" in best_effort.error
    assert "already being homed (attempt 1)" in engine.home("b")["error"]
    assert "is being homed" in engine.set_zero("b")["error"]
    assert mock(engine).homing_started == ["b"]
    engine.run_cycles(CYCLES)
    assert entry(engine)["state"] == "attained"


def test_an_estop_stops_the_homing_and_it_ends_failed_where_it_stopped(make_engine: MakeEngine) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(40)
    engine.request_estop()
    engine.run_cycles(1)
    assert mock(engine).homing_stopped == ["b"]
    done = entry(engine)
    assert done["state"] == "failed" and done["detail"] == "e-stop: stopped"
    stopped_at = done["position"]
    assert -0.2 < stopped_at < 0.4  # halfway: the drive halted where it was
    assert any("homing b failed: e-stop: stopped" in e for e in events(engine))
    engine.run_cycles(500)
    assert engine.supervisor.latched[1] == pytest.approx(stopped_at)  # held where it stopped, never pulled back
    assert float(engine.state.position[1]) == pytest.approx(stopped_at)


def test_a_fault_of_the_joint_stops_the_homing(make_engine: MakeEngine) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(10)
    mock(engine).fault_codes[1] = 9
    engine.run_cycles(1)
    done = entry(engine)
    assert done["state"] == "failed" and done["detail"] == "fault: bus: drive fault code 0x9: stopped"
    assert mock(engine).homing_stopped == ["b"]


def test_a_hardware_fault_of_its_component_stops_the_homing(make_engine: MakeEngine) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(10)
    mock(engine).read_error = "bus off"
    engine.run_cycles(1)
    assert entry(engine)["state"] == "failed" and "bus off" in entry(engine)["detail"]
    assert mock(engine).homing_stopped == ["b"]


def test_the_drives_own_failure_is_reported_in_its_words(make_engine: MakeEngine) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(10)
    mock(engine).homing_failure = "homing error: switch not found"
    engine.run_cycles(2)
    done = entry(engine)
    assert done["state"] == "failed" and done["detail"] == "homing error: switch not found"
    assert mock(engine).homing_stopped == []  # the drive ended it itself
    assert any("homing b failed: homing error: switch not found" in e for e in events(engine))
    mock(engine).homing_failure = None
    engine.run_cycles(300)
    assert engine.home("b")["attempt"] == 2  # a new attempt once the joint is held and still again
    assert entry(engine) == {"joint": "b", "state": "running", "attempt": 2, "detail": None, "position": None}


def test_stopping_the_daemon_stops_the_homing(make_engine: MakeEngine) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(10)
    engine.stop()
    assert mock(engine).homing_stopped == ["b"]
    assert entry(engine)["state"] == "failed" and "the daemon is stopping" in entry(engine)["detail"]


def test_a_drive_that_does_not_confirm_the_stop_is_ended_by_the_engine(
    make_engine: MakeEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    engine = homing_engine(make_engine)
    engine.home("b")
    engine.run_cycles(10)
    monkeypatch.setattr(mock(engine), "stop_homing", lambda joint: None)  # a drive that does not answer
    monkeypatch.setattr(mock(engine), "homing", lambda joint: (Homing.RUNNING, ""))
    engine.request_estop()
    engine.run_cycles(400)  # < STOP_CONFIRM (1 s = 500 cycles)
    assert entry(engine)["state"] == "running" and 1 in engine.manager.reserved  # still its drive's
    engine.run_cycles(101)
    done = entry(engine)
    assert done["state"] == "failed" and done["detail"] == "e-stop: the drive did not report the stop in time"
    assert engine.manager.reserved == {}


def test_a_component_that_cannot_home_says_so(make_engine: MakeEngine) -> None:
    engine = make_engine()  # the mock without params.homing
    assert engine.home("a") == {"error": "bus: mock: no homing configured (params.homing)"}
    assert engine.manager.reserved == {}
    assert engine.switch(["fwd"], []).ok


def test_the_twin_cannot_home() -> None:
    from tests.test_twin_engine import twin

    engine = twin("rrbot_twin.yaml")
    assert "cannot home its drives" in engine.home("joint1")["error"]


def test_homing_joint_holds_while_another_controller_commands_the_others(make_engine: MakeEngine) -> None:
    engine = homing_engine(
        make_engine,
        {
            "controllers": {
                "fwd_a": {"type": "forward_command", "params": {"joints": ["a"], "interface": "position"}},
            }
        },
    )
    assert engine.switch(["fwd_a"], []).ok
    engine.home("b")
    send(engine, "fwd_a", [0.2])
    engine.run_cycles(CYCLES + 2)
    assert entry(engine)["state"] == "attained"
    assert float(engine.state.position[0]) == pytest.approx(0.2, abs=1e-3)
