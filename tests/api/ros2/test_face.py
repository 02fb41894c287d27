"""The ROS 2 face against a bare Zenoh peer speaking rmw_zenoh's bytes: what is offered, and bad input refused."""

from __future__ import annotations

import itertools
import threading
from typing import Any

import numpy as np
import zenoh
import zenoh.ext

from hild.api.ros2 import types, wire
from tests.api.conftest import WAIT, Daemon
from tests.api.ros2.conftest import CLIENT_GID, URDF, call, request
from tests.helpers import wait_for

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
LIST = "controller_manager_msgs/srv/ListControllers"
SWITCH = "controller_manager_msgs/srv/SwitchController"
CLOCK = "rosgraph_msgs/msg/Clock"


class Inbox:
    def __init__(self) -> None:
        self.samples: list[zenoh.Sample] = []
        self.lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.samples.append(sample)

    def __len__(self) -> int:
        with self.lock:
            return len(self.samples)

    def last(self) -> zenoh.Sample:
        with self.lock:
            return self.samples[-1]


def test_joint_states_are_cdr_with_rmw_zenoh_attachment(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    inbox = Inbox()
    sub = peer.declare_subscriber(wire.data_key(0, "/joint_states", JOINT_STATE), inbox)
    wait_for(lambda: len(inbox) >= 3, what="three joint states")
    sample = inbox.last()
    msg = types.decode(sample.payload.to_bytes(), JOINT_STATE)
    assert list(msg.name) == ["a", "b", "c"]
    assert msg.header.frame_id == "base_link"  # joint_state_broadcaster's default frame_id
    np.testing.assert_allclose(msg.position, [0.1, -0.1, 0.0], atol=1e-6)  # b: reduction 2
    assert sample.attachment is not None
    meta = wire.parse_attachment(sample.attachment.to_bytes())
    seqs = [wire.parse_attachment(s.attachment.to_bytes()).sequence for s in inbox.samples[:3]]
    assert seqs == sorted(seqs) and len(set(seqs)) == 3 and meta.stamp_ns > 0
    sub.undeclare()


def test_liveliness_tokens_put_the_node_in_the_ros_graph(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    keys = [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**", timeout=WAIT) if r.ok is not None]
    zid = str(ros_daemon.server.session.info.zid())  # type: ignore[union-attr]
    assert f"@ros2_lv/0/{zid}/0/0/NN/%/%/controller_manager" in keys
    entities = {(k.split("/")[5], k.split("/")[9]) for k in keys if k.count("/") > 9}
    assert {
        ("MP", "%joint_states"),
        ("MP", "%robot_description"),
        ("MS", "%fwd%commands"),
        ("MS", "%fwd_a%commands"),
        ("SS", "%controller_manager%list_controllers"),
        ("SS", "%controller_manager%switch_controller"),
    } <= entities
    description = next(k for k in keys if "%robot_description" in k)
    assert description.endswith("/:1:,1:,:,:,,")  # transient local, depth 1


def test_list_controllers_answers_with_the_controllers_and_echoes_the_attachment(
    ros_daemon: Daemon, peer: zenoh.Session
) -> None:
    reply = call(peer, "/controller_manager/list_controllers", LIST, request(LIST), sequence=41)
    assert reply.ok is not None
    response = types.decode(reply.ok.payload.to_bytes(), f"{LIST}_Response")
    states = {c.name: (c.state, c.type) for c in response.controller}
    assert states["jsb"] == ("active", "joint_state_broadcaster/JointStateBroadcaster")
    assert states["fwd"] == ("inactive", "forward_command_controller/ForwardCommandController")
    meta = wire.parse_attachment(reply.ok.attachment.to_bytes())  # type: ignore[union-attr]
    assert (meta.sequence, meta.gid) == (41, CLIENT_GID)


def switch(peer: zenoh.Session, activate: list[str], strictness: int = 2, deactivate: tuple[str, ...] = ()) -> bool:
    payload = request(
        SWITCH,
        activate_controllers=activate,
        deactivate_controllers=list(deactivate),
        strictness=strictness,
        activate_asap=False,
        timeout=types.message("builtin_interfaces/msg/Duration", sec=0, nanosec=0),
    )
    reply = call(peer, "/controller_manager/switch_controller", SWITCH, payload)
    assert reply.ok is not None
    return bool(types.decode(reply.ok.payload.to_bytes(), f"{SWITCH}_Response").ok)


def commands(values: list[float]) -> bytes:
    layout = types.message("std_msgs/msg/MultiArrayLayout", dim=[], data_offset=0)
    msg = types.message(FLOAT64_ARRAY, layout=layout, data=np.array(values, dtype=np.float64))
    return types.encode(msg, FLOAT64_ARRAY)


def position(daemon: Daemon) -> np.ndarray[Any, Any]:
    return np.array(daemon.engine.state.position, copy=True)


def test_switch_then_commands_move_the_joints(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["fwd"])
    key = wire.data_key(0, "/fwd/commands", FLOAT64_ARRAY)
    pub = peer.declare_publisher(key)
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    target = [0.3, 0.2, -0.1]

    def arrived() -> bool:
        pub.put(commands(target), attachment=wire.attachment(1, CLIENT_GID))
        return bool(np.allclose(position(ros_daemon), target, atol=0.02))

    wait_for(arrived, what="the joints at the commanded position")
    pub.undeclare()


def test_unknown_controller_is_refused_ok_false_with_an_event(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert not switch(peer, ["nope"])
    wait_for(lambda: ros_daemon.events_with("refused ROS request on /controller_manager/switch_controller"))
    assert ros_daemon.events_with("nope")
    assert all(c["state"] != "active" or c["name"] == "jsb" for c in ros_daemon.engine.snapshot().controllers)


def test_malformed_request_gets_an_error_reply_and_an_event(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    reply = call(peer, "/controller_manager/switch_controller", SWITCH, b"\x00\x01\x00\x00\xff\xff")
    assert reply.err is not None and reply.ok is None
    wait_for(lambda: ros_daemon.events_with("malformed CDR"), what="the warning event")
    assert all(c["state"] != "active" or c["name"] == "jsb" for c in ros_daemon.engine.snapshot().controllers)


def held_still(daemon: Daemon, start: np.ndarray[Any, Any]) -> None:
    assert np.allclose(position(daemon), start, atol=1e-3)


def test_malformed_commands_are_dropped_with_an_event(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["fwd"])
    start = position(ros_daemon)
    pub = peer.declare_publisher(wire.data_key(0, "/fwd/commands", FLOAT64_ARRAY))
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    pub.put(b"\x00\x01\x00\x00\x01", attachment=wire.attachment(1, CLIENT_GID))
    wait_for(lambda: ros_daemon.events_with("dropped command on /fwd/commands"), what="the drop event")
    assert ros_daemon.events_with("malformed CDR")
    held_still(ros_daemon, start)


def test_commands_of_the_wrong_length_are_dropped_with_an_event(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    assert switch(peer, ["fwd"])
    start = position(ros_daemon)
    pub = peer.declare_publisher(wire.data_key(0, "/fwd/commands", FLOAT64_ARRAY))
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    pub.put(commands([0.5, 0.5]), attachment=wire.attachment(1, CLIENT_GID))
    wait_for(lambda: ros_daemon.events_with("expected 3 values"), what="the drop event (the JSON input's own text)")
    held_still(ros_daemon, start)


def test_a_wrong_type_hash_matches_nothing(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """rmw_zenoh's design: a different hash is a different key. Nothing in the daemon subscribes to it, so no
    sample is delivered, decoded or reported: the peer sees no match, exactly as between two ROS nodes."""
    assert switch(peer, ["fwd"])
    right = wire.data_key(0, "/fwd/commands", FLOAT64_ARRAY)
    wrong = right.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64
    good = peer.declare_publisher(right)
    bad = peer.declare_publisher(wrong)
    wait_for(lambda: good.matching_status.matching, what="the daemon's subscriber on the right key")
    assert not bad.matching_status.matching
    start = position(ros_daemon)
    bad.put(commands([0.5, 0.5, 0.5]))
    good.put(commands([0.5, 0.5]))  # a refusal we can wait for: it comes after the wrong-hash sample, if any
    wait_for(lambda: ros_daemon.events_with("expected 3 values"), what="the later refusal")
    held_still(ros_daemon, start)


def test_robot_description_reaches_a_late_transient_local_subscriber(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    received = Inbox()
    key = wire.data_key(0, "/robot_description", "std_msgs/msg/String")
    sub = zenoh.ext.declare_advanced_subscriber(
        peer, key, received, history=zenoh.ext.HistoryConfig(detect_late_publishers=True)
    )
    wait_for(lambda: len(received) >= 1, what="the cached robot_description")
    assert types.decode(received.last().payload.to_bytes(), "std_msgs/msg/String").data == URDF
    sub.undeclare()


def test_a_request_without_rmw_zenohs_attachment_is_refused(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """The reply must echo the request's sequence number and GID; without them there is nothing to echo."""
    replies = list(
        peer.get(
            wire.data_key(0, "/controller_manager/list_controllers", LIST),
            payload=request(LIST),
            target=zenoh.QueryTarget.ALL_COMPLETE,
            timeout=WAIT,
        )
    )
    assert len(replies) == 1 and replies[0].err is not None
    wait_for(lambda: ros_daemon.events_with("attachment of 0 bytes"), what="the warning event")


def test_on_the_sim_clock_clock_is_published_and_stamps_are_sim_time(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """/clock (rosgraph_msgs/msg/Clock) carries the lockstep clock, at most every 10 ms of it, never ahead of the
    cycle; /joint_states is stamped with its sample's sim time, so use_sim_time nodes see one clock."""
    ticks, states = Inbox(), Inbox()
    clock = peer.declare_subscriber(wire.data_key(0, "/clock", CLOCK), ticks)
    joint_states = peer.declare_subscriber(wire.data_key(0, "/joint_states", JOINT_STATE), states)
    wait_for(lambda: len(ticks) >= 5 and len(states) >= 5, what="clock ticks and joint states")
    now = ros_daemon.engine.t
    clock.undeclare()
    joint_states.undeclare()

    def seconds(t: Any) -> float:
        return float(t.sec) + float(t.nanosec) * 1e-9

    ticked = [seconds(types.decode(s.payload.to_bytes(), CLOCK).clock) for s in ticks.samples]
    assert all(b - a >= 0.01 - 1e-9 for a, b in itertools.pairwise(ticked)) and 0.0 <= ticked[-1] <= now + 1e-9
    stamped = [seconds(types.decode(s.payload.to_bytes(), JOINT_STATE).header.stamp) for s in states.samples]
    assert stamped == sorted(stamped) and 0.0 <= stamped[-1] <= now + 1e-9  # sim seconds, not the wall clock's epoch
    keys = [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**", timeout=WAIT) if r.ok is not None]
    assert any(k.split("/")[5:10:4] == ["MP", "%clock"] for k in keys if k.count("/") > 9)
