"""The controller manager's lifecycle beyond load and switch (issue [runtime]): configure again, replace, unload,
and a controller whose own code raises in on_configure, on_cleanup or on_params — reported, and the rest as it was.
Lockstep: nothing here depends on timing."""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable
from typing import Any

import pytest

from hild.config.params import with_values
from hild.config.tuning import MANAGER
from hild.controller import Controller
from hild.crossing.requests import Cleanup, Configure, Load, Refused, SetHardwareState, SetParams, Unload
from hild.cycle.engine import Engine
from hild.cycle.manager import SwitchError
from tests.test_engine import JumpGuard, events, modes, send

MakeEngine = Callable[..., Engine]


class Fragile(Controller):
    """Raises from the hooks named in ``raises``; counts the calls of each."""

    def __init__(self, context, raises: set[str] = frozenset()) -> None:  # type: ignore[assignment]
        super().__init__(context, Controller.Params())
        self.raises = raises
        self.calls: dict[str, int] = {}

    def _hook(self, name: str) -> None:
        self.calls[name] = self.calls.get(name, 0) + 1
        if name in self.raises:
            raise RuntimeError(f"{name} failed")

    def on_configure(self) -> None:
        self._hook("configure")

    def on_cleanup(self) -> None:
        self._hook("cleanup")

    def on_params(self, old: object) -> None:
        self._hook("params")


def fragile(engine: Engine, name: str, raises: set[str] = frozenset()) -> Fragile:  # type: ignore[assignment]
    return Fragile(engine.controller_context(name), raises)


def with_one(make_engine: MakeEngine) -> tuple[Engine, Fragile]:
    """An engine with the Fragile controller ``one`` added (configured, inactive)."""
    engine = make_engine()
    one = fragile(engine, "one")
    engine.add_controller("one", "test", one)
    return engine, one


def test_configure_again_cleans_up_first_and_a_raising_on_configure_leaves_it_unconfigured(
    make_engine: MakeEngine,
) -> None:
    engine, one = with_one(make_engine)
    engine.manager.configure("one")  # inactive → cleaned up, configured again
    assert one.calls == {"configure": 2, "cleanup": 1}
    one.raises = {"configure"}
    with pytest.raises(SwitchError, match="one: on_configure raised RuntimeError: configure failed; it stays unconf"):
        engine.manager.configure("one")
    assert engine.manager.records["one"].state == "unconfigured"
    result = engine.switch(["one"], [])
    assert not result.ok and "one is not configured" in result.error


def test_cleanup_takes_only_an_inactive_controller_to_unconfigured_and_configure_brings_it_back(
    make_engine: MakeEngine,
) -> None:
    engine, one = with_one(make_engine)
    assert engine.switch(["one"], []).ok

    def cleanup() -> concurrent.futures.Future[Any]:
        future = engine.request(Cleanup("one"))
        engine.run_cycles(1)
        return future

    with pytest.raises(Refused, match="'one' is active: it cannot be cleaned up \\(deactivate it first\\)"):
        cleanup().result(0)
    assert engine.switch([], ["one"]).ok
    assert cleanup().result(0) == {"name": "one", "state": "unconfigured"}
    assert one.calls == {"configure": 1, "cleanup": 1} and engine.manager.records["one"].state == "unconfigured"
    assert "info:controller_manager:cleaned up one: unconfigured" in events(engine)
    with pytest.raises(Refused, match="'one' is unconfigured: it cannot be cleaned up \\(only an inactive one"):
        cleanup().result(0)
    result = engine.switch(["one"], [])
    assert not result.ok and "one is not configured" in result.error
    configured = engine.request(Configure("one"))
    engine.run_cycles(1)
    assert configured.result(0)["state"] == "inactive" and engine.switch(["one"], []).ok


def test_a_replacement_whose_on_configure_raises_leaves_the_loaded_one_as_it_was(make_engine: MakeEngine) -> None:
    engine = make_engine()
    old = fragile(engine, "one")
    engine.add_controller("one", "test", old)
    with pytest.raises(SwitchError, match="the new instance's on_configure raised RuntimeError"):
        engine.manager.replace("one", "test", fragile(engine, "one", {"configure"}))
    assert engine.manager.records["one"].instance is old and engine.manager.records["one"].state == "inactive"
    new = fragile(engine, "one")
    assert engine.manager.replace("one", "test", new) == "inactive"
    assert old.calls["cleanup"] == 1 and new.calls == {"configure": 1}


