"""The rcl_interfaces parameter services (`ros2 param list|get|set|describe`, rclpy's parameter client) on each
controller's node ``/<controller>`` (hild's list/get/set_parameters: the same checks and refusals) and on
``/controller_manager`` (``update_rate``, and what a spawner sets before a load), against a bare Zenoh peer."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import zenoh

from hild.api.ros2 import types
from hild.api.ros2.parameter_values import (
    BOOL,
    BOOL_ARRAY,
    BYTE_ARRAY,
    DOUBLE,
    DOUBLE_ARRAY,
    INTEGER,
    INTEGER_ARRAY,
    NOT_SET,
    STRING,
    STRING_ARRAY,
    from_ros,
    message_with_defaults,
    ros_type,
    to_ros,
)
from hild.api.ros2.parameters import listing
from tests.api.conftest import WAIT, Daemon
from tests.api.ros2.conftest import ask
from tests.api.ros2.test_face import switch
from tests.api.ros2.test_loaded_later import on_cycle
from tests.helpers import wait_for

SRV = "rcl_interfaces/srv"
SIX = {
    "list_parameters": f"{SRV}/ListParameters",
    "get_parameters": f"{SRV}/GetParameters",
    "set_parameters": f"{SRV}/SetParameters",
    "set_parameters_atomically": f"{SRV}/SetParametersAtomically",
    "describe_parameters": f"{SRV}/DescribeParameters",
    "get_parameter_types": f"{SRV}/GetParameterTypes",
}


def parameter(name: str, value: Any) -> Any:
    return types.message("rcl_interfaces/msg/Parameter", name=name, value=to_ros(value))


def names(peer: zenoh.Session, node: str, prefixes: tuple[str, ...] = (), depth: int = 0) -> tuple[list, list]:
    result = ask(peer, f"/{node}/list_parameters", SIX["list_parameters"], prefixes=list(prefixes), depth=depth).result
    return list(result.names), list(result.prefixes)


def got(peer: zenoh.Session, node: str, *wanted: str) -> list[Any]:
    values = ask(peer, f"/{node}/get_parameters", SIX["get_parameters"], names=list(wanted)).values
    return [from_ros(v) for v in values]


def described(peer: zenoh.Session, node: str, *wanted: str) -> dict[str, Any]:
    descriptors = ask(peer, f"/{node}/describe_parameters", SIX["describe_parameters"], names=list(wanted)).descriptors
    return {d.name: d for d in descriptors}


def set_each(peer: zenoh.Session, node: str, *parameters: Any) -> list[tuple[bool, str]]:
    results = ask(peer, f"/{node}/set_parameters", SIX["set_parameters"], parameters=list(parameters)).results
    return [(r.successful, r.reason) for r in results]


def set_all(peer: zenoh.Session, node: str, *parameters: Any) -> tuple[bool, str]:
    result = ask(
        peer, f"/{node}/set_parameters_atomically", SIX["set_parameters_atomically"], parameters=list(parameters)
    ).result
    return result.successful, result.reason


def tokens(peer: zenoh.Session) -> list[list[str]]:
    replies = peer.liveliness().get("@ros2_lv/0/**", timeout=WAIT)
    return [str(r.ok.key_expr).split("/") for r in replies if r.ok is not None]


def of_late(key: list[str]) -> bool:
    return key[8] == "late" or (len(key) > 9 and key[9].startswith("%late%"))


# ---- on the wire: the nodes and their services ----------------------------------------------------------------------
def test_each_controller_is_a_node_with_all_six_parameter_services(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """rclpy's parameter client waits for all six; `ros2 param` looks the node up first. Each service's token
    carries its node's id, so the graph files it under that node."""
    keys = tokens(peer)
    node_ids = {k[8]: k[3] for k in keys if k[5] == "NN"}
    assert {"controller_manager", "jsb", "fwd", "fwd_a", "traj"} <= set(node_ids)
    assert len(set(node_ids.values())) == len(node_ids)  # one id each
    services = {(k[8], k[9], k[3]) for k in keys if k[5] == "SS"}
    for node in ("controller_manager", "fwd", "traj"):
        for short in SIX:
            assert (node, f"%{node}%{short}", node_ids[node]) in services, (node, short)


