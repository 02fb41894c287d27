"""A controller's parameters (and the daemon's own, ``controller_manager``) read and set while the robot runs:
validated whole in the client domain against the controller's schema, applied between two cycles in both halves
(docs/protocol.md, "Parameters while the robot runs")."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from hild.api.codec import encode
from hild.api.fields import MAX_NAMES, Reply, RequestError, Service, controller_name, mapping, names, required, sender
from hild.config.loader import CheckedController, ConfigError
from hild.config.params import describe, flatten, with_values
from hild.config.tuning import MANAGER
from hild.crossing.requests import Load, Request, SetParams
from hild.daemon.link import CycleLink

OnCycle = Callable[[Request], Awaitable[Any]]
Check = Callable[[str, dict[str, Any], set[str], str], CheckedController]


class ControllerParameters:
    def __init__(self, engine: CycleLink, on_cycle: OnCycle, check: Check) -> None:
        """``check``: how a controller's section is checked (a rebuild with new fixed parameters is a reload)."""
        self.engine = engine
        self.on_cycle = on_cycle
        self._checked = check

    def services(self) -> dict[str, Service]:
        return {
            "list_parameters": Service({"controller": controller_name}, read=self._list_parameters),
            "get_parameters": Service({"controller": controller_name, "names": names}, read=self._get_parameters),
            "set_parameters": Service(
                {"controller": controller_name, "values": mapping, "by": sender}, self._set_parameters
            ),
            "tuned_config": Service({}, self._tuned_config),
        }

    def _controller(self, request: dict[str, Any]) -> tuple[str, Any]:
        """The controller named in ``request`` (its API half: its params are what the cycle's are), or the daemon's
        own parameters (``controller_manager``: always active, so only its dynamic ones change)."""
        name = required(request, "controller")
        if name == MANAGER:
            return name, _Node(self.engine.snapshot().tuning)
        controller = self.engine.controllers().get(name)
        if controller is None:
            known = ", ".join(sorted(self.engine.controllers())) or "none"
            raise RequestError(f"unknown controller {name!r} (loaded: {known})")
        return name, controller

    def _list_parameters(self, request: dict[str, Any]) -> Reply:
        name, controller = self._controller(request)
        model = type(controller.params)
        parameters = []
        for path, value in flatten(controller.params).items():
            dynamic, description = describe(model, path)
            parameters.append({"name": path, "value": value, "dynamic": dynamic, "description": description})
        return {"controller": name, "parameters": parameters}

    def _get_parameters(self, request: dict[str, Any]) -> Reply:
        name, controller = self._controller(request)
        values = flatten(controller.params)
        wanted = request.get("names") or list(values)
        unknown = [path for path in wanted if path not in values]
        if unknown:
            raise RequestError(f"{name} has no parameter(s) {', '.join(map(repr, unknown))} (list_parameters)")
        return {"controller": name, "values": {path: values[path] for path in wanted}}

    async def _set_parameters(self, request: dict[str, Any]) -> Reply:
        """Validated here against the controller's own schema, whole; applied between two cycles in both halves.
        A controller that is active takes only dynamic parameters; one that is not takes any, and is then rebuilt
        (as a reload, from these values: it is configured again if it was)."""
        name, controller = self._controller(request)
        values = request.get("values") or {}
        if not values:
            raise RequestError('nothing to set: {"controller": NAME, "values": {"path.to.param": value}}')
        if len(values) > MAX_NAMES:
            raise RequestError(f"{len(values)} parameters in one request; at most {MAX_NAMES}")
        model = type(controller.params)
        if name == MANAGER:
            joints = controller.params.joints
            unknown = sorted(
                {p.split(".")[1] for p in values if p.startswith("joints.") and p.split(".")[1] not in joints}
            )
            if unknown:
                raise RequestError(f"unknown joint(s) {unknown} (joints: {', '.join(joints)})")
        try:
            params = with_values(controller.params, values)
        except ValueError as exc:
            raise RequestError(f"{name}: {_validation_text(exc)}; nothing changed") from None
        changes = _changes(controller.params, params)
        if not changes:
            return {"controller": name, "changed": [], "applied": "unchanged"}
        fixed = sorted({path for path in values if not describe(model, path)[0]})
        if not fixed:
            reply = await self.on_cycle(SetParams(name, params, tuple(changes), request.get("by", "a client")))
            return {"controller": name, "changed": reply["changed"], "applied": "now"}
        if controller.active:
            raise RequestError(
                f"{', '.join(fixed)} of {name} cannot change while it is active: deactivate it, set them, "
                "and it is rebuilt with them (only dynamic parameters change while active: list_parameters)"
            )
        controllers = self.engine.snapshot().controllers
        type_name = next(c["type"] for c in controllers if c["name"] == name)
        section = {"type": type_name, "params": params.model_dump(mode="json")}
        checked = self._checked(name, section, {c["name"] for c in controllers}, "request")
        by = request.get("by", "a client")
        load = Load(name, checked.type, checked.params, replaces=True, keeps_fallbacks=True, source=f"by {by}")
        reply = await self.on_cycle(load)
        return {"controller": name, "changed": changes, "applied": f"rebuilt ({reply['state']})"}

    async def _tuned_config(self, request: dict[str, Any]) -> Reply:
        """The daemon's config file with every parameter as it is now (``hild ctl params save`` writes it)."""
        from hild.config.tuned import tuned_copy  # ruamel.yaml: loaded only when a copy is asked for

        path = self.engine.loaded.path
        snapshot = self.engine.snapshot()
        types = {c["name"]: c["type"] for c in snapshot.controllers}
        controllers = {n: (types[n], c.params) for n, c in self.engine.controllers().items() if n in types}
        try:
            text, changed = await asyncio.to_thread(tuned_copy, path, controllers, snapshot.tuning)
        except ConfigError as exc:
            raise RequestError(f"{path} does not load as it is on disk, so there is nothing to copy:\n{exc}") from None
        return {"path": str(path), "yaml": text, "changed": changed}


@dataclass(frozen=True)
class _Node:
    """The daemon's own parameters, read and set like a controller's that is always active."""

    params: Any
    active: bool = True


def _changes(old: Any, new: Any) -> list[str]:
    """``path: old → new`` for every parameter that differs, in JSON."""
    before, after = flatten(old), flatten(new)
    return [
        f"{path}: {encode(before.get(path)).decode()} → {encode(value).decode()}"
        for path, value in after.items()
        if before.get(path) != value
    ]


def _validation_text(exc: ValueError) -> str:
    """A pydantic error as ``path: what``, one per problem; any other ValueError as it is."""
    errors = getattr(exc, "errors", None)
    if not callable(errors):
        return str(exc)
    parts = []
    for err in errors():
        where = ".".join(str(p) for p in err["loc"]) or "params"
        parts.append(f"{where}: {err['msg'].removeprefix('Value error, ')} (found {err.get('input')!r:.60})")
    return "; ".join(parts)
