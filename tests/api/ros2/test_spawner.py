"""The exact sequence of calls ros2_control 4.46.0's spawner and `ros2 control load_controller FILE --set-state
active` make (controller_manager/spawner.py, controller_manager_services.py, ros2controlcli's load_controller.py),
replayed by pyzeros as an rmw_zenoh client (its own CDR, keys and hashes) against the daemon; the controller ends
active, built from the params file.

The sequence, per controller:
1. ``list_controllers``: loaded already? (then no load)
2. ``set_controller_parameters_from_param_files``: the files holding the controller's section; then one
   ``SetParameters`` call each on ``/controller_manager/set_parameters`` — ``<c>.params_file``, ``<c>.type`` (read
   from the section), ``<c>.fallback_controllers`` (if the section has them) — each value built by rclpy's
   ``get_parameter_value(str(value))`` exactly as ``set_controller_parameters`` does, and before each call rclpy's
   parameter client waits for all six parameter services of ``/controller_manager``;
3. ``load_controller {c}``; 4. ``configure_controller {c}``;
5. ``switch_controller`` activating ``[c]``: the spawner with STRICT (2), ``activate_asap`` (its ``--switch-asap``
   default) and a 5 s timeout; the CLI with ``strictness=True`` (BEST_EFFORT, 1), ``activate_asap`` and 5 s.
"""

# No ``from __future__ import annotations``: pyzeros' IDL (cyclonedds_idl) builds its serializers from the dataclasses'
# real annotations; with string annotations the request classes defined here cannot serialize.
import asyncio
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml
import zenoh

pyzeros = pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")
rclpy_parameter = pytest.importorskip("rclpy.parameter", reason="the ros2-verify extra (rclpy) is not installed")

import asyncio_for_robotics as afor  # noqa: E402
from ros2_pyterfaces.cyclone import idl  # noqa: E402
from ros2_pyterfaces.cyclone.builtin_interfaces.msg import Duration  # noqa: E402
from ros2_pyterfaces.cyclone.rcl_interfaces import srv as rcl  # noqa: E402
from ros2_pyterfaces.cyclone.rcl_interfaces.msg import Parameter, ParameterValue  # noqa: E402

from hild.api.ros2 import types  # noqa: E402
from tests.api.conftest import WAIT, Daemon  # noqa: E402
from tests.api.ros2.test_against_pyzeros import (  # noqa: E402
    ListControllers,
    ListControllers_Request,
    SwitchController,
    SwitchController_Request,
)

CM = "/controller_manager"
STRICT, BEST_EFFORT = 2, 1
PARAMETER_SERVICES = {
    "list_parameters": rcl.ListParameters,
    "get_parameters": rcl.GetParameters,
    "set_parameters": rcl.SetParameters,
    "set_parameters_atomically": rcl.SetParametersAtomically,
    "describe_parameters": rcl.DescribeParameters,
    "get_parameter_types": rcl.GetParameterTypes,
}


@dataclass
class LoadController_Request(idl.IdlStruct, typename="controller_manager_msgs/srv/LoadController_Request"):
    name: str = ""


@dataclass
class LoadController_Response(idl.IdlStruct, typename="controller_manager_msgs/srv/LoadController_Response"):
    ok: bool = False


@dataclass
class ConfigureController_Request(idl.IdlStruct, typename="controller_manager_msgs/srv/ConfigureController_Request"):
    name: str = ""


@dataclass
class ConfigureController_Response(idl.IdlStruct, typename="controller_manager_msgs/srv/ConfigureController_Response"):
    ok: bool = False


LoadController = idl.make_idl_service(LoadController_Request, LoadController_Response)
ConfigureController = idl.make_idl_service(ConfigureController_Request, ConfigureController_Response)


def test_pyzeros_computes_the_same_hashes_for_the_services_the_spawner_calls() -> None:
    assert LoadController.hash_rihs01() == types.type_hash("controller_manager_msgs/srv/LoadController")
    assert ConfigureController.hash_rihs01() == types.type_hash("controller_manager_msgs/srv/ConfigureController")
    for short, service in PARAMETER_SERVICES.items():
        name = "".join(part.title() for part in short.split("_"))
        assert service.hash_rihs01() == types.type_hash(f"rcl_interfaces/srv/{name}"), short


def spawner_value(value: Any) -> ParameterValue:
    """``set_controller_parameters``' value: rclpy's ``get_parameter_value(string_value=str(value))``, as pyzeros'
    message."""
    ros = rclpy_parameter.get_parameter_value(string_value=str(value))
    return ParameterValue(
        type=ros.type,
        bool_value=ros.bool_value,
        integer_value=ros.integer_value,
        double_value=ros.double_value,
        string_value=ros.string_value,
        bool_array_value=list(ros.bool_array_value),
        integer_array_value=list(ros.integer_array_value),
        double_array_value=list(ros.double_array_value),
        string_array_value=list(ros.string_array_value),
    )


