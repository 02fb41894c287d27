"""The six parameter services of a ROS node (rcl_interfaces 2.0.3: list, get, set, set atomically, describe, get
types) over a store of hild parameters: a controller's (``ControllerParameters``: hild's ``list_parameters`` and
``set_parameters`` JSON services, the same checks and refusals) or the controller manager's
(``hild.api.ros2.manager_parameters``).

All six are declared together: rclpy's parameter client (``ros2 param``, the spawner) waits for all of them before
its first call. They answer as rclcpp's parameter service does, which is what a ros2_control node runs: a get,
describe or get-types naming a parameter the node does not have answers with an empty list; ``set_parameters``
sets each parameter on its own (one result each, the reason when refused), ``set_parameters_atomically`` all or
none; ``list_parameters`` filters by prefix and depth as rclcpp does (``.`` separates, depth 0 = all).
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from hild.api.ros2 import types
from hild.api.ros2.node import ROS_SENDER, RosNode, ServiceHost
from hild.api.ros2.parameter_values import STRING, from_ros, ros_type, to_ros
from hild.api.services import Services

LIST = "rcl_interfaces/srv/ListParameters"
GET = "rcl_interfaces/srv/GetParameters"
SET = "rcl_interfaces/srv/SetParameters"
SET_ATOMICALLY = "rcl_interfaces/srv/SetParametersAtomically"
DESCRIBE = "rcl_interfaces/srv/DescribeParameters"
GET_TYPES = "rcl_interfaces/srv/GetParameterTypes"
SEPARATOR = "."
NO_ROS_TYPE = "shown as its JSON text: ROS has no type for it; change it with hild's set_parameters"


@dataclass(frozen=True)
class Entry:
    """One parameter as a node shows it: its JSON value, whether it can be set now, and what it is."""

    name: str
    value: Any
    read_only: bool
    description: str = ""


class ParameterStore(Protocol):
    def entries(self) -> dict[str, Entry]: ...  # LookupError (the reason) when the node's parameters cannot be read

    async def set(self, values: dict[str, Any]) -> str | None: ...  # all or nothing: None when set, else why not


def listing(names: list[str], prefixes: list[str], depth: int) -> tuple[list[str], list[str]]:
    """rclcpp's ``list_parameters``: the names under ``prefixes`` (all without) at most ``depth`` levels below
    (0: any depth), and the prefix of each name listed."""

    def within(rest: str) -> bool:
        return depth == 0 or rest.count(SEPARATOR) < depth

    out: list[str] = []
    found: list[str] = []
    for name in names:
        if prefixes:
            wanted = any(
                name == prefix or (name.startswith(prefix + SEPARATOR) and within(name[len(prefix) :]))
                for prefix in prefixes
            )
        else:
            wanted = within(name)
        if not wanted:
            continue
        out.append(name)
        prefix, dot, _ = name.rpartition(SEPARATOR)
        if dot and prefix not in found:
            found.append(prefix)
    return out, found


class ParameterServer:
    """The six services under ``<node>/``; ``store`` answers them, ``face`` reports what is refused."""

    def __init__(self, host: ServiceHost, node: str, store: ParameterStore, face: RosNode) -> None:
        self.store = store
        self.face = face
        self.prefix = face.name(node)
        served: tuple[tuple[str, str, Callable[[Any], Awaitable[Any]]], ...] = (
            ("list_parameters", LIST, self._list),
            ("get_parameters", GET, self._get),
            ("set_parameters", SET, self._set),
            ("set_parameters_atomically", SET_ATOMICALLY, self._set_atomically),
            ("describe_parameters", DESCRIBE, self._describe),
            ("get_parameter_types", GET_TYPES, self._types),
        )
        for short, type_name, serve in served:
            host.declare_service(f"{node}/{short}", type_name, serve)

    def _entries(self, service: str) -> dict[str, Entry]:
        try:
            return self.store.entries()
        except LookupError as exc:  # e.g. the controller was unloaded a moment ago
            self.face.refused(f"{self.prefix}/{service}", str(exc.args[0] if exc.args else exc))
            return {}

    def _known(self, service: str, names: list[str]) -> list[Entry]:
        """The entries of ``names``, or none at all if one is unknown (rclcpp: not declared → empty reply)."""
        entries = self._entries(service)
        if any(name not in entries for name in names):
            return []
        return [entries[name] for name in names]

    async def _list(self, request: Any) -> Any:
        names, prefixes = listing(list(self._entries("list_parameters")), list(request.prefixes), int(request.depth))
        result = types.message("rcl_interfaces/msg/ListParametersResult", names=names, prefixes=prefixes)
        return types.message(f"{LIST}_Response", result=result)

    async def _get(self, request: Any) -> Any:
        values = [to_ros(entry.value) for entry in self._known("get_parameters", list(request.names))]
        return types.message(f"{GET}_Response", values=values)

    async def _types(self, request: Any) -> Any:
        found = self._known("get_parameter_types", list(request.names))
        kinds = [STRING if ros_type(entry.value) is None else ros_type(entry.value) for entry in found]
        return types.message(f"{GET_TYPES}_Response", types=np.asarray(kinds, dtype=np.uint8))

    async def _describe(self, request: Any) -> Any:
        descriptors = [describe(entry) for entry in self._known("describe_parameters", list(request.names))]
        return types.message(f"{DESCRIBE}_Response", descriptors=descriptors)

    async def _set(self, request: Any) -> Any:
        """Each parameter on its own, in order, as rclcpp's ``set_parameters`` does."""
        results = [await self._apply("set_parameters", [parameter]) for parameter in request.parameters]
        return types.message(f"{SET}_Response", results=results)

    async def _set_atomically(self, request: Any) -> Any:
        result = await self._apply("set_parameters_atomically", list(request.parameters))
        return types.message(f"{SET_ATOMICALLY}_Response", result=result)

    async def _apply(self, service: str, parameters: list[Any]) -> Any:
        """One all-or-nothing change of ``parameters``: a SetParametersResult with hild's reason when refused."""
        values: dict[str, Any] = {}
        reason: str | None = None
        for parameter in parameters:
            try:
                values[str(parameter.name)] = from_ros(parameter.value)
            except ValueError as exc:
                reason = f"{parameter.name}: {exc}"
                break
        if reason is None and values:  # none at all: nothing to do, as rclcpp answers it
            reason = await self.store.set(values)
        if reason is not None:
            self.face.refused(f"{self.prefix}/{service}", reason)
        return types.message("rcl_interfaces/msg/SetParametersResult", successful=reason is None, reason=reason or "")


