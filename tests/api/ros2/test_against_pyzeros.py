"""End to end against an independent rmw_zenoh client: pyzeros (pure Python, its own CDR, keys, tokens and RIHS01,
none of hild's code) subscribes to ``/joint_states`` and calls ``list_controllers`` and ``switch_controller``.

controller_manager_msgs are not in pyzeros' message set: they are declared here in its own IDL dataclasses from
ros2_control 4.46.0's .msg/.srv files (released/ros2_control-4.46.0, Jazzy's current release), so the service
hashes in the keys are computed by pyzeros' algorithm — a second implementation. A hash that differed from hild's
would be a different key: the calls would time out.
Skipped only when the ros2-verify extra is not installed.
"""

import asyncio
import shutil
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml
import zenoh

pyzeros = pytest.importorskip("pyzeros", reason="the ros2-verify extra (pyzeros) is not installed")

import asyncio_for_robotics as afor  # noqa: E402
from ros2_pyterfaces.cyclone import idl  # noqa: E402
from ros2_pyterfaces.cyclone.builtin_interfaces.msg import Duration, Time  # noqa: E402
from ros2_pyterfaces.cyclone.geometry_msgs.msg import WrenchStamped  # noqa: E402
from ros2_pyterfaces.cyclone.rosgraph_msgs.msg import Clock  # noqa: E402
from ros2_pyterfaces.cyclone.sensor_msgs.msg import JointState  # noqa: E402
from ros2_pyterfaces.cyclone.service_msgs.msg import ServiceEventInfo  # noqa: E402
from ros2_pyterfaces.cyclone.std_msgs.msg import Header  # noqa: E402
from ros2_pyterfaces.cyclone.trajectory_msgs.msg import (  # noqa: E402
    JointTrajectory,
    JointTrajectoryPoint,
    MultiDOFJointTrajectory,
    MultiDOFJointTrajectoryPoint,
)
from ros2_pyterfaces.cyclone.unique_identifier_msgs.msg import UUID  # noqa: E402

from hild.api.ros2 import types  # noqa: E402
from hild.config import load_config  # noqa: E402
from hild.cycle.engine import Engine  # noqa: E402
from tests.api.conftest import WAIT, Daemon  # noqa: E402
from tests.api.ros2.conftest import peer_config, running  # noqa: E402
from tests.conftest import CONFIGS  # noqa: E402

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
    is_async: bool = False
    update_rate: T.uint16 = 0
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
    message: str = ""


