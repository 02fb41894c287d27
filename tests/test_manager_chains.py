"""Chained controllers in the controller manager (mock robot, lockstep): update order, atomic switches of whole
chains, the refusals, failure propagation, exclusive reference claims, what list_controllers says, config checks."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hild.config import ConfigError, load_config
from hild.controller import ControllerState
from hild.cycle.engine import Engine
from tests.conftest import merge, mock_robot, with_trajectory
from tests.test_engine import events, modes

MakeEngine = Callable[..., Engine]
IMP = {
    "type": "joint_impedance",
    "params": {
        "joints": ["a", "b", "c"],
        "stiffness": [50, 50, 50],
        "damping": [2, 2, 2],
        "max_stiffness": [100, 100, 100],
        "max_damping": [5, 5, 5],
        "gravity_compensation": False,
    },
}


def chained_robot() -> dict[str, Any]:
    config = with_trajectory(mock_robot(), "jtc", "jtc_ab", joints=("a", "b"))
    config["controllers"]["jtc"]["params"]["joints"] = ["a", "b", "c"]
    config["controllers"]["jtc"]["chain_to"] = "imp"
    config["controllers"]["jtc_ab"]["chain_to"] = "imp"
    config["controllers"]["imp"] = IMP
    return config


@pytest.fixture
def chained(write_config: Callable[..., Path]) -> Engine:
    engine = Engine(load_config(write_config(chained_robot())))
    engine.start()
    events(engine)
    return engine


def states(engine: Engine) -> dict[str, str]:
    return {name: str(rec.state) for name, rec in engine.manager.records.items()}


def test_a_chained_controller_needs_the_one_it_chains_to(chained: Engine) -> None:
    result = chained.switch(["jtc"], [])
    assert not result.ok and "jtc chains to imp, which would not be active after the switch" in result.error
    assert states(chained)["jtc"] == "inactive" and states(chained)["imp"] == "inactive"


def test_a_whole_chain_switches_at_once_and_the_chained_one_updates_first(chained: Engine) -> None:
    result = chained.switch(["jtc", "imp"], [])  # in any order: the one chained to starts first
    assert result.ok and result.activated == ["imp", "jtc"]
    order = [r.name for r in chained.manager.active]
    assert order.index("jtc") < order.index("imp")
    seen: list[str] = []
    for name in ("jtc", "imp"):
        instance = chained.manager.records[name].instance
        original = instance.update
        instance.update = lambda *a, _n=name, _o=original: (seen.append(_n), _o(*a))[1]  # type: ignore[method-assign]
    chained.run_cycles(3)
    assert seen == ["jtc", "imp"] * 3
    assert modes(chained) == ["controlled"] * 3
    # what jtc wrote reached imp's references, and imp's command the hardware
    refs = chained.manager.records["imp"].instance.references
    assert refs is not None and refs.written.tolist() == [True, True, True]
    chained.run_cycles(30)
    np.testing.assert_allclose(chained.final.kp, 50.0)  # the impedance's stiffness, ramped in


def test_stopping_the_one_chained_to_is_refused_in_strict_and_takes_the_chain_in_best_effort(chained: Engine) -> None:
    assert chained.switch(["imp", "jtc"], []).ok
    refused = chained.switch([], ["imp"])
    assert not refused.ok and "imp cannot be deactivated while ['jtc'] chain to it" in refused.error
    assert states(chained)["imp"] == "active"
    best = chained.switch([], ["imp"], strict=False)
    assert best.ok and set(best.deactivated) == {"imp", "jtc"}
    assert states(chained)["jtc"] == "inactive" and states(chained)["imp"] == "inactive"
    chained.run_cycles(2)
    assert modes(chained) == ["hold"] * 3


def test_a_failing_activation_rolls_the_whole_chain_back(chained: Engine) -> None:
    def boom(*_: Any) -> None:
        raise RuntimeError("no")

    chained.manager.records["jtc"].instance.on_activate = boom  # type: ignore[method-assign]
    result = chained.switch(["imp", "jtc"], [])
    assert not result.ok and "rolled back" in result.error
    assert states(chained)["imp"] == "inactive" and states(chained)["jtc"] == "inactive"
    chained.manager.records["jtc"].instance.on_activate = boom  # type: ignore[method-assign]
    chained.manager.records["imp"].instance.on_activate = boom  # type: ignore[method-assign]
    best = chained.switch(["imp", "jtc"], [], strict=False)  # imp does not start: jtc is not started either
    assert best.activated == [] and states(chained)["jtc"] == "inactive"


def test_when_the_one_chained_to_fails_the_chain_stops_and_the_joints_hold(chained: Engine) -> None:
    assert chained.switch(["imp", "jtc"], []).ok

    def boom(*_: Any) -> None:
        raise RuntimeError("bug")

    chained.manager.records["imp"].instance.update = boom  # type: ignore[method-assign]
    chained.run_cycles(2)
    assert states(chained)["imp"] == "failed" and states(chained)["jtc"] == "inactive"
    assert "imp, which it chains to, failed" in chained.manager.records["jtc"].error
    assert modes(chained) == ["hold"] * 3
    assert any("jtc'], chained to it, deactivated too" in e for e in events(chained))


def test_a_failing_chained_controller_leaves_the_one_it_chains_to_holding_its_targets(chained: Engine) -> None:
    assert chained.switch(["imp", "jtc"], []).ok
    chained.run_cycles(5)
    before = chained.final.position.copy()

    def boom(*_: Any) -> None:
        raise RuntimeError("bug")

    chained.manager.records["jtc"].instance.update = boom  # type: ignore[method-assign]
    chained.run_cycles(5)
    assert states(chained)["jtc"] == "failed" and states(chained)["imp"] == "active"
    assert modes(chained) == ["controlled"] * 3  # the impedance holds compliantly at its last targets
    np.testing.assert_allclose(chained.final.position, before, atol=1e-9)


def test_references_are_exclusive_claims(chained: Engine) -> None:
    assert chained.switch(["imp", "jtc"], []).ok
    result = chained.switch(["jtc_ab"], [])
    assert not result.ok and "imp's references of joint a are claimed by both jtc and jtc_ab" in result.error
    assert chained.switch(["jtc_ab"], ["jtc"]).ok  # a swap within the chain, atomic
    assert chained.manager.records["imp"].chained_claims == frozenset(
        f"imp/{j}/{f}" for j in "ab" for f in ("position", "velocity")
    )


def test_an_estop_stops_the_chain(chained: Engine) -> None:
    assert chained.switch(["imp", "jtc"], []).ok
    assert set(chained.estop()["deactivated"]) == {"imp", "jtc"}


def test_list_controllers_reports_the_chain(chained: Engine) -> None:
    assert chained.switch(["imp", "jtc"], []).ok
    listed = {c["name"]: c for c in chained.status()["controllers"]}
    imp, jtc = listed["imp"], listed["jtc"]
    assert imp["is_chainable"] and imp["is_chained"] and imp["chain_to"] is None
    assert "imp/a/kp" in imp["reference_interfaces"] and len(imp["reference_interfaces"]) == 15
    assert jtc["chain_to"] == "imp" and not jtc["is_chainable"] and not jtc["is_chained"]
    assert jtc["chain_connections"] == [{"name": "imp", "reference_interfaces": jtc["claimed"]}]
    assert jtc["claimed"][:2] == ["imp/a/position", "imp/a/velocity"]
    assert not listed["jtc_ab"]["is_chained"]
    assert chained.switch([], ["jtc"]).ok
    assert not {c["name"]: c for c in chained.status()["controllers"]}["imp"]["is_chained"]


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"jtc": {"chain_to": "nope"}}, "unknown controller 'nope'"),
        ({"jtc": {"chain_to": "jtc"}}, "a controller cannot chain to itself"),
        ({"jtc": {"chain_to": "fwd"}}, "fwd (forward_command) exports no reference interfaces: it is not chainable"),
        ({"imp": {"chain_to": "jtc"}}, "comes back to"),
    ],
)
def test_config_checks_the_chain(write_config: Callable[..., Path], patch: dict[str, Any], message: str) -> None:
    config = merge(chained_robot(), {"controllers": patch})
    with pytest.raises(ConfigError, match=message.replace("(", "\\(").replace(")", "\\)")):
        load_config(write_config(config))


def test_a_chained_controller_keeps_state_names_in_the_snapshot(chained: Engine) -> None:
    assert chained.manager.records["jtc"].state is ControllerState.INACTIVE
    assert chained.manager.records["jtc"].chain_to == "imp"