def test_on_cleanup_that_raises_is_reported_and_the_unload_goes_on(make_engine: MakeEngine) -> None:
    engine = make_engine()
    engine.add_controller("one", "test", fragile(engine, "one", {"cleanup"}))
    engine.manager.unload("one")
    assert "one" not in engine.manager.records
    assert any("one: on_cleanup raised RuntimeError: cleanup failed" in e for e in events(engine))


def test_on_params_that_raises_gets_the_old_params_back_and_nothing_changes(make_engine: MakeEngine) -> None:
    engine = make_engine()
    fwd = engine.manager.records["fwd"].instance
    old = fwd.params
    future = engine.request(SetParams("fwd", old.model_copy(update={"command_timeout": 0.9}), ("x",)))
    engine.run_cycles(1)
    assert future.result(0)["changed"] == ["x"] and fwd.params.command_timeout == 0.9
    one = fragile(engine, "one", {"params"})
    engine.add_controller("one", "test", one)
    engine.loads["one"] = Load("one", "test", one.params)
    failed = engine.request(SetParams("one", Controller.Params(), ("y",)))
    engine.run_cycles(1)
    with pytest.raises(Refused, match="one: on_params raised RuntimeError: params failed, and again with its old"):
        failed.result(0)  # it raises for any params: not even its old ones take
    assert one.calls["params"] == 2 and one.params is not None
    one.raises = set()
    once = engine.request(SetParams("one", Controller.Params(), ("y",)))
    engine.run_cycles(1)
    assert once.result(0)["changed"] == ["y"]
    engine.stop()


class RejectsTimeout(Fragile):
    """Takes any parameters but a command_timeout over 1 s (its old ones are always fine)."""

    def on_params(self, old: object) -> None:
        if getattr(self.params, "command_timeout", 0.0) > 1.0:
            raise ValueError("too slow")


def test_on_params_that_raises_for_the_new_ones_keeps_the_old_ones_and_the_controller_runs(
    make_engine: MakeEngine,
) -> None:
    engine = make_engine()
    fwd = engine.manager.records["fwd"].instance
    picky = RejectsTimeout(engine.controller_context("picky"))
    picky.params = fwd.params
    engine.add_controller("picky", "test", picky)
    engine.loads["picky"] = Load("picky", "test", fwd.params)
    failed = engine.request(SetParams("picky", fwd.params.model_copy(update={"command_timeout": 2.0}), ("z",)))
    engine.run_cycles(1)
    with pytest.raises(Refused, match="picky: on_params raised ValueError: too slow; nothing changed"):
        failed.result(0)
    assert picky.params.command_timeout == fwd.params.command_timeout
    engine.stop()


def test_lifecycle_requests_never_move_the_arm(make_engine: MakeEngine) -> None:
    """Load, configure, new parameters and unload while a controller moves a joint: the command never steps."""
    engine = make_engine()
    assert engine.switch(["fwd"], []).ok
    guard = JumpGuard(engine)
    params = engine.loaded.controller_params["fwd"]
    fwd = engine.manager.records["fwd"].instance
    for k in range(20):
        fwd.accept({"values": [0.1 + 0.01 * k, -0.2, 0.3]})
        for request in (
            Load(f"late{k}", "forward_command", params),
            Configure(f"late{k}"),
            SetParams("fwd", params.model_copy(update={"command_timeout": 0.5 + 0.01 * k}), ("t",)),
            Unload(f"late{k}"),
        ):
            future = engine.request(request)
            guard.run(1)
            assert future.done() and future.exception() is None, future.exception()
    assert set(engine.manager.records) == {"jsb", "fwd"} and engine.manager.records["fwd"].state == "active"
    engine.stop()


# ---- hardware set inactive by an operator --------------------------------------------------------------------------
def test_hardware_set_inactive_mid_move_holds_its_joints_where_they_are_and_keeps_writing(
    make_engine: MakeEngine,
) -> None:
    """ros2_control stops writing an inactive component; hild keeps its drives held (an unbraked arm would fall),
    so inactive means: read, held by the supervisor, out of every controller's reach."""
    engine = make_engine()
    assert engine.switch(["fwd"], []).ok
    guard = JumpGuard(engine)
    bus = engine.hardware[0]
    writes = []
    real_write = bus.component.write
    bus.component.write = lambda t, dt, command: (writes.append(t), real_write(t, dt, command))[1]  # type: ignore[method-assign]
    for k in range(50):  # moving
        send(engine, "fwd", [0.2 * k / 50, -0.2, 0.3])
        guard.run(1)
    inactive = engine.request(SetHardwareState(bus.name, "inactive"))
    guard.run(1)
    assert inactive.result(0) == {"name": bus.name, "state": "inactive", "deactivated": ["fwd"]}
    latched = engine.final.position.copy()
    guard.run(200)
    assert modes(engine) == ["hold"] * 3
    assert abs(engine.final.position - latched).max() < 1e-9  # held where it was, not at the controller's target
    assert len(writes) == 251  # and written every cycle: the drives stay enabled
    assert engine.snapshot().hardware[0]["state"] == "inactive"
    assert not any(i["available"] for i in engine.snapshot().interfaces)
    refused = engine.switch(["fwd"], [])
    assert not refused.ok and "of inactive hardware ['bus'] (set it active first)" in refused.error
    again = engine.request(SetHardwareState(bus.name, "inactive"))
    guard.run(1)
    assert again.result(0)["deactivated"] == []  # already inactive: nothing more to do
    active = engine.request(SetHardwareState(bus.name, "active"))
    guard.run(1)
    assert active.result(0)["state"] == "active" and engine.switch(["fwd"], []).ok
    assert [e for e in events(engine) if "hardware bus set" in e] == [
        "info:controller_manager:hardware bus set inactive; deactivated ['fwd'], its joints held",
        "info:controller_manager:hardware bus set active",
    ]