def section_value(files: list[str], controller: str, key: str) -> Any:
    """``get_parameter_from_param_files`` for a file keyed by the controller's plain name."""
    for path in files:
        section = yaml.safe_load(Path(path).read_text()).get(controller) or {}
        if key in section.get("ros__parameters", {}):
            return section["ros__parameters"][key]
    return None


@dataclass
class Replay:
    """What each call of the sequence got back."""

    calls: list[tuple[str, Any]] = field(default_factory=list)

    def ok(self) -> bool:
        return all(getattr(reply, "ok", True) for _, reply in self.calls)


async def spawn(controller: str, files: list[str], strictness: int) -> Replay:
    replay = Replay()
    listing = pyzeros.Client(ListControllers, f"{CM}/list_controllers")
    await asyncio.wait_for(listing.wait_for_service(), WAIT)
    listed = await asyncio.wait_for(listing.call_async(ListControllers_Request()), WAIT)
    replay.calls.append(("list_controllers", listed))
    assert controller not in {c.name for c in listed.controller}  # so the spawner loads it

    parameters = {short: pyzeros.Client(kind, f"{CM}/{short}") for short, kind in PARAMETER_SERVICES.items()}
    values = [("params_file", files), ("type", section_value(files, controller, "type"))]
    fallbacks = section_value(files, controller, "fallback_controllers")
    if fallbacks:
        values.append(("fallback_controllers", fallbacks))
    for key, value in values:
        for client in parameters.values():  # AsyncParameterClient.wait_for_services: all six, or it fails
            await asyncio.wait_for(client.wait_for_service(), WAIT)
        request = rcl.SetParameters_Request(
            parameters=[Parameter(name=f"{controller}.{key}", value=spawner_value(value))]
        )
        reply = await asyncio.wait_for(parameters["set_parameters"].call_async(request), WAIT)
        assert len(reply.results) == 1 and reply.results[0].successful, (key, reply.results[0].reason)
        replay.calls.append((f"set {key}", reply.results[0]))

    load = pyzeros.Client(LoadController, f"{CM}/load_controller")
    configure = pyzeros.Client(ConfigureController, f"{CM}/configure_controller")
    switching = pyzeros.Client(SwitchController, f"{CM}/switch_controller")
    for client in (load, configure, switching):
        await asyncio.wait_for(client.wait_for_service(), WAIT)
    replay.calls.append(
        ("load", await asyncio.wait_for(load.call_async(LoadController_Request(name=controller)), WAIT))
    )
    configured = await asyncio.wait_for(configure.call_async(ConfigureController_Request(name=controller)), WAIT)
    replay.calls.append(("configure", configured))
    activate = SwitchController_Request(
        activate_controllers=[controller], strictness=strictness, activate_asap=True, timeout=Duration(sec=5)
    )
    replay.calls.append(("switch", await asyncio.wait_for(switching.call_async(activate), WAIT)))
    replay.calls.append(("listed", await asyncio.wait_for(listing.call_async(ListControllers_Request()), WAIT)))
    return replay


def params_file(tmp_path: Path, controller: str) -> str:
    path = tmp_path / "spawned_controllers.yaml"
    path.write_text(
        f"""
/**:
  ros__parameters:
    use_sim_time: false
{controller}:
  ros__parameters:
    type: forward_command_controller/ForwardCommandController
    joints: [b, c]
    interface: position
    command_timeout: 0.3
    fallback_controllers: [fwd_a]
"""
    )
    return str(path)


@pytest.mark.parametrize(
    ("who", "strictness"),
    [("spawner", STRICT), ("ros2 control load_controller --set-state active", BEST_EFFORT)],
)
def test_the_spawners_sequence_ends_with_the_controller_active(
    ros_daemon: Daemon, peer: zenoh.Session, tmp_path: Path, who: str, strictness: int
) -> None:
    controller = "spawned"

    @afor.scoped
    async def main() -> Replay:
        return await spawn(controller, [params_file(tmp_path, controller)], strictness)

    with pyzeros.auto_context(node=f"spawner_{controller}", zenoh_session=peer, domain_id=0):
        replay = asyncio.run(main())
    assert [name for name, _ in replay.calls] == [
        "list_controllers",
        "set params_file",
        "set type",
        "set fallback_controllers",
        "load",
        "configure",
        "switch",
        "listed",
    ]
    assert replay.ok(), replay.calls
    final = {c.name: c for c in replay.calls[-1][1].controller}
    spawned = final[controller]
    assert (spawned.state, spawned.type) == ("active", "forward_command_controller/ForwardCommandController")
    assert list(spawned.claimed_interfaces) == ["b/position", "c/position"]
    record = ros_daemon.engine.manager.records[controller]
    assert record.instance.params.command_timeout == 0.3  # the params file's section, read on the robot PC
    assert record.fallbacks == ("fwd_a",)
