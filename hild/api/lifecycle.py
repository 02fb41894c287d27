"""Controllers loaded, configured, unloaded and reloaded while the robot runs: the services, checked here in the
client domain as ``hild check`` checks a config's controllers, applied by the cycle after a write
(docs/protocol.md, "Controllers while the robot runs")."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

from hild import plugins
from hild.api.fields import Reply, RequestError, Service, controller_name, mapping, names, required, sender, text
from hild.config.loader import CheckedController, ConfigError, check_controller, load_config
from hild.config.tuning import MANAGER
from hild.crossing.cells import MAX_CONTROLLERS
from hild.crossing.requests import Cleanup, Configure, Load, Request, Unload
from hild.daemon.link import CycleLink

OnCycle = Callable[[Request], Awaitable[Any]]


def loaded_names(engine: CycleLink) -> set[str]:
    """The controllers the cycle has loaded, as its latest snapshot says."""
    return {c["name"] for c in engine.snapshot().controllers}


class ControllerLifecycle:
    def __init__(self, engine: CycleLink, on_cycle: OnCycle) -> None:
        self.engine = engine
        self.on_cycle = on_cycle

    def services(self) -> dict[str, Service]:
        load_fields = {
            "name": controller_name,
            "type": text,
            "params": mapping,
            "fallback_controllers": names,
            "chain_to": controller_name,
        }
        return {
            "list_controller_types": Service({}, read=self._list_controller_types),
            "load_controller": Service({**load_fields, "by": sender}, self._load),
            "configure_controller": Service({"name": controller_name}, self._configure),
            "cleanup_controller": Service({"name": controller_name}, self._cleanup),
            "unload_controller": Service({"name": controller_name}, self._unload),
            "reload_controller": Service({"name": controller_name}, self._reload),
        }

    def _list_controller_types(self, request: dict[str, Any]) -> Reply:
        return {"types": [{"type": name, "class": where} for name, where in plugins.sources(plugins.CONTROLLERS)]}

    async def _load(self, request: dict[str, Any]) -> Reply:
        """Checked here as ``hild check`` checks the config's controllers; built and adopted by the cycle."""
        name = required(request, "name")
        if name == MANAGER:
            raise RequestError(f"{MANAGER!r} names the daemon's own parameters: choose another name")
        loaded = loaded_names(self.engine)
        if name in loaded:
            raise RequestError(f"controller {name!r} is already loaded (reload it, or unload it first)")
        if len(loaded) >= MAX_CONTROLLERS:
            raise RequestError(f"{len(loaded)} controllers are loaded: at most {MAX_CONTROLLERS}; unload one first")
        section = {k: v for k, v in request.items() if k not in ("name", "by")}
        if "type" not in section:
            raise RequestError('give the controller\'s type: {"name": NAME, "type": TYPE, "params": {...}}')
        checked = self.checked(name, section, loaded, "request")
        load = Load(
            name,
            checked.type,
            checked.params,
            checked.fallbacks,
            chain_to=checked.chain_to,
            source=f"by {request.get('by', 'a client')}",
        )
        return dict(await self.on_cycle(load))

    async def _configure(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Configure(self._loaded(request))))

    async def _cleanup(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Cleanup(self._loaded(request))))

    async def _unload(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Unload(self._loaded(request))))

    async def _reload(self, request: dict[str, Any]) -> Reply:
        """Replace a controller that is not active with a new one built from the config file as it is on disk now
        (the same file the daemon started from); not loaded, it is loaded."""
        name = required(request, "name")
        path = self.engine.loaded.path
        try:
            on_disk = await asyncio.to_thread(load_config, path)
        except ConfigError as exc:
            raise RequestError(f"{path} does not load, so nothing was reloaded:\n{exc}") from None
        section = on_disk.config.controllers.get(name)
        if section is None:
            raise RequestError(f"{path} has no controller {name!r}: nothing to reload it from")
        loaded = loaded_names(self.engine)
        raw = {
            "type": section.type,
            "params": section.params,
            "fallback_controllers": section.fallback_controllers,
            "chain_to": section.chain_to,
        }
        checked = self.checked(name, raw, loaded, str(path))
        load = Load(
            name,
            checked.type,
            checked.params,
            checked.fallbacks,
            replaces=name in loaded,
            chain_to=checked.chain_to,
            source=f"from {path}",
        )
        return dict(await self.on_cycle(load))

    def checked(self, name: str, section: dict[str, Any], loaded: set[str], source: str) -> CheckedController:
        """``section`` as ``hild check`` checks a config's controller, against the running robot; a refusal lists
        every problem (fallbacks among ``loaded``)."""
        try:
            return check_controller(self.engine.loaded, name, section, loaded, source)
        except ConfigError as exc:
            raise RequestError(f"controller {name!r} was not loaded:\n{exc}") from None

    def _loaded(self, request: dict[str, Any]) -> str:
        name = required(request, "name")
        loaded = loaded_names(self.engine)
        if name not in loaded:
            known = ", ".join(sorted(loaded)) or "none"
            raise RequestError(f"unknown controller {name!r} (loaded: {known})")
        return name