@pytest.mark.parametrize(
    ("name", "state", "reason"),
    [
        ("nope", "inactive", "no hardware component 'nope' (components: ['bus'])"),
        ("bus", "unconfigured", "bus unconfigured: hardware can be set active or inactive while the daemon runs"),
    ],
)
def test_a_hardware_state_request_that_cannot_be_is_refused(
    make_engine: MakeEngine, name: str, state: str, reason: str
) -> None:
    engine = make_engine()
    future = engine.request(SetHardwareState(name, state))
    engine.run_cycles(1)
    with pytest.raises(Refused, match=reason.replace("(", "\\(").replace(")", "\\)").replace("[", "\\[")):
        future.result(0)
    assert engine.snapshot().hardware[0]["state"] == "active"


# ---- the daemon's own limits: soft margins and the velocity scale ---------------------------------------------------
def tune(engine: Engine, **changes: float) -> concurrent.futures.Future[Any]:
    """Ask the cycle for the daemon's own parameters with ``changes`` (dotted paths, ``__`` for the dots)."""
    values = {path.replace("__", "."): value for path, value in changes.items()}
    return engine.request(SetParams(MANAGER, with_values(engine.tuning, values), tuple(values)))


def test_a_wider_soft_margin_keeps_commands_further_from_the_stops_and_a_narrower_one_is_refused(
    make_engine: MakeEngine,
) -> None:
    engine = make_engine()
    narrower = tune(engine, joints__a__soft_margin=0.0)
    engine.run_cycles(1)
    with pytest.raises(Refused, match=r"soft_margin of \['a'\] below the config's"):
        narrower.result(0)
    wider = tune(engine, joints__a__soft_margin=0.8)  # a is at 0.1: inside [-0.2, 0.2]
    engine.run_cycles(1)
    assert wider.result(0)["changed"] == ["joints.a.soft_margin"]
    assert engine.switch(["fwd"], []).ok
    send(engine, "fwd", [0.5, -0.2, 0.3])
    JumpGuard(engine).run(50)  # within the stream's 0.2 s timeout
    assert engine.final.position[0] == pytest.approx(0.2)  # clamped to 1.0 - 0.8
    assert "position" in engine.status()["joints"][0]["limits"]


def test_a_margin_that_would_leave_a_joint_outside_its_range_is_refused_and_nothing_changes(
    make_engine: MakeEngine,
) -> None:
    engine = make_engine()
    outside = tune(engine, joints__c__soft_margin=0.8)  # c is at 0.3, the new range [-0.2, 0.2]
    engine.run_cycles(1)
    with pytest.raises(Refused, match=r"c is at 0\.3 rad, outside the new soft range \[-0\.2, 0\.2\]"):
        outside.result(0)
    assert engine.tuning.joints["c"].soft_margin == 0.05  # the config's
    assert engine.supervisor._soft_upper[2] == pytest.approx(0.95)


def test_the_velocity_scale_slows_what_controllers_command_and_never_steps_it(make_engine: MakeEngine) -> None:
    engine = make_engine()
    scaled = tune(engine, velocity_scale=0.25)
    engine.run_cycles(1)
    assert scaled.result(0)["changed"] == ["velocity_scale"]
    assert engine.switch(["fwd"], []).ok
    send(engine, "fwd", [0.9, -0.2, 0.3])
    before = engine.final.position[0]
    engine.run_cycles(10)
    moved = engine.final.position[0] - before
    assert moved == pytest.approx(0.25 * engine.limits.velocity[0] * 10 * engine.period, rel=0.15)
