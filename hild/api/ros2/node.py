"""What a part of the ROS 2 face (the action server, the controller manager's services, parameters, /clock) needs of
the node it lives on: names, publishers, services, other nodes, subscriptions, the ROS clock and a place to report a
refusal.

:class:`hild.api.ros2.face.RosFace` meets :class:`RosNode`; the parts import this module, never the face, so the
face is the one module that knows all of them and none of them knows it.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Protocol

from hild.api.ros2.wire import attachment

ROS_SENDER = "a ROS 2 client"  # who a ROS request is from, in the events: ROS requests name no user


@dataclass
class Writer:
    """One ROS publisher: its key, GID and sequence number."""

    publisher: Any
    gid: bytes
    sequence: int = 0

    def put(self, payload: bytes) -> None:
        self.sequence += 1
        self.publisher.put(payload, attachment=attachment(self.sequence, self.gid))


class ServiceHost(Protocol):
    """Where services are declared: the daemon's node, or another node of the same session."""

    def declare_service(self, relative: str, type_name: str, serve: Callable[[Any], Any]) -> None: ...


class NodeHost(ServiceHost, Protocol):
    """Another ROS node of the session (a controller's, as ros2_control's controllers are nodes of their own)."""

    def close(self) -> None: ...  # its services, then its node token, withdrawn


class RosNode(ServiceHost, Protocol):
    def name(self, relative: str) -> str: ...  # the fully qualified ROS name of ``relative`` under the namespace

    def now_ns(self) -> int: ...  # ROS time: the sim clock when the config says so, else the wall clock

    def writer(self, name: str, type_name: str, *, latched: bool = False) -> Writer: ...

    def declare_node(self, name: str) -> NodeHost: ...  # a node ``<namespace>/<name>`` in the ROS graph

    def subscribe(
        self, controller: str, name: str, type_name: str, handle: Callable[[Any], Awaitable[None]]
    ) -> None: ...

    def refused(self, name: str, reason: str) -> None: ...  # a refused request, reported once as an event
