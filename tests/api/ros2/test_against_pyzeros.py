"""End to end against an independent rmw_zenoh client: pyzeros (pure Python, its own CDR, keys, tokens and RIHS01,
none of hild's code) subscribes to ``/joint_states`` and calls ``list_controllers`` and ``switch_controller``.

controller_manager_msgs are not in pyzeros' message set: they are declared here in its own IDL dataclasses from
ros2_control 4.20.0's .msg/.srv files, so the service hashes in the keys are computed by pyzeros' algorithm — a
second implementation. A hash that differed from hild's would be a different key: the calls would time out.
Skipped only when the ros2-verify extra is not installed.
"""

import asyncio
from dataclasses import dataclass, field
from typing import Any

import pytest
import zenoh

pyzeros = pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")

import asyncio_for_robotics as afor  # noqa: E402
from ros2_pyterfaces.cyclone import idl  # noqa: E402
from ros2_pyterfaces.cyclone.builtin_interfaces.msg import Duration  # noqa: E402
from ros2_pyterfaces.cyclone.sensor_msgs.msg import JointState  # noqa: E402
from ros2_pyterfaces.cyclone.service_msgs.msg import ServiceEventInfo  # noqa: E402

from hild.api.ros2 import types  # noqa: E402
from tests.api.conftest import WAIT, Daemon  # noqa: E402

T = idl.types


@dataclass
class ChainConnection(idl.IdlStruct, typename="controller_manager_msgs/msg/ChainConnection"):
    name: str = ""
    reference_interfaces: T.sequence[str] = field(default_factory=list)


@dataclass
class ControllerState(idl.IdlStruct, typename="controller_manager_msgs/msg/ControllerState"):
    name: str = ""
    state: str = ""
    type: str = ""
    claimed_interfaces: T.sequence[str] = field(default_factory=list)
    required_command_interfaces: T.sequence[str] = field(default_factory=list)
    required_state_interfaces: T.sequence[str] = field(default_factory=list)
    is_chainable: bool = False
    is_chained: bool = False
    exported_state_interfaces: T.sequence[str] = field(default_factory=list)
    reference_interfaces: T.sequence[str] = field(default_factory=list)
    chain_connections: T.sequence[ChainConnection] = field(default_factory=list)


@dataclass
class ListControllers_Request(idl.IdlStruct, typename="controller_manager_msgs/srv/ListControllers_Request"):
    pass


@dataclass
class ListControllers_Response(idl.IdlStruct, typename="controller_manager_msgs/srv/ListControllers_Response"):
    controller: T.sequence[ControllerState] = field(default_factory=list)


@dataclass
class ListControllers_Event(idl.IdlStruct, typename="controller_manager_msgs/srv/ListControllers_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[ListControllers_Request, 1] = field(default_factory=list)
    response: T.sequence[ListControllers_Response, 1] = field(default_factory=list)


@dataclass
class SwitchController_Request(idl.IdlStruct, typename="controller_manager_msgs/srv/SwitchController_Request"):
    activate_controllers: T.sequence[str] = field(default_factory=list)
    deactivate_controllers: T.sequence[str] = field(default_factory=list)
    strictness: T.int32 = 0
    activate_asap: bool = False
    timeout: Duration = field(default_factory=Duration)


@dataclass
class SwitchController_Response(idl.IdlStruct, typename="controller_manager_msgs/srv/SwitchController_Response"):
    ok: bool = False


@dataclass
class SwitchController_Event(idl.IdlStruct, typename="controller_manager_msgs/srv/SwitchController_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[SwitchController_Request, 1] = field(default_factory=list)
    response: T.sequence[SwitchController_Response, 1] = field(default_factory=list)


ListControllers = idl.make_idl_service(
    ListControllers_Request, ListControllers_Response, _event_type=ListControllers_Event
)
SwitchController = idl.make_idl_service(
    SwitchController_Request, SwitchController_Response, _event_type=SwitchController_Event
)


def test_pyzeros_computes_the_same_service_hashes() -> None:
    assert ListControllers.hash_rihs01() == types.type_hash("controller_manager_msgs/srv/ListControllers")
    assert SwitchController.hash_rihs01() == types.type_hash("controller_manager_msgs/srv/SwitchController")
    assert JointState.hash_rihs01() == types.type_hash("sensor_msgs/msg/JointState")


async def _session(daemon: Daemon) -> dict[str, Any]:
    joint_states = pyzeros.Sub(JointState, "/joint_states")
    listing = pyzeros.Client(ListControllers, "/controller_manager/list_controllers")
    switching = pyzeros.Client(SwitchController, "/controller_manager/switch_controller")
    state = await asyncio.wait_for(joint_states.wait_for_value(), WAIT)
    await asyncio.wait_for(listing.wait_for_service(), WAIT)
    before = await asyncio.wait_for(listing.call_async(ListControllers_Request()), WAIT)
    await asyncio.wait_for(switching.wait_for_service(), WAIT)
    request = SwitchController_Request(activate_controllers=["fwd"], strictness=2)
    switched = await asyncio.wait_for(switching.call_async(request), WAIT)
    refused = await asyncio.wait_for(
        switching.call_async(SwitchController_Request(activate_controllers=["nope"], strictness=2)), WAIT
    )
    after = await asyncio.wait_for(listing.call_async(ListControllers_Request()), WAIT)
    return {"state": state, "before": before, "switched": switched, "refused": refused, "after": after}


def test_pyzeros_subscribes_lists_and_switches(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    @afor.scoped
    async def main() -> dict[str, Any]:
        return await _session(ros_daemon)

    with pyzeros.auto_context(node="pyzeros_probe", zenoh_session=peer, domain_id=0):
        got = asyncio.run(main())
    assert list(got["state"].name) == ["a", "b", "c"]
    before = {c.name: c.state for c in got["before"].controller}
    assert before == {"jsb": "active", "fwd": "inactive", "fwd_a": "inactive", "traj": "inactive"}
    assert got["switched"].ok is True and got["refused"].ok is False
    after = {c.name: (c.state, list(c.claimed_interfaces)) for c in got["after"].controller}
    assert after["fwd"] == ("active", ["a/position", "b/position", "c/position"])
