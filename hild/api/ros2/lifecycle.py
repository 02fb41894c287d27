"""The controller lifecycle services of ros2_control's controller manager (controller_manager_msgs, 4.46.0), each
answered by hild's JSON service of the same job through ``Services.handle``: the same checks, the same refusals.

- ``load_controller {name}`` → ``load_controller {name, type, params, fallback_controllers}`` from what was set on
  the manager (``<name>.type``, ``.params_file``, ``.fallback_controllers``: the spawner's sequence); with no
  ``<name>.type`` set, ``reload_controller {name}``, which loads it from the daemon's config file, as ros2_control's
  manager loads a controller its own YAML names.
- ``configure_controller``, ``cleanup_controller``, ``unload_controller`` → the JSON services of the same names.
- ``reload_controller_libraries {force_kill}`` → ``reload_controller`` for every loaded controller (rebuilt from the
  config file on disk; hild's controller code is imported once, at start); refused while any is active unless
  ``force_kill``, which deactivates them first, as ros2_control does.
- ``list_controller_types`` → ``list_controller_types``, under the plugin names ``list_controllers`` reports.

Their responses are only ``ok``: a refusal's reason is a warning event (``refused ROS request on …``), as for a
switch, and the JSON service's own event says what was done.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable
from typing import Any

from hild.api.ros2 import types
from hild.api.ros2.controller_manager import hild_type, plugin_name
from hild.api.ros2.manager_parameters import PendingLoads
from hild.api.ros2.node import ROS_SENDER, RosNode
from hild.api.ros2.params_files import controller_params
from hild.api.services import Services

PACKAGE = "controller_manager_msgs/srv"
BASE_CLASS = "controller_interface::ControllerInterface"  # hild has no chainable controllers


class LifecycleServices:
    """Declared under the manager's node, as ros2_control's are."""

    def __init__(self, face: RosNode, services: Services, node: str, pending: PendingLoads) -> None:
        self.face = face
        self.services = services
        self.node = node
        self.pending = pending
        served: tuple[tuple[str, str, Callable[[Any], Awaitable[Any]] | None], ...] = (
            ("load_controller", "LoadController", self._load),
            ("configure_controller", "ConfigureController", None),  # None: hild's JSON service of the same name
            ("unload_controller", "UnloadController", None),
            ("cleanup_controller", "CleanupController", None),
            ("reload_controller_libraries", "ReloadControllerLibraries", self._reload_all),
            ("list_controller_types", "ListControllerTypes", self._types),
        )
        for short, kind, serve in served:
            face.declare_service(f"{node}/{short}", f"{PACKAGE}/{kind}", serve or self._by_name(short, kind))

    async def _call(self, service: str, body: dict[str, Any]) -> dict[str, Any]:
        return await self.services.handle(service, json.dumps(body).encode())

    def _read(self, service: str) -> dict[str, Any]:
        return dict(json.loads(self.services.read(service, b"")))

    def _ok(self, kind: str, short: str, reason: str | None) -> Any:
        """``{kind}_Response(ok)``; a refusal is reported with its reason."""
        if reason is not None:
            self.face.refused(self.face.name(f"{self.node}/{short}"), reason)
        return types.message(f"{PACKAGE}/{kind}_Response", ok=reason is None)

    @staticmethod
    def _error(reply: dict[str, Any]) -> str | None:
        return None if reply.get("ok") else str(reply.get("error"))

    async def _load(self, request: Any) -> Any:
        return self._ok("LoadController", "load_controller", await self.load(str(request.name)))

    async def load(self, name: str) -> str | None:
        """What the manager's parameters say for ``name``, else its section of the config file; None when loaded."""
        pending = self.pending.of(name)
        if "type" not in pending:
            if name in {c["name"] for c in self._read("list_controllers").get("controllers", [])}:
                return f"controller {name!r} is already loaded"
            error = self._error(await self._call("reload_controller", {"name": name}))
            if error is not None:
                error += f"; nor was {name}.type set on {self.face.name(self.node)} (the spawner sets it)"
            return error
        body: dict[str, Any] = {"name": name, "type": hild_type(pending["type"]), "by": ROS_SENDER}
        files = pending.get("params_file") or []
        if files:
            try:
                body["params"] = await asyncio.to_thread(controller_params, files, name, self.face.name(name))
            except ValueError as exc:
                return f"{name}.params_file: {exc}"
        if pending.get("fallback_controllers"):
            body["fallback_controllers"] = pending["fallback_controllers"]
        return self._error(await self._call("load_controller", body))

    def _by_name(self, short: str, kind: str) -> Callable[[Any], Awaitable[Any]]:
        """The ROS service ``short`` answered by hild's JSON service of the same name with ``{name}``."""

        async def serve(request: Any) -> Any:
            reply = await self._call(short, {"name": str(request.name)})
            return self._ok(kind, short, self._error(reply))

        return serve

    async def _reload_all(self, request: Any) -> Any:
        return self._ok("ReloadControllerLibraries", "reload_controller_libraries", await self.reload_all(request))

    async def reload_all(self, request: Any) -> str | None:
        """Every loaded controller rebuilt from the config file, one by one; those that cannot be (e.g. loaded at
        run time and not in the file) stay as they were and are named in the reason."""
        controllers = self._read("list_controllers").get("controllers", [])
        active = [c["name"] for c in controllers if c["state"] == "active"]
        if active and not request.force_kill:
            return (
                f"active controllers ({', '.join(active)}): deactivate them first, or set force_kill to have them "
                "deactivated (ros2_control refuses the same)"
            )
        if active:
            error = self._error(await self._call("switch_controllers", {"deactivate": active, "strict": True}))
            if error is not None:
                return f"could not deactivate {', '.join(active)}: {error}"
        failed = []
        for name in (c["name"] for c in controllers):
            error = self._error(await self._call("reload_controller", {"name": name}))
            if error is not None:
                failed.append(f"{name}: {error}")
        return "not reloaded: " + "; ".join(failed) if failed else None

    async def _types(self, request: Any) -> Any:
        reply = self._read("list_controller_types")
        names = [plugin_name(t["type"]) for t in reply.get("types", [])]
        return types.message(
            f"{PACKAGE}/ListControllerTypes_Response", types=names, base_classes=[BASE_CLASS] * len(names)
        )
