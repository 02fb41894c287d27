"""The controller manager's lifecycle services (`ros2 control load_controller|set_controller_state|unload_controller|
reload_controller_libraries|list_controller_types`) against a bare Zenoh peer: each answered by hild's JSON service,
its refusals a warning event with hild's reason (the responses carry only ``ok``)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
import zenoh

from hild.api.ros2 import types
from hild.api.ros2.parameter_values import to_ros
from tests.api.conftest import Daemon
from tests.api.ros2.conftest import ask
from tests.api.ros2.test_controller_manager import listed
from tests.api.ros2.test_face import switch
from tests.api.ros2.test_loaded_later import on_cycle
from tests.helpers import wait_for

CM = "controller_manager_msgs/srv"
FWD_PLUGIN = "forward_command_controller/ForwardCommandController"
SET_PARAMETERS = "rcl_interfaces/srv/SetParameters"


def lifecycle(peer: zenoh.Session, short: str, kind: str, **fields: object) -> bool:
    return bool(ask(peer, f"/controller_manager/{short}", f"{CM}/{kind}", **fields).ok)


def load(peer: zenoh.Session, name: str) -> bool:
    return lifecycle(peer, "load_controller", "LoadController", name=name)


def configure(peer: zenoh.Session, name: str) -> bool:
    return lifecycle(peer, "configure_controller", "ConfigureController", name=name)


def unload(peer: zenoh.Session, name: str) -> bool:
    return lifecycle(peer, "unload_controller", "UnloadController", name=name)


def reload_libraries(peer: zenoh.Session, force_kill: bool) -> bool:
    return lifecycle(peer, "reload_controller_libraries", "ReloadControllerLibraries", force_kill=force_kill)


def on_manager(peer: zenoh.Session, **values: object) -> None:
    """Set ``<controller>.<key>`` values on /controller_manager (keyword ``late__type`` → ``late.type``)."""
    parameters = [
        types.message("rcl_interfaces/msg/Parameter", name=name.replace("__", "."), value=to_ros(value))
        for name, value in values.items()
    ]
    results = ask(peer, "/controller_manager/set_parameters", SET_PARAMETERS, parameters=parameters).results
    assert all(r.successful for r in results), [r.reason for r in results]


def refused(daemon: Daemon, service: str, reason: str) -> None:
    prefix = f"refused ROS request on /controller_manager/{service}: "
    wait_for(lambda: [e for e in daemon.events_with(prefix) if reason in e["message"]], what=f"the event: {reason}")


def params_file(tmp_path: Path, name: str, params: dict[str, object]) -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({name: {"ros__parameters": params}}))
    return str(path)


def test_load_configure_activate_and_unload_as_set_controller_state_does(
    ros_daemon: Daemon, peer: zenoh.Session, tmp_path: Path
) -> None:
    path = params_file(tmp_path, "late", {"type": FWD_PLUGIN, "joints": ["b", "c"], "interface": "position"})
    on_manager(peer, late__params_file=[path], late__type=FWD_PLUGIN)
    assert load(peer, "late")
    late = listed(peer)["late"]
    assert (late.state, late.type, list(late.required_command_interfaces)) == ("unconfigured", FWD_PLUGIN, [])
    wait_for(lambda: ros_daemon.events_with("loaded late (forward_command) by a ROS 2 client: unconfigured"))
    # `ros2 control set_controller_state late inactive` sees unconfigured and configures; `active` switches
    assert configure(peer, "late")
    late = listed(peer)["late"]
    assert (late.state, list(late.required_command_interfaces)) == ("inactive", ["b/position", "c/position"])
    assert switch(peer, ["late"], strictness=1)
    assert listed(peer)["late"].state == "active"
    assert not unload(peer, "late")
    refused(ros_daemon, "unload_controller", "'late' is active; deactivate it first")
    assert switch(peer, [], deactivate=("late",))
    assert unload(peer, "late")
    assert "late" not in listed(peer)


def test_a_controller_of_the_config_file_loads_by_name_alone(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """As ros2_control's manager loads a controller its own YAML names, with no <name>.type set."""
    assert unload(peer, "fwd_a") and "fwd_a" not in listed(peer)
    assert load(peer, "fwd_a")
    fwd_a = listed(peer)["fwd_a"]
    assert (fwd_a.state, fwd_a.type) == ("unconfigured", FWD_PLUGIN)
    wait_for(lambda: ros_daemon.events_with("loaded fwd_a (forward_command) from "), what="the load event")
    assert configure(peer, "fwd_a") and list(listed(peer)["fwd_a"].required_command_interfaces) == ["a/position"]