def describe(entry: Entry) -> Any:
    kind = ros_type(entry.value)
    description = entry.description if kind is not None else " ".join(filter(None, (entry.description, NO_ROS_TYPE)))
    return types.message(
        "rcl_interfaces/msg/ParameterDescriptor",
        name=entry.name,
        type=STRING if kind is None else kind,
        description=description,
        additional_constraints="",
        read_only=entry.read_only or kind is None,
        dynamic_typing=False,
        floating_point_range=[],
        integer_range=[],
    )


class ControllerParameters:
    """A loaded controller's parameters, through hild's JSON services. ``read_only``: the controller is active
    and the parameter is not dynamic (set_parameters refuses it until the controller is deactivated; while it is
    not active every parameter may be set, and the controller is rebuilt with the new value)."""

    def __init__(self, services: Services, controller: str) -> None:
        self.services = services
        self.controller = controller

    def _read(self, service: str, body: dict[str, Any] | None) -> dict[str, Any]:
        reply = json.loads(self.services.read(service, b"" if body is None else json.dumps(body).encode()))
        if not reply.get("ok"):
            raise LookupError(str(reply.get("error")))
        return dict(reply)

    def entries(self) -> dict[str, Entry]:
        listed = self._read("list_parameters", {"controller": self.controller})["parameters"]
        controllers = self._read("list_controllers", None)["controllers"]
        active = any(c["name"] == self.controller and c["state"] == "active" for c in controllers)
        return {
            p["name"]: Entry(p["name"], p["value"], active and not p["dynamic"], p.get("description") or "")
            for p in listed
        }

    async def set(self, values: dict[str, Any]) -> str | None:
        body = json.dumps({"controller": self.controller, "values": values, "by": ROS_SENDER}).encode()
        reply = await self.services.handle("set_parameters", body)
        return None if reply.get("ok") else str(reply.get("error"))
