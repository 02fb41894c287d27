"""The controller manager's hardware services (`ros2 control list_hardware_components|list_hardware_interfaces|
set_hardware_component_state`) from hild's list_hardware and list_interfaces, against a bare Zenoh peer."""

from __future__ import annotations

from typing import Any

import pytest
import zenoh

from hild.api.ros2 import types
from tests.api.conftest import Daemon
from tests.api.ros2.conftest import ask
from tests.api.ros2.test_face import switch
from tests.helpers import wait_for

CM = "controller_manager_msgs/srv"
FIELDS = ("position", "velocity", "effort")


def interfaces(peer: zenoh.Session) -> Any:
    return ask(peer, "/controller_manager/list_hardware_interfaces", f"{CM}/ListHardwareInterfaces")


def set_state(peer: zenoh.Session, name: str, state_id: int, label: str = "") -> Any:
    target = types.message("lifecycle_msgs/msg/State", id=state_id, label=label)
    return ask(
        peer,
        "/controller_manager/set_hardware_component_state",
        f"{CM}/SetHardwareComponentState",
        name=name,
        target_state=target,
    )


def test_command_interfaces_are_claimed_while_a_controller_holds_them(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    before = {i.name: i for i in interfaces(peer).command_interfaces}
    json_names = [i["name"] for i in ros_daemon.engine.snapshot().interfaces]
    assert list(before) == json_names and "a/position" in before
    assert all(i.is_available and not i.is_claimed and i.data_type == "double" for i in before.values())
    assert switch(peer, ["fwd_a"])
    after = {i.name: i.is_claimed for i in interfaces(peer).command_interfaces}
    assert [name for name, claimed in after.items() if claimed] == ["a/position"]


def test_state_interfaces_are_every_joints_position_velocity_effort(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    state = interfaces(peer).state_interfaces
    assert [i.name for i in state] == [f"{j}/{f}" for j in "abc" for f in FIELDS]
    assert all(i.is_available and not i.is_claimed for i in state)


def test_each_component_with_its_state_and_interfaces(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["fwd"])
    (bus,) = ask(peer, "/controller_manager/list_hardware_components", f"{CM}/ListHardwareComponents").component
    assert (bus.name, bus.type, bus.plugin_name, bus.is_async, bus.rw_rate) == (
        "bus",
        "system",
        "hild/mock",
        False,
        500,
    )
    assert (bus.state.id, bus.state.label) == (3, "active")
    claimed = {i.name for i in bus.command_interfaces if i.is_claimed}
    assert claimed == {"a/position", "b/position", "c/position"}
    assert len(bus.state_interfaces) == 9 and not any(i.is_claimed for i in bus.state_interfaces)


def test_active_is_ok_for_an_active_component(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    reply = set_state(peer, "bus", 3, "active")
    assert reply.ok and (reply.state.id, reply.state.label) == (3, "active")
    assert set_state(peer, "bus", 0, "active").ok  # by label, as rclcpp_lifecycle takes it


@pytest.mark.parametrize("by", [(2, ""), (0, "inactive")], ids=["by id", "by label"])
def test_inactive_deactivates_its_controllers_holds_its_joints_and_active_gives_them_back(
    ros_daemon: Daemon, peer: zenoh.Session, by: tuple[int, str]
) -> None:
    assert switch(peer, ["fwd"])
    reply = set_state(peer, "bus", *by)
    assert reply.ok and (reply.state.id, reply.state.label) == (2, "inactive")
    wait_for(lambda: ros_daemon.events_with("hardware bus set inactive; deactivated ['fwd'], its joints held"))
    snapshot = ros_daemon.engine.snapshot()
    assert [c["state"] for c in snapshot.controllers if c["name"] == "fwd"] == ["inactive"]
    assert {j["mode"] for j in snapshot.joints} == {"hold"}
    listing = interfaces(peer)
    assert not any(i.is_available or i.is_claimed for i in listing.command_interfaces)
    assert all(i.is_available for i in listing.state_interfaces)  # still read, as ros2_control has it
    assert not switch(peer, ["fwd"])  # nothing may command it now …
    wait_for(lambda: ros_daemon.events_with("fwd claims ['a/position', 'b/position', 'c/position'], of inactive hard"))
    assert set_state(peer, "bus", 3, "active").ok
    assert all(i.is_available for i in interfaces(peer).command_interfaces)
    assert switch(peer, ["fwd"])  # … and once active again, it may


@pytest.mark.parametrize(
    ("name", "state_id", "label", "reason"),
    [
        ("bus", 1, "unconfigured", "bus unconfigured (id 1): not a state hild offers"),
        ("bus", 4, "finalized", "bus finalized (id 4): not a state hild offers"),
        ("nope", 3, "active", "no hardware component 'nope'"),
    ],
)
def test_every_other_request_is_refused_saying_why_and_changes_nothing(
    ros_daemon: Daemon, peer: zenoh.Session, name: str, state_id: int, label: str, reason: str
) -> None:
    reply = set_state(peer, name, state_id, label)
    assert not reply.ok
    wait_for(lambda: [e for e in ros_daemon.events_with("set_hardware_component_state") if reason in e["message"]])
    assert ros_daemon.engine.snapshot().hardware[0]["state"] == "active"


def test_a_faulted_component_is_reported_and_active_says_how_to_recover(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    engine = ros_daemon.engine
    engine.submit(lambda: engine._hardware_fault(engine.hardware[0], "encoder lost")).result(5.0)
    wait_for(lambda: engine.snapshot().hardware[0]["state"] == "fault", what="the fault in the snapshot")
    (bus,) = ask(peer, "/controller_manager/list_hardware_components", f"{CM}/ListHardwareComponents").component
    assert (bus.state.id, bus.state.label) == (0, "fault")
    assert not any(i.is_available for i in interfaces(peer).command_interfaces)
    reply = set_state(peer, "bus", 3, "active")
    assert not reply.ok and reply.state.label == "fault"
    wait_for(lambda: ros_daemon.events_with("bus is fault (encoder lost): recover it as an operator does, with"))