@pytest.mark.parametrize(
    ("name", "manager", "file_params", "reason"),
    [
        ("ghost", {}, None, "has no controller 'ghost': nothing to reload it from; nor was ghost.type set on "
         "/controller_manager"),
        ("fwd", {}, None, "controller 'fwd' is already loaded"),
        ("x", {"x__type": FWD_PLUGIN, "x__params_file": ["/nonexistent/x.yaml"]}, None,
         "x.params_file: /nonexistent/x.yaml: cannot read it on the robot PC"),
        ("x", {"x__type": FWD_PLUGIN}, {"joints": ["a"], "gain": 2.0}, "controllers.x.params.gain: unknown key"),
        ("x", {"x__type": FWD_PLUGIN}, {"joints": ["z"]}, "unknown joint 'z'"),
        ("x", {"x__type": "position_controllers/JointGroupPositionController"}, {"joints": ["a"]},
         "unknown controller type 'position_controllers/JointGroupPositionController'"),
        ("x", {"x__type": FWD_PLUGIN, "x__fallback_controllers": ["nope"]}, {"joints": ["a"]}, "nope"),
    ],
)  # fmt: skip
def test_a_load_hild_refuses_is_not_ok_and_the_event_says_why(
    ros_daemon: Daemon,
    peer: zenoh.Session,
    tmp_path: Path,
    name: str,
    manager: dict[str, object],
    file_params: dict[str, object] | None,
    reason: str,
) -> None:
    if file_params is not None:
        manager = {**manager, f"{name}__params_file": [params_file(tmp_path, name, file_params)]}
    if manager:
        on_manager(peer, **manager)
    before = {n: c.state for n, c in listed(peer).items()}
    assert not load(peer, name)
    refused(ros_daemon, "load_controller", reason)
    assert {n: c.state for n, c in listed(peer).items()} == before


def test_configure_names_a_loaded_controller_and_cleanup_takes_an_inactive_one_to_unconfigured(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    assert not configure(peer, "ghost")
    refused(ros_daemon, "configure_controller", "unknown controller 'ghost'")
    assert switch(peer, ["fwd"])
    assert not lifecycle(peer, "cleanup_controller", "CleanupController", name="fwd")
    refused(ros_daemon, "cleanup_controller", "'fwd' is active: it cannot be cleaned up (deactivate it first)")
    # `ros2 control set_controller_state fwd unconfigured`: deactivate (a switch), then cleanup
    assert switch(peer, [], deactivate=("fwd",))
    assert lifecycle(peer, "cleanup_controller", "CleanupController", name="fwd")
    assert listed(peer)["fwd"].state == "unconfigured"
    wait_for(lambda: ros_daemon.events_with("cleaned up fwd: unconfigured"))
    assert configure(peer, "fwd")  # and `set_controller_state fwd inactive` brings it back
    assert listed(peer)["fwd"].state == "inactive"


def test_reload_controller_libraries_rebuilds_every_controller_from_the_config_file(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    assert switch(peer, ["fwd"])
    assert not reload_libraries(peer, force_kill=False)  # jsb (autostart) and fwd are active
    refused(ros_daemon, "reload_controller_libraries", "active controllers (jsb, fwd): deactivate them first")
    path = Path(ros_daemon.engine.loaded.path)
    config = yaml.safe_load(path.read_text())
    config["controllers"]["fwd_a"]["params"]["joints"] = ["c"]
    path.write_text(yaml.safe_dump(config, sort_keys=False))

    assert reload_libraries(peer, force_kill=True)  # deactivates them first, as ros2_control does
    states = listed(peer)
    assert {n: c.state for n, c in states.items()} == {n: "inactive" for n in ("jsb", "fwd", "fwd_a", "traj")}
    assert list(states["fwd_a"].required_command_interfaces) == ["c/position"]
    wait_for(lambda: ros_daemon.events_with(f"reloaded fwd_a (forward_command) from {path}"), what="the reload")

    engine = ros_daemon.engine
    on_cycle(ros_daemon, lambda: engine.load_controller("late", "forward_command", {"joints": ["b"]}))
    wait_for(lambda: "late" in listed(peer), what="late listed")
    assert not reload_libraries(peer, force_kill=False)  # late is not in the file: it stays as it is
    refused(ros_daemon, "reload_controller_libraries", "not reloaded: late: ")
    assert listed(peer)["late"].state == "inactive"


def test_list_controller_types_under_the_plugin_names_list_controllers_reports(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    reply = ask(peer, "/controller_manager/list_controller_types", f"{CM}/ListControllerTypes")
    kinds = list(reply.types)
    assert {
        FWD_PLUGIN,
        "joint_state_broadcaster/JointStateBroadcaster",
        "joint_trajectory_controller/JointTrajectoryController",
        "hild/servo",
    } <= set(kinds)
    assert list(reply.base_classes) == ["controller_interface::ControllerInterface"] * len(kinds)
    assert {c.type for c in listed(peer).values()} <= set(kinds)  # every listed type can be loaded by that name
