"""parallel_gripper's ``gripper_cmd`` action over rmw_zenoh: ParallelGripperCommand from pyzeros (an independent
rmw_zenoh client with its own CDR and hashes), and GripperCommand (MoveIt's) from a bare Zenoh peer with hild's
types. Both against the gripper rig in lockstep: closing on the box stalls, the result says so."""

import asyncio
import shutil
import uuid as uuidlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
import zenoh

from hild.api.ros2 import types
from hild.config import load_config
from hild.cycle.engine import Engine
from tests.api.conftest import WAIT, Daemon, running
from tests.api.ros2.conftest import call, peer_config, request
from tests.api.ros2.test_face import switch
from tests.controllers.test_parallel_gripper import BOX_HALF_WIDTH, RIG, rig_config

m = types.message
PARALLEL = "control_msgs/action/ParallelGripperCommand"
GRIPPER = "control_msgs/action/GripperCommand"
BASE = "/gripper/gripper_cmd/_action"


def rig_daemon(tmp_path: Path, ros_action: str) -> Iterator[Daemon]:
    shutil.copy(RIG, tmp_path / "rig.xml")
    config = rig_config({"ros_action": ros_action})
    config["ros2"] = {"domain_id": 0, "namespace": "/"}
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    with running(Engine(load_config(path))) as daemon:
        yield daemon


@pytest.fixture
def parallel_daemon(tmp_path: Path) -> Iterator[Daemon]:
    yield from rig_daemon(tmp_path, "parallel_gripper_command")


@pytest.fixture
def gripper_command_daemon(tmp_path: Path) -> Iterator[Daemon]:
    yield from rig_daemon(tmp_path, "gripper_command")


def uuid_msg(raw: bytes) -> Any:
    return m("unique_identifier_msgs/msg/UUID", uuid=np.frombuffer(raw, dtype=np.uint8).copy())


def send(peer: zenoh.Session, action: str, raw_id: bytes, goal: Any) -> bool:
    name = f"{action}_SendGoal"
    reply = call(peer, f"{BASE}/send_goal", name, request(name, goal_id=uuid_msg(raw_id), goal=goal))
    assert reply.ok is not None
    return bool(types.decode(reply.ok.payload.to_bytes(), f"{name}_Response").accepted)


def result(peer: zenoh.Session, action: str, raw_id: bytes) -> Any:
    name = f"{action}_GetResult"
    reply = call(peer, f"{BASE}/get_result", name, request(name, goal_id=uuid_msg(raw_id)))
    assert reply.ok is not None
    return types.decode(reply.ok.payload.to_bytes(), f"{name}_Response")


def gripper_command(position: float, max_effort: float) -> Any:
    command = m("control_msgs/msg/GripperCommand", position=position, max_effort=max_effort)
    return m(f"{GRIPPER}_Goal", command=command)


def test_gripper_command_closes_on_the_box_and_opens(gripper_command_daemon: Daemon) -> None:
    peer = zenoh.open(peer_config(gripper_command_daemon.endpoint))
    try:
        assert switch(peer, ["gripper"])
        closing = uuidlib.uuid4().bytes
        assert send(peer, GRIPPER, closing, gripper_command(0.0, 8.0))
        done = result(peer, GRIPPER, closing)
        assert done.status == 4  # SUCCEEDED: allow_stalling
        assert done.result.stalled and not done.result.reached_goal
        assert done.result.position == pytest.approx(BOX_HALF_WIDTH, abs=0.002)
        assert -done.result.effort == pytest.approx(8.0, rel=0.15)
        opening = uuidlib.uuid4().bytes
        assert send(peer, GRIPPER, opening, gripper_command(0.04, 0.0))  # 0: the controller's max_effort
        done = result(peer, GRIPPER, opening)
        assert done.status == 4 and done.result.reached_goal and not done.result.stalled
        refused = uuidlib.uuid4().bytes
        assert not send(peer, GRIPPER, refused, gripper_command(0.5, 5.0))  # outside the finger's range
        assert result(peer, GRIPPER, refused).status == 0  # UNKNOWN: never accepted
        assert gripper_command_daemon.events_with("outside finger's soft range")
    finally:
        peer.close()


pyzeros = pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")

import asyncio_for_robotics as afor  # noqa: E402
from ros2_pyterfaces.cyclone import idl  # noqa: E402
from ros2_pyterfaces.cyclone.builtin_interfaces.msg import Time  # noqa: E402
from ros2_pyterfaces.cyclone.sensor_msgs.msg import JointState  # noqa: E402
from ros2_pyterfaces.cyclone.service_msgs.msg import ServiceEventInfo  # noqa: E402
from ros2_pyterfaces.cyclone.unique_identifier_msgs.msg import UUID  # noqa: E402

from tests.api.ros2.test_against_pyzeros import (  # noqa: E402
    SwitchController,
    SwitchController_Request,
)

T = idl.types


# control_msgs/action/ParallelGripperCommand (control_msgs 5.8.0, jazzy), written from its .action file in
# pyzeros' IDL: rosidl's derived types, by hand.
@dataclass
class Goal(idl.IdlStruct, typename=f"{PARALLEL}_Goal"):
    command: JointState = field(default_factory=JointState)


@dataclass
class Result(idl.IdlStruct, typename=f"{PARALLEL}_Result"):
    state: JointState = field(default_factory=JointState)
    stalled: bool = False
    reached_goal: bool = False


