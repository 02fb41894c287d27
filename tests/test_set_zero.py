"""set-zero: an explicit operator command on a held, still joint; hold re-latches in the drive's new frame."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from hild.api.services import Services
from tests.test_engine import MakeEngine, events, send


def test_set_zero_relatches_hold_in_the_new_frame_without_pulling(make_engine: MakeEngine) -> None:
    engine = make_engine()
    engine.run_cycles(10)
    assert engine.set_zero("b") == {"joint": "b"}
    assert any("set-zero: b" in e for e in events(engine))
    engine.run_cycles(2)
    assert engine.state.position[1] == 0.0  # the drive now reads zero here
    assert engine.final.position[1] == 0.0  # and hold commands zero: no pull back toward -0.2
    engine.run_cycles(500)
    np.testing.assert_allclose(engine.state.position, [0.1, 0.0, 0.3])
    assert engine.supervisor.latched[1] == 0.0
    assert [j["mode"] for j in engine.status()["joints"]] == ["hold"] * 3


@pytest.mark.parametrize(
    ("joint", "prepare", "reason"),
    [
        ("nope", None, "unknown joint 'nope'"),
        ("a", "control", "is in controlled"),
        ("a", "move", "needs it still"),
    ],
)
def test_set_zero_is_refused_unless_the_joint_is_held_and_still(
    make_engine: MakeEngine, joint: str, prepare: str | None, reason: str
) -> None:
    engine = make_engine()
    if prepare == "control":
        assert engine.switch(["fwd"], []).ok
        send(engine, "fwd", [0.1, -0.2, 0.3])
        engine.run_cycles(2)
    if prepare == "move":
        engine.state.velocity[0] = 0.5  # as read this cycle
    before = engine.state.position.copy()
    result = engine.set_zero(joint)
    assert reason in result["error"]
    engine.run_cycles(5)
    np.testing.assert_allclose(engine.state.position, before)


def test_the_twin_has_no_zero_to_set() -> None:
    from tests.test_twin_engine import twin

    engine = twin("rrbot_twin.yaml")
    assert "cannot set a zero" in engine.set_zero("joint1")["error"]


def test_the_service_needs_confirmation(make_engine: MakeEngine) -> None:
    engine = make_engine()
    services = Services(engine)

    async def ask(raw: bytes) -> dict[str, object]:
        return await services.handle("set_zero", raw)

    reply = asyncio.run(ask(b'{"joint": "a"}'))
    assert reply["ok"] is False and "confirm" in str(reply["error"])
    reply = asyncio.run(ask(b'{"joint": "a", "confirm": "yes"}'))
    assert reply["ok"] is False and "true or false" in str(reply["error"])