def test_a_controller_node_comes_with_its_controller_and_goes_with_it(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    engine = ros_daemon.engine
    on_cycle(ros_daemon, lambda: engine.load_controller("late", "forward_command", {"joints": ["b"]}))
    wait_for(lambda: any(k[5] == "NN" and k[8] == "late" for k in tokens(peer)), what="the node /late")
    wait_for(lambda: any(k[9] == "%late%set_parameters" for k in tokens(peer) if len(k) > 9), what="its services")
    assert got(peer, "late", "joints") == [["b"]]
    on_cycle(ros_daemon, lambda: engine.manager.unload("late"))
    wait_for(lambda: not any(of_late(k) for k in tokens(peer)), what="the node and its services withdrawn")
    assert any(k[5] == "NN" and k[8] == "fwd" for k in tokens(peer))  # the others stay


# ---- a controller's node --------------------------------------------------------------------------------------------
def test_list_filters_by_prefix_and_depth_as_rclcpp_does(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    every, prefixes = names(peer, "traj")
    assert {"joints", "velocity_scale", "constraints.goal_time", "constraints.stopped_velocity_tolerance"} <= set(every)
    assert "constraints" in prefixes
    top, _ = names(peer, "traj", depth=1)
    assert "joints" in top and not any("." in name for name in top)
    under, under_prefixes = names(peer, "traj", ("constraints",), depth=2)  # rclcpp's depth counts the first dot
    assert {"constraints.goal_time", "constraints.stopped_velocity_tolerance"} <= set(under)
    assert all(name.startswith("constraints.") for name in under) and under_prefixes == ["constraints"]


def test_get_and_types_give_each_value_its_ros_type(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert got(peer, "fwd", "joints", "interface", "command_timeout") == [["a", "b", "c"], "position", 0.5]
    kinds = ask(peer, "/fwd/get_parameter_types", SIX["get_parameter_types"], names=["joints", "command_timeout"])
    assert list(kinds.types) == [STRING_ARRAY, DOUBLE]
    assert got(peer, "fwd", "joints", "nope") == []  # rclcpp: a name the node lacks → an empty reply
    assert list(ask(peer, "/fwd/get_parameter_types", SIX["get_parameter_types"], names=["nope"]).types) == []
    assert got(peer, "jsb", "publish_rate") == [100.0]


def test_describe_says_read_only_for_a_fixed_parameter_only_while_active(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    before = described(peer, "fwd", "joints", "command_timeout")
    assert (before["joints"].read_only, before["command_timeout"].read_only) == (False, False)
    assert before["joints"].description == "Joints commanded, in the order of the values."
    assert before["joints"].type == STRING_ARRAY and before["command_timeout"].type == DOUBLE
    assert switch(peer, ["fwd"])
    after = described(peer, "fwd", "joints", "command_timeout")
    assert (after["joints"].read_only, after["command_timeout"].read_only) == (True, False)
    assert described(peer, "fwd", "joints", "nope") == {}


def test_a_mapping_is_shown_as_its_json_text_read_only(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    every, _ = names(peer, "traj")
    assert "constraints.joints" in every
    assert got(peer, "traj", "constraints.joints") == ["{}"]
    shown = described(peer, "traj", "constraints.joints")["constraints.joints"]
    assert shown.type == STRING and shown.read_only and "ROS has no type for it" in shown.description


def test_set_parameters_sets_each_on_its_own_with_hilds_reasons(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["fwd"])
    results = set_each(
        peer,
        "fwd",
        parameter("command_timeout", 0.25),
        parameter("joints", ["a"]),
        parameter("command_timeout", -1.0),
    )
    assert results[0] == (True, "")
    assert not results[1][0] and "joints of fwd cannot change while it is active" in results[1][1]
    assert not results[2][0] and "command_timeout: Input should be greater than 0" in results[2][1]
    assert got(peer, "fwd", "command_timeout", "joints") == [0.25, ["a", "b", "c"]]
    assert ros_daemon.engine.manager.records["fwd"].instance.params.command_timeout == 0.25  # the cycle's own
    wait_for(lambda: ros_daemon.events_with("refused ROS request on /fwd/set_parameters"), what="the refusal event")


def test_an_integer_sets_a_double_as_ros2_param_set_sends_it(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """`ros2 param set /fwd command_timeout 1` sends an INTEGER 1 (rclpy's guess from the text)."""
    assert set_each(peer, "fwd", parameter("command_timeout", 1)) == [(True, "")]
    assert got(peer, "fwd", "command_timeout") == [1.0]


def test_set_atomically_is_all_or_nothing_and_a_rebuild_keeps_the_node(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    ok, reason = set_all(peer, "fwd_a", parameter("command_timeout", 0.3), parameter("interface", "torque"))
    assert not ok and "interface: Input should be 'position', 'velocity' or 'effort'" in reason
    assert got(peer, "fwd_a", "command_timeout", "interface") == [0.5, "position"]
    node = [k[3] for k in tokens(peer) if k[5] == "NN" and k[8] == "fwd_a"]
    assert set_all(peer, "fwd_a", parameter("command_timeout", 0.3), parameter("joints", ["b"])) == (True, "")
    assert got(peer, "fwd_a", "command_timeout", "joints") == [0.3, ["b"]]
    fwd_a = next(c for c in ros_daemon.engine.snapshot().controllers if c["name"] == "fwd_a")
    assert fwd_a["claimed"] == ["b/position"]  # rebuilt with the new joints
    assert [k[3] for k in tokens(peer) if k[5] == "NN" and k[8] == "fwd_a"] == node  # the same node answers


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        (message_with_defaults({"type": NOT_SET}), "cannot be unset"),
        (message_with_defaults({"type": BYTE_ARRAY, "byte_array_value": np.array([1], dtype=np.uint8)}), "byte"),
        (message_with_defaults({"type": 42}), "unknown parameter type 42"),
    ],
)
def test_a_value_hild_cannot_hold_is_refused_before_anything_changes(
    ros_daemon: Daemon, peer: zenoh.Session, value: Any, reason: str
) -> None:
    request = types.message("rcl_interfaces/msg/Parameter", name="command_timeout", value=value)
    ((ok, why),) = set_each(peer, "fwd", request)
    assert not ok and reason in why, why
    assert got(peer, "fwd", "command_timeout") == [0.5]


# ---- the controller manager's node --------------------------------------------------------------------------------
def test_the_manager_has_its_update_rate_read_only(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert names(peer, "controller_manager") == (["update_rate"], [])
    assert got(peer, "controller_manager", "update_rate") == [500]
    rate = described(peer, "controller_manager", "update_rate")["update_rate"]
    assert rate.read_only and rate.type == INTEGER and "cycle's rate" in rate.description
    ((ok, reason),) = set_each(peer, "controller_manager", parameter("update_rate", 100))
    assert not ok and "update_rate is read-only" in reason
    assert got(peer, "controller_manager", "update_rate") == [500]


def test_the_manager_keeps_what_the_next_load_of_a_controller_uses(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    plugin = "forward_command_controller/ForwardCommandController"
    results = set_each(
        peer,
        "controller_manager",
        parameter("x.type", plugin),
        parameter("x.params_file", "/tmp/x.yaml"),  # a single string is taken as a one-path array, as ros2_control
        parameter("x.fallback_controllers", ["fwd_a"]),
    )
    assert results == [(True, "")] * 3
    assert names(peer, "controller_manager", ("x",)) == (["x.type", "x.params_file", "x.fallback_controllers"], ["x"])
    assert got(peer, "controller_manager", "x.type", "x.params_file") == [plugin, ["/tmp/x.yaml"]]


@pytest.mark.parametrize(
    ("name", "value", "reason"),
    [
        ("x.node_options_args", ["--ros-args", "-r", "a:=b"], "--controller-ros-args (remappings, …) cannot apply"),
        ("x.params_file", ["relative.yaml"], "'relative.yaml' is not an absolute path"),
        ("x.type", ["a"], "x.type must be a non-empty string"),
        ("x.fallback_controllers", "fwd_a", "x.fallback_controllers must be a string array"),
        ("x.gain", 2.0, "the controller manager has update_rate (read-only) and, per controller to load"),
        ("use_sim_time", True, "the controller manager has update_rate"),
    ],
)
def test_the_manager_refuses_what_it_does_not_keep(
    ros_daemon: Daemon, peer: zenoh.Session, name: str, value: Any, reason: str
) -> None:
    ((ok, why),) = set_each(peer, "controller_manager", parameter(name, value))
    assert not ok and reason in why, why
    ok, why = set_all(peer, "controller_manager", parameter("y.type", "forward_command"), parameter(name, value))
    assert not ok and reason in why
    assert names(peer, "controller_manager") == (["update_rate"], [])  # neither was kept


# ---- pure: rclcpp's listing, ROS types ---------------------------------------------------------------------------
def test_listing_is_rclcpps() -> None:
    every = ["a", "b.c", "b.d.e", "bb.x", "b"]
    assert listing(every, [], 0) == (every, ["b", "b.d", "bb"])
    assert listing(every, [], 1) == (["a", "b"], [])
    assert listing(every, [], 2) == (["a", "b.c", "bb.x", "b"], ["b", "bb"])
    assert listing(every, ["b"], 1) == (["b"], [])  # rclcpp counts the separator after the prefix: depth 1 is b
    assert listing(every, ["b"], 2) == (["b.c", "b"], ["b"])  # not bb.x: a prefix ends at a separator
    assert listing(every, ["b"], 0) == (["b.c", "b.d.e", "b"], ["b", "b.d"])
    assert listing(every, ["b.d", "a"], 0) == (["a", "b.d.e"], ["b.d"])


@pytest.mark.parametrize(
    ("value", "kind"),
    [
        (True, BOOL),
        (3, INTEGER),
        (0.5, DOUBLE),
        ("x", STRING),
        ([True, False], BOOL_ARRAY),
        ([1, 2], INTEGER_ARRAY),
        ([1.5, 2], DOUBLE_ARRAY),
        (["a"], STRING_ARRAY),
        ([], STRING_ARRAY),
        (None, NOT_SET),
        ({"a": 1}, None),
        ([1, "a"], None),
        ([[1]], None),
        (2**70, None),
    ],
)
def test_each_json_value_has_the_ros_type_it_is(value: Any, kind: int | None) -> None:
    assert ros_type(value) == kind
    encoded = types.encode(to_ros(value), "rcl_interfaces/msg/ParameterValue")
    back = types.decode(encoded, "rcl_interfaces/msg/ParameterValue")
    if kind is None:
        assert back.type == STRING and back.string_value.startswith(("{", "[", "1"))
    elif kind != NOT_SET:
        assert from_ros(back) == ([float(v) for v in value] if kind == DOUBLE_ARRAY else value)