@dataclass
class Feedback(idl.IdlStruct, typename=f"{PARALLEL}_Feedback"):
    state: JointState = field(default_factory=JointState)


@dataclass
class FeedbackMessage(idl.IdlStruct, typename=f"{PARALLEL}_FeedbackMessage"):
    goal_id: UUID = field(default_factory=UUID)
    feedback: Feedback = field(default_factory=Feedback)


@dataclass
class SendGoal_Request(idl.IdlStruct, typename=f"{PARALLEL}_SendGoal_Request"):
    goal_id: UUID = field(default_factory=UUID)
    goal: Goal = field(default_factory=Goal)


@dataclass
class SendGoal_Response(idl.IdlStruct, typename=f"{PARALLEL}_SendGoal_Response"):
    accepted: bool = False
    stamp: Time = field(default_factory=Time)


@dataclass
class SendGoal_Event(idl.IdlStruct, typename=f"{PARALLEL}_SendGoal_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[SendGoal_Request, 1] = field(default_factory=list)
    response: T.sequence[SendGoal_Response, 1] = field(default_factory=list)


SendGoal = idl.make_idl_service(SendGoal_Request, SendGoal_Response, _event_type=SendGoal_Event)


@dataclass
class GetResult_Request(idl.IdlStruct, typename=f"{PARALLEL}_GetResult_Request"):
    goal_id: UUID = field(default_factory=UUID)


@dataclass
class GetResult_Response(idl.IdlStruct, typename=f"{PARALLEL}_GetResult_Response"):
    status: T.int8 = 0
    result: Result = field(default_factory=Result)


@dataclass
class GetResult_Event(idl.IdlStruct, typename=f"{PARALLEL}_GetResult_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[GetResult_Request, 1] = field(default_factory=list)
    response: T.sequence[GetResult_Response, 1] = field(default_factory=list)


GetResult = idl.make_idl_service(GetResult_Request, GetResult_Response, _event_type=GetResult_Event)


def test_pyzeros_computes_the_same_parallel_gripper_hashes() -> None:
    assert SendGoal.hash_rihs01() == types.type_hash(f"{PARALLEL}_SendGoal")
    assert GetResult.hash_rihs01() == types.type_hash(f"{PARALLEL}_GetResult")
    assert FeedbackMessage.hash_rihs01() == types.type_hash(f"{PARALLEL}_FeedbackMessage")


async def grasp(
    position: float, effort: float, velocity: float = 0.05, controller: str = "gripper", joint: str = "finger"
) -> dict[str, Any]:
    """From pyzeros: activate ``controller``, send a ParallelGripperCommand goal, take the first feedback and the
    result (get_result answers when the goal has ended)."""
    base = f"/{controller}/gripper_cmd/_action"
    switching = pyzeros.Client(SwitchController, "/controller_manager/switch_controller")
    send_goal = pyzeros.Client(SendGoal, f"{base}/send_goal")
    get_result = pyzeros.Client(GetResult, f"{base}/get_result")
    feedback = pyzeros.Sub(FeedbackMessage, f"{base}/feedback")
    for client in (switching, send_goal, get_result):
        await asyncio.wait_for(client.wait_for_service(), WAIT)
    request_ = SwitchController_Request(activate_controllers=[controller], strictness=2)
    switched = await asyncio.wait_for(switching.call_async(request_), WAIT)
    goal_id = UUID(uuid=bytes(range(1, 17)))
    command = JointState(name=[joint], position=[position], velocity=[velocity], effort=[effort])
    accepted = await asyncio.wait_for(send_goal.call_async(SendGoal_Request(goal_id=goal_id, goal=Goal(command))), WAIT)
    first_feedback = await asyncio.wait_for(feedback.wait_for_value(), WAIT)
    done = await asyncio.wait_for(get_result.call_async(GetResult_Request(goal_id=goal_id)), WAIT)
    return {"switched": switched, "accepted": accepted, "feedback": first_feedback, "result": done}


def grasp_from_pyzeros(daemon: Daemon, node: str, *goal: Any) -> dict[str, Any]:
    """:func:`grasp` (``goal``: its arguments) as a pyzeros node ``node`` on a session of its own to ``daemon``."""
    session = zenoh.open(peer_config(daemon.endpoint))

    @afor.scoped
    async def main() -> dict[str, Any]:
        return await grasp(*goal)

    try:
        with pyzeros.auto_context(node=node, zenoh_session=session, domain_id=0):
            return asyncio.run(main())
    finally:
        session.close()


def test_pyzeros_closes_the_gripper_on_the_box(parallel_daemon: Daemon) -> None:
    got = grasp_from_pyzeros(parallel_daemon, "pyzeros_gripper_probe", 0.0, 6.0)
    assert got["switched"].ok and got["accepted"].accepted
    assert list(got["feedback"].feedback.state.name) == ["finger"]
    done = got["result"]
    assert done.status == 4 and done.result.stalled and not done.result.reached_goal
    assert list(done.result.state.name) == ["finger"]
    assert done.result.state.position[0] == pytest.approx(BOX_HALF_WIDTH, abs=0.002)
    assert -done.result.state.effort[0] == pytest.approx(6.0, rel=0.15)
    finger = parallel_daemon.engine.joints.index("finger")
    assert -parallel_daemon.engine.state.effort[finger] == pytest.approx(6.0, rel=0.15)  # still pressing