@dataclass
class SwitchController_Event(idl.IdlStruct, typename="controller_manager_msgs/srv/SwitchController_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[SwitchController_Request, 1] = field(default_factory=list)
    response: T.sequence[SwitchController_Response, 1] = field(default_factory=list)


# control_msgs/action/FollowJointTrajectory (control_msgs 5.x, jazzy) and action_msgs/srv/CancelGoal, written
# from their .action/.srv files in pyzeros' IDL: rosidl's derived types, by hand.
FJT = "control_msgs/action/FollowJointTrajectory"


@dataclass
class JointTolerance(idl.IdlStruct, typename="control_msgs/msg/JointTolerance"):
    name: str = ""
    position: T.float64 = 0.0
    velocity: T.float64 = 0.0
    acceleration: T.float64 = 0.0


@dataclass
class JointComponentTolerance(idl.IdlStruct, typename="control_msgs/msg/JointComponentTolerance"):
    joint_name: str = ""
    component: T.uint16 = 0
    position: T.float64 = 0.0
    velocity: T.float64 = 0.0
    acceleration: T.float64 = 0.0


@dataclass
class Goal(idl.IdlStruct, typename=f"{FJT}_Goal"):
    trajectory: JointTrajectory = field(default_factory=JointTrajectory)
    multi_dof_trajectory: MultiDOFJointTrajectory = field(default_factory=MultiDOFJointTrajectory)
    path_tolerance: T.sequence[JointTolerance] = field(default_factory=list)
    component_path_tolerance: T.sequence[JointComponentTolerance] = field(default_factory=list)
    goal_tolerance: T.sequence[JointTolerance] = field(default_factory=list)
    component_goal_tolerance: T.sequence[JointComponentTolerance] = field(default_factory=list)
    goal_time_tolerance: Duration = field(default_factory=Duration)


@dataclass
class Result(idl.IdlStruct, typename=f"{FJT}_Result"):
    error_code: T.int32 = 0
    error_string: str = ""


@dataclass
class Feedback(idl.IdlStruct, typename=f"{FJT}_Feedback"):
    header: Header = field(default_factory=Header)
    joint_names: T.sequence[str] = field(default_factory=list)
    desired: JointTrajectoryPoint = field(default_factory=JointTrajectoryPoint)
    actual: JointTrajectoryPoint = field(default_factory=JointTrajectoryPoint)
    error: JointTrajectoryPoint = field(default_factory=JointTrajectoryPoint)
    multi_dof_joint_names: T.sequence[str] = field(default_factory=list)
    multi_dof_desired: MultiDOFJointTrajectoryPoint = field(default_factory=MultiDOFJointTrajectoryPoint)
    multi_dof_actual: MultiDOFJointTrajectoryPoint = field(default_factory=MultiDOFJointTrajectoryPoint)
    multi_dof_error: MultiDOFJointTrajectoryPoint = field(default_factory=MultiDOFJointTrajectoryPoint)


@dataclass
class FeedbackMessage(idl.IdlStruct, typename=f"{FJT}_FeedbackMessage"):
    goal_id: UUID = field(default_factory=UUID)
    feedback: Feedback = field(default_factory=Feedback)


@dataclass
class SendGoal_Request(idl.IdlStruct, typename=f"{FJT}_SendGoal_Request"):
    goal_id: UUID = field(default_factory=UUID)
    goal: Goal = field(default_factory=Goal)


@dataclass
class SendGoal_Response(idl.IdlStruct, typename=f"{FJT}_SendGoal_Response"):
    accepted: bool = False
    stamp: Time = field(default_factory=Time)


@dataclass
class SendGoal_Event(idl.IdlStruct, typename=f"{FJT}_SendGoal_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[SendGoal_Request, 1] = field(default_factory=list)
    response: T.sequence[SendGoal_Response, 1] = field(default_factory=list)


@dataclass
class GetResult_Request(idl.IdlStruct, typename=f"{FJT}_GetResult_Request"):
    goal_id: UUID = field(default_factory=UUID)


@dataclass
class GetResult_Response(idl.IdlStruct, typename=f"{FJT}_GetResult_Response"):
    status: T.int8 = 0
    result: Result = field(default_factory=Result)


@dataclass
class GetResult_Event(idl.IdlStruct, typename=f"{FJT}_GetResult_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[GetResult_Request, 1] = field(default_factory=list)
    response: T.sequence[GetResult_Response, 1] = field(default_factory=list)


@dataclass
class GoalInfo(idl.IdlStruct, typename="action_msgs/msg/GoalInfo"):
    goal_id: UUID = field(default_factory=UUID)
    stamp: Time = field(default_factory=Time)


@dataclass
class CancelGoal_Request(idl.IdlStruct, typename="action_msgs/srv/CancelGoal_Request"):
    goal_info: GoalInfo = field(default_factory=GoalInfo)


@dataclass
class CancelGoal_Response(idl.IdlStruct, typename="action_msgs/srv/CancelGoal_Response"):
    return_code: T.int8 = 0
    goals_canceling: T.sequence[GoalInfo] = field(default_factory=list)


@dataclass
class CancelGoal_Event(idl.IdlStruct, typename="action_msgs/srv/CancelGoal_Event"):
    info: ServiceEventInfo = field(default_factory=ServiceEventInfo)
    request: T.sequence[CancelGoal_Request, 1] = field(default_factory=list)
    response: T.sequence[CancelGoal_Response, 1] = field(default_factory=list)


SendGoal = idl.make_idl_service(SendGoal_Request, SendGoal_Response, _event_type=SendGoal_Event)
GetResult = idl.make_idl_service(GetResult_Request, GetResult_Response, _event_type=GetResult_Event)
CancelGoal = idl.make_idl_service(CancelGoal_Request, CancelGoal_Response, _event_type=CancelGoal_Event)

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
    assert Clock.hash_rihs01() == types.type_hash("rosgraph_msgs/msg/Clock")
    assert WrenchStamped.hash_rihs01() == types.type_hash("geometry_msgs/msg/WrenchStamped")


def test_pyzeros_computes_the_same_action_hashes() -> None:
    """control_msgs' FollowJointTrajectory is on no PyPI index: its hashes are checked by agreement of two
    independent implementations (and the algorithm on ros-z's Fibonacci vectors, test_wire.py)."""
    assert SendGoal.hash_rihs01() == types.type_hash(f"{FJT}_SendGoal")
    assert GetResult.hash_rihs01() == types.type_hash(f"{FJT}_GetResult")
    assert FeedbackMessage.hash_rihs01() == types.type_hash(f"{FJT}_FeedbackMessage")
    assert CancelGoal.hash_rihs01() == types.type_hash("action_msgs/srv/CancelGoal")


async def _session(daemon: Daemon) -> dict[str, Any]:
    joint_states = pyzeros.Sub(JointState, "/joint_states")
    clock = pyzeros.Sub(Clock, "/clock")
    tick = await asyncio.wait_for(clock.wait_for_value(), WAIT)
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
    return {"state": state, "before": before, "switched": switched, "refused": refused, "after": after, "tick": tick}


def test_pyzeros_subscribes_lists_and_switches(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    @afor.scoped
    async def main() -> dict[str, Any]:
        return await _session(ros_daemon)

    with pyzeros.auto_context(node="pyzeros_probe", zenoh_session=peer, domain_id=0):
        got = asyncio.run(main())
    assert list(got["state"].name) == ["a", "b", "c"] and got["state"].header.frame_id == "base_link"
    sim_now = ros_daemon.engine.t  # lockstep: ROS time is the sim clock, on /clock and in every stamp
    for stamp in (got["tick"].clock, got["state"].header.stamp):
        assert 0.0 < stamp.sec + stamp.nanosec * 1e-9 <= sim_now + 1e-9  # ns rounding
    before = {c.name: c.state for c in got["before"].controller}
    assert before == {"jsb": "active", "fwd": "inactive", "fwd_a": "inactive", "traj": "inactive"}
    assert got["switched"].ok is True and got["refused"].ok is False
    assert got["switched"].message == "switched controllers: activated fwd; deactivated none"
    assert "unknown controller(s) 'nope'" in got["refused"].message
    claims = ["a/position", "b/position", "c/position"]
    fwd_before = next(c for c in got["before"].controller if c.name == "fwd")
    assert (list(fwd_before.claimed_interfaces), list(fwd_before.required_command_interfaces)) == ([], claims)
    assert (fwd_before.is_async, fwd_before.update_rate) == (False, 500)
    after = {c.name: (c.state, list(c.claimed_interfaces)) for c in got["after"].controller}
    assert after["fwd"] == ("active", claims)


async def _goal_session(
    target: list[float],
    controller: str = "traj",
    joints: tuple[str, ...] = ("a", "b", "c"),
    action: str = "follow_joint_trajectory",
) -> dict[str, Any]:
    base = f"/{controller}/{action}/_action"
    switching = pyzeros.Client(SwitchController, "/controller_manager/switch_controller")
    send_goal = pyzeros.Client(SendGoal, f"{base}/send_goal")
    get_result = pyzeros.Client(GetResult, f"{base}/get_result")
    cancel_goal = pyzeros.Client(CancelGoal, f"{base}/cancel_goal")
    feedback = pyzeros.Sub(FeedbackMessage, f"{base}/feedback")
    for client in (switching, send_goal, get_result, cancel_goal):
        await asyncio.wait_for(client.wait_for_service(), WAIT)
    switched = await asyncio.wait_for(
        switching.call_async(SwitchController_Request(activate_controllers=[controller], strictness=2)), WAIT
    )
    goal_id = UUID(uuid=bytes(range(1, 17)))
    points = [JointTrajectoryPoint(positions=target, time_from_start=Duration(sec=0, nanosec=600_000_000))]
    goal = Goal(trajectory=JointTrajectory(joint_names=list(joints), points=points))
    accepted = await asyncio.wait_for(send_goal.call_async(SendGoal_Request(goal_id=goal_id, goal=goal)), WAIT)
    first_feedback = await asyncio.wait_for(feedback.wait_for_value(), WAIT)
    result = await asyncio.wait_for(get_result.call_async(GetResult_Request(goal_id=goal_id)), WAIT)
    joint_states = pyzeros.Sub(JointState, "/joint_states")
    state = await asyncio.wait_for(joint_states.wait_for_value(), WAIT)
    late = await asyncio.wait_for(cancel_goal.call_async(CancelGoal_Request(goal_info=GoalInfo(goal_id=goal_id))), WAIT)
    return {
        "switched": switched,
        "accepted": accepted,
        "feedback": first_feedback,
        "result": result,
        "late": late,
        "state": state,
    }


def test_pyzeros_sends_a_follow_joint_trajectory_goal(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """The three action services and the feedback topic, from pyzeros, against the mock robot in lockstep."""
    target = [0.25, -0.1, 0.05]

    @afor.scoped
    async def main() -> dict[str, Any]:
        return await _goal_session(target)

    with pyzeros.auto_context(node="pyzeros_action_probe", zenoh_session=peer, domain_id=0):
        got = asyncio.run(main())
    assert got["switched"].ok and got["accepted"].accepted
    assert bytes(got["feedback"].goal_id.uuid) == bytes(range(1, 17))
    assert (got["result"].status, got["result"].result.error_code) == (4, 0)  # SUCCEEDED
    assert got["late"].return_code == 3  # GOAL_TERMINATED: nothing left to cancel
    position = ros_daemon.engine.state.position
    assert max(abs(p - t) for p, t in zip(position, target, strict=True)) < 0.02


@pytest.fixture
def twin_daemon(tmp_path: Path) -> Iterator[Daemon]:
    """configs/rrbot_twin.yaml (the MuJoCo twin, from its URDF) with a ros2 section, on the lockstep sim clock."""
    data = yaml.safe_load((CONFIGS / "rrbot_twin.yaml").read_text())
    data["ros2"] = {}
    data["clock"] = {"source": "sim", "real_time_factor": 0}
    shutil.copy(CONFIGS / "rrbot.urdf", tmp_path / "rrbot.urdf")
    path = tmp_path / "rrbot_twin.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with running(Engine(load_config(path))) as daemon:
        yield daemon


def test_pyzeros_drives_the_twin(twin_daemon: Daemon) -> None:
    """The rrbot twin (MuJoCo physics) in lockstep: a goal from pyzeros succeeds, and pyzeros' own /joint_states
    subscription then reads the arm at the target."""
    target = [0.4, -0.3]
    session = zenoh.open(peer_config(twin_daemon.endpoint))

    @afor.scoped
    async def main() -> dict[str, Any]:
        return await _goal_session(target, "joint_trajectory", ("joint1", "joint2"))

    try:
        with pyzeros.auto_context(node="pyzeros_twin_probe", zenoh_session=session, domain_id=0):
            got = asyncio.run(main())
    finally:
        session.close()
    assert got["accepted"].accepted and (got["result"].status, got["result"].result.error_code) == (4, 0)
    assert list(got["state"].name) == ["joint1", "joint2"]
    assert max(abs(p - t) for p, t in zip(got["state"].position, target, strict=True)) < 0.03


def test_pyzeros_computes_the_same_gid_from_a_token() -> None:
    from pyzeros.utils import rmw_zenoh_gid

    from hild.api.ros2 import wire

    token = wire.NodeInfo(0, "ab12", "/", "controller_manager").entity_token(
        3, wire.PUBLISHER, "/joint_states", "sensor_msgs/msg/JointState"
    )
    assert rmw_zenoh_gid(token) == wire.gid_of(token)
