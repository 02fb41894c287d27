"""Controllers loaded after the API started appear on ROS 2, and unloaded ones disappear: their tokens (what the
ROS graph tools list), their topics and their action, as the JSON API's own endpoints follow the controllers."""

from __future__ import annotations

import concurrent.futures
from typing import Any

import numpy as np
import zenoh

from hild.api.ros2 import wire
from tests.api.conftest import WAIT, Daemon
from tests.api.ros2.conftest import CLIENT_GID
from tests.api.ros2.test_action import goal, point, result, send
from tests.api.ros2.test_face import FLOAT64_ARRAY, commands, position, switch
from tests.helpers import wait_for


def entities(peer: zenoh.Session) -> set[tuple[str, str]]:
    """(kind, name) of every entity token of the daemon's node: what `ros2 topic/service list` would show."""
    replies = peer.liveliness().get("@ros2_lv/0/**", timeout=WAIT)
    keys = [str(r.ok.key_expr) for r in replies if r.ok is not None]
    return {(k.split("/")[5], k.split("/")[9]) for k in keys if k.count("/") > 9}


def on_cycle(daemon: Daemon, action: Any) -> Any:
    """Load or unload as hild does it at run time: on the cycle thread, between cycles."""
    return daemon.engine.submit(action).result(WAIT)


def test_a_forward_command_controller_loaded_later_takes_ros_commands(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    engine = ros_daemon.engine
    on_cycle(ros_daemon, lambda: engine.load_controller("late", "forward_command", {"joints": ["a", "b", "c"]}))
    wait_for(lambda: ("MS", "%late%commands") in entities(peer), what="the new subscription's token")
    assert switch(peer, ["late"])
    pub = peer.declare_publisher(wire.data_key(0, "/late/commands", FLOAT64_ARRAY))
    wait_for(lambda: pub.matching_status.matching, what="the daemon's subscriber")
    target = [0.2, -0.3, 0.1]

    def arrived() -> bool:
        pub.put(commands(target), attachment=wire.attachment(1, CLIENT_GID))
        return bool(np.allclose(position(ros_daemon), target, atol=0.02))

    wait_for(arrived, what="the joints at the commanded position")
    assert engine.switch([], ["late"]).ok
    on_cycle(ros_daemon, lambda: engine.manager.unload("late"))
    wait_for(lambda: ("MS", "%late%commands") not in entities(peer), what="the token withdrawn")
    wait_for(lambda: not pub.matching_status.matching, what="the subscriber undeclared")
    pub.undeclare()
    assert ("MP", "%joint_states") in entities(peer)  # the rest of the node stays


def test_a_trajectory_controller_loaded_later_offers_its_action(ros_daemon: Daemon, peer: zenoh.Session) -> None:
    """Its action runs a goal; unloaded while a goal runs, the waiting get_result still answers, then every
    endpoint goes."""
    engine = ros_daemon.engine
    base = "/traj2/follow_joint_trajectory/_action"
    on_cycle(ros_daemon, lambda: engine.load_controller("traj2", "joint_trajectory", {"joints": ["a", "b", "c"]}))
    offered = {("SS", f"{base}/send_goal".replace("/", "%")), ("MS", "%traj2%joint_trajectory")}
    wait_for(lambda: offered <= entities(peer), what="the action's and the topic's tokens")
    assert switch(peer, ["traj2"])
    target = [0.2, 0.1, -0.1]
    assert send(peer, b"1" * 16, goal([point(target, 0.3)]), base)
    assert result(peer, b"1" * 16, base).status == 4  # SUCCEEDED
    np.testing.assert_allclose(position(ros_daemon), target, atol=0.02)

    assert send(peer, b"2" * 16, goal([point([0.9, 0.9, 0.9], 20.0)]), base)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        waiting = pool.submit(result, peer, b"2" * 16, base)
        assert switch(peer, [], deactivate=("traj2",))
        on_cycle(ros_daemon, lambda: engine.manager.unload("traj2"))
        assert waiting.result(WAIT).status in (5, 6)  # CANCELED (unloaded) or ABORTED (hild's own stop)
    wait_for(lambda: not any("%traj2%" in name for _, name in entities(peer)), what="every traj2 token withdrawn")
    assert ("SS", "%traj%follow_joint_trajectory%_action%send_goal") in entities(peer)  # the other one stays
