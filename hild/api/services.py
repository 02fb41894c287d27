"""The control-plane services, independent of Zenoh: bytes in, a reply dict out.

Every reply carries ``ok`` and ``error`` (null when ok); nothing a client sends can raise out of
:meth:`Services.handle` or :meth:`Services.read`.

The cycle is reached through the ``CycleLink`` (``self.engine``), wherever it runs. Read-only services read it back
(``status()``, ``snapshot()``: the cycle process's snapshot and numeric cells, or the in-process engine's read-back
methods; safe from any thread either way) and need nothing of the cycle, so they keep answering even when the
cycle is stuck, which is when an operator needs them most; :meth:`Services.read` answers them synchronously from a
recent reply, so the API can answer a batch of polls in one go. Services that change state send a typed request
(:mod:`hild.crossing.requests`) through ``request`` (an e-stop through ``request_estop``, never queued): the engine
applies it between two cycles, in the cycle process or on the in-process cycle thread. :meth:`Services.handle`
awaits the reply on the asyncio thread and gives up after ``timeout``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextvars
import logging
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hild import plugins
from hild.api.codec import MAX_PAYLOAD, PayloadError, decode, encode
from hild.api.keys import check_chunk
from hild.api.queries import LargePayloadWorker, too_large
from hild.config.loader import ConfigError, check_controller, load_config
from hild.config.params import describe, flatten, with_values
from hild.config.tuning import MANAGER
from hild.controller import and_more, unknown_keys
from hild.crossing.cells import MAX_CONTROLLERS
from hild.crossing.requests import (
    Configure,
    Enable,
    Load,
    Refused,
    Request,
    Reset,
    SetParams,
    SetZero,
    Switch,
    Unload,
)
from hild.daemon.link import CycleLink

log = logging.getLogger("hild.api")

# s: how long a read-only reply is reused while the engine has not changed. change_seq covers modes, faults,
# limits, controllers and hardware, so what ages is only the stamp and the loop counters: a polled status is as
# fresh as the one published every 0.2 s on hild/<robot>/status. A rebuild holds the GIL; at 2 x 200
# Hz polling, rebuilding every 20 ms was what polling still cost the cycle (docs/performance.md has the figures).
READ_MAX_AGE = 0.2
EMPTY_REQUESTS = frozenset({b"", b"{}"})
DEFAULT_TIMEOUT = 1.0  # s; below the client's default 2 s so the client sees our error, not its own timeout
# A caller's own, shorter limit on waiting for the cycle (ROS' SwitchController.timeout), for the request being
# handled: a context variable, so the services that hop to the cycle need not all carry it.
_ASKED_TIMEOUT: contextvars.ContextVar[float | None] = contextvars.ContextVar("asked_timeout", default=None)
MAX_NAMES = 256
MAX_SENDER = 64  # characters of a request's "by"
# Bytes a request may have, refused larger before it is copied or decoded (docs/protocol.md, "Limits"). A request
# without fields is "", "{}" or a little whitespace; the largest with fields, a switch of 2 x MAX_NAMES names of
# up to ~120 characters. One status poll of 1 MiB cost the cycle 43 ms of GIL to refuse by its keys.
EMPTY_REQUEST = 256
FIELDS_REQUEST = 64 * 1024


def ok(body: Reply) -> Reply:
    """A successful reply; a body may carry its own ok/error (switch, reset)."""
    return {"ok": True, "error": None, **body}


class RequestError(Exception):
    """A request that cannot be served; the message is the reply's ``error``."""


Validator = Callable[[str, Any], Any]
Reply = dict[str, Any]


def names(field: str, value: Any) -> list[str]:
    """A list of distinct, non-empty controller names."""
    if not isinstance(value, list):
        raise RequestError(f"{field} must be a list of controller names, not {type(value).__name__}")
    if len(value) > MAX_NAMES:
        raise RequestError(f"{field} lists {len(value)} names; at most {MAX_NAMES}")
    seen: set[str] = set()
    for item in value:
        if not isinstance(item, str) or not item:
            raise RequestError(f"{field} must contain non-empty strings, found {item!r}")
        if item in seen:
            raise RequestError(f"{field} lists {item!r} twice")
        seen.add(item)
    return value


def boolean(field: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise RequestError(f"{field} must be true or false, not {value!r}")
    return value


def joint_name(field: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise RequestError(f"{field} must be a joint name, not {value!r}")
    return value


def controller_name(field: str, value: Any) -> str:
    """A controller's name: it becomes a chunk of its Zenoh keys (``hild/<robot>/ctrl/<name>/…``)."""
    try:
        return check_chunk(value, field)
    except ValueError as exc:
        raise RequestError(str(exc)) from None


def text(field: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise RequestError(f"{field} must be a non-empty string, not {value!r}")
    return value


def mapping(field: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise RequestError(f"{field} must be a JSON object, not {type(value).__name__}")
    return value


def sender(field: str, value: Any) -> str:
    """Who a change is from, as the client says (``user@host``): it goes into the event and the recording."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_SENDER or not value.isprintable():
        raise RequestError(f"{field} must be a printable string of at most {MAX_SENDER} characters")
    return value


def request_limit(fields: Mapping[str, Validator]) -> int:
    """The size limit of a request with these fields, in bytes."""
    return FIELDS_REQUEST if fields else EMPTY_REQUEST


def parse_request(raw: bytes, fields: Mapping[str, Validator]) -> dict[str, Any]:
    """Decode a request object and check every field; an empty payload is an empty object.

    The size limit is checked first; the API's gate checks it too, before the payload is even copied."""
    limit = request_limit(fields)
    if len(raw) > limit:
        raise RequestError(too_large(len(raw), limit)["error"])
    if not raw.strip():
        return {}
    try:
        request = decode(raw)
    except PayloadError as exc:
        raise RequestError(str(exc)) from None
    if not isinstance(request, dict):
        raise RequestError(f"request must be a JSON object, not {type(request).__name__}")
    unknown, more = unknown_keys(request, fields)
    if unknown:
        allowed = ", ".join(sorted(fields)) if fields else "none"
        raise RequestError(f"unknown field(s) {', '.join(map(repr, unknown))}{and_more(more)} (allowed: {allowed})")
    return {key: fields[key](key, value) for key, value in request.items()}


@dataclass(frozen=True)
class Service:
    fields: Mapping[str, Validator]
    run: Callable[[dict[str, Any]], Awaitable[Reply]] | None = None  # changes state: on the asyncio thread
    read: Callable[[dict[str, Any]], Reply] | None = None  # read-only: answered on any thread

    @property
    def limit(self) -> int:
        return request_limit(self.fields)


class Services:
    def __init__(
        self, engine: CycleLink, timeout: float = DEFAULT_TIMEOUT, *, lane: LargePayloadWorker | None = None
    ) -> None:
        self.engine = engine
        self.timeout = timeout
        self.lane = lane or LargePayloadWorker()
        self._read_cache: dict[str, tuple[int, float, bytes]] = {}  # service → (change_seq, monotonic, reply)
        self.table: dict[str, Service] = {
            "status": Service({}, read=self._status),
            "list_controllers": Service({}, read=self._list_controllers),
            "switch_controllers": Service({"activate": names, "deactivate": names, "strict": boolean}, self._switch),
            "list_interfaces": Service({}, read=self._list_interfaces),
            "list_hardware": Service({}, read=self._list_hardware),
            "estop": Service({}, self._estop),
            "reset": Service({}, self._reset),
            "set_zero": Service({"joint": joint_name, "confirm": boolean}, self._set_zero),
            "enable": Service({"joints": names}, self._enable),
            "list_controller_types": Service({}, read=self._list_controller_types),
            "load_controller": Service(
                {"name": controller_name, "type": text, "params": mapping, "fallback_controllers": names, "by": sender},
                self._load,
            ),
            "configure_controller": Service({"name": controller_name}, self._configure),
            "unload_controller": Service({"name": controller_name}, self._unload),
            "reload_controller": Service({"name": controller_name}, self._reload),
            "list_parameters": Service({"controller": controller_name}, read=self._list_parameters),
            "get_parameters": Service({"controller": controller_name, "names": names}, read=self._get_parameters),
            "set_parameters": Service(
                {"controller": controller_name, "values": mapping, "by": sender}, self._set_parameters
            ),
            "tuned_config": Service({}, self._tuned_config),
        }

    async def handle(self, name: str, raw: bytes, *, timeout: float | None = None) -> Reply:
        """Serve one request on the asyncio thread; always returns a reply with ``ok`` and ``error``. ``timeout``:
        wait at most that long for the cycle (never longer than the services' own timeout)."""
        asked = _ASKED_TIMEOUT.set(timeout)
        try:
            return await self._handle(name, raw)
        finally:
            _ASKED_TIMEOUT.reset(asked)

    async def _handle(self, name: str, raw: bytes) -> Reply:
        service = self.table.get(name)
        try:
            if service is None:
                raise RequestError(f"unknown service {name!r} (known: {', '.join(self.table)})")
            if self.lane.needed(raw):  # never a legitimate request, but decoding it must not stall the loop
                request = await self.lane.run(lambda: parse_request(raw, service.fields))
            else:
                request = parse_request(raw, service.fields)
            body = service.read(request) if service.read is not None else await self._run(service, request)
        except Exception as exc:
            return self._failed(name, exc)
        return ok(body)

    def limit(self, name: str) -> int:
        """The size limit of a request to service ``name``, in bytes (an unknown one: the payload limit)."""
        service = self.table.get(name)
        return MAX_PAYLOAD if service is None else service.limit

    @property
    def read_only(self) -> frozenset[str]:
        """The services :meth:`read` can answer on any thread."""
        return frozenset(name for name, service in self.table.items() if service.read is not None)

    def readable(self, name: str, raw: bytes) -> bool:
        """Whether :meth:`read` answers this request here and now: a read-only service, a small payload."""
        service = self.table.get(name)
        return service is not None and service.read is not None and not self.lane.needed(raw)

    def read(self, name: str, raw: bytes) -> bytes:
        """Serve a request :meth:`readable` admitted, on the caller's thread: the encoded reply, with ``ok``.

        A request without fields is answered from a reply at most ``READ_MAX_AGE`` old built since the engine's
        last change (``change_seq``: modes, faults, controllers): a client that switches and then asks sees the
        switch, and a 10 kHz poll costs five builds a second, not ten thousand."""
        empty = raw.strip() in EMPTY_REQUESTS
        change, now = self.engine.change_seq, time.monotonic()
        if empty:
            cached = self._read_cache.get(name)
            if cached is not None and cached[0] == change and now - cached[1] <= READ_MAX_AGE:
                return cached[2]
        service = self.table[name]
        assert service.read is not None
        try:
            reply = ok(service.read(parse_request(raw, service.fields)))
        except Exception as exc:
            return encode(self._failed(name, exc))
        encoded = encode(reply)
        if empty:
            self._read_cache[name] = (change, now, encoded)
        return encoded

    @staticmethod
    async def _run(service: Service, request: dict[str, Any]) -> Reply:
        assert service.run is not None
        return await service.run(request)

    @staticmethod
    def _failed(name: str, exc: Exception) -> Reply:
        if isinstance(exc, Refused):
            return {**exc.details, "ok": False, "error": str(exc)}
        if isinstance(exc, RequestError):
            return {"ok": False, "error": str(exc)}
        log.exception("service %s failed", name, exc_info=exc)  # a bug must cost one reply, not the daemon
        return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"}

    # ---- the cycle hop ------------------------------------------------------------------------------------------
    async def on_cycle(self, request: Request) -> Any:
        """Have the cycle apply ``request`` between two cycles and return its reply; :class:`Refused` when it
        refuses, RequestError after ``timeout``."""
        return await self.wait_cycle(self.engine.request(request))

    async def wait_cycle(self, future: concurrent.futures.Future[Any]) -> Any:
        """Await a request the cycle will apply; withdraw it if the cycle does not get to it in time and it can
        still be withdrawn (only in the in-process case: a request in the shared region's queue cannot)."""
        timeout = self.wait_limit()
        try:
            return await asyncio.wait_for(asyncio.wrap_future(future), timeout)
        except TimeoutError:
            # wait_for's cancellation reaches the request's future: the in-process engine withdraws it if it is
            # still queued; RemoteCycle marks its futures running once queued, so those may still apply.
            if not (future.cancel() or future.cancelled()):
                raise RequestError(
                    f"the cycle took more than {timeout:g} s to apply the request; it may still apply"
                ) from None
            raise RequestError(
                f"cycle not running: the request was not applied within {timeout:g} s and was withdrawn"
            ) from None

    def wait_limit(self) -> float:
        """How long the request being handled may wait for the cycle: its caller's timeout, at most ours."""
        asked = _ASKED_TIMEOUT.get()
        return self.timeout if asked is None else min(asked, self.timeout)

    # ---- services ---------------------------------------------------------------------------------------------
    def _status(self, request: dict[str, Any]) -> Reply:
        return self.engine.status()

    def _list_controllers(self, request: dict[str, Any]) -> Reply:
        return {"controllers": [dict(c) for c in self.engine.snapshot().controllers]}

    def _list_interfaces(self, request: dict[str, Any]) -> Reply:
        return {"interfaces": [dict(i) for i in self.engine.snapshot().interfaces]}

    def _list_hardware(self, request: dict[str, Any]) -> Reply:
        return {"hardware": [dict(h) for h in self.engine.snapshot().hardware]}

    async def _switch(self, request: dict[str, Any]) -> Reply:
        activate = request.get("activate", [])
        deactivate = request.get("deactivate", [])
        strict = request.get("strict", True)
        if not activate and not deactivate:
            raise RequestError("nothing to switch: give activate and/or deactivate")
        if strict:
            loaded = {c["name"] for c in self.engine.snapshot().controllers}
            unknown = [n for n in (*activate, *deactivate) if n not in loaded]
            if unknown:
                known = ", ".join(sorted(loaded)) or "none"
                raise RequestError(f"unknown controller(s) {', '.join(map(repr, unknown))} (loaded: {known})")
        return dict(await self.on_cycle(Switch(tuple(activate), tuple(deactivate), strict)))  # its own ok/error

    async def _estop(self, request: dict[str, Any]) -> Reply:
        # Bypasses the request queue, so a flood of other requests can never delay or refuse an e-stop.
        return dict(await self.wait_cycle(self.engine.request_estop()))

    async def _reset(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Reset()))

    async def _set_zero(self, request: dict[str, Any]) -> Reply:
        if "joint" not in request:
            raise RequestError('give the joint: {"joint": NAME, "confirm": true}')
        if request.get("confirm") is not True:
            raise RequestError('set-zero redefines the joint\'s position: confirm it with "confirm": true')
        return dict(await self.on_cycle(SetZero(request["joint"])))

    async def _enable(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Enable(tuple(request.get("joints", ())))))

    # ---- controller lifecycle (docs/protocol.md, "Controllers while the robot runs") -------------------------------
    def _list_controller_types(self, request: dict[str, Any]) -> Reply:
        return {"types": [{"type": name, "class": where} for name, where in plugins.sources(plugins.CONTROLLERS)]}

    async def _load(self, request: dict[str, Any]) -> Reply:
        """Checked here as ``hild check`` checks the config's controllers; built and adopted by the cycle."""
        name = _required(request, "name")
        if name == MANAGER:
            raise RequestError(f"{MANAGER!r} names the daemon's own parameters: choose another name")
        loaded = {c["name"] for c in self.engine.snapshot().controllers}
        if name in loaded:
            raise RequestError(f"controller {name!r} is already loaded (reload it, or unload it first)")
        if len(loaded) >= MAX_CONTROLLERS:
            raise RequestError(f"{len(loaded)} controllers are loaded: at most {MAX_CONTROLLERS}; unload one first")
        section = {k: v for k, v in request.items() if k not in ("name", "by")}
        if "type" not in section:
            raise RequestError('give the controller\'s type: {"name": NAME, "type": TYPE, "params": {...}}')
        checked = self._checked(name, section, loaded, "request")
        load = Load(name, checked.type, checked.params, checked.fallbacks, source=f"by {request.get('by', 'a client')}")
        return dict(await self.on_cycle(load))

    async def _configure(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Configure(self._loaded(request))))

    async def _unload(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Unload(self._loaded(request))))

    async def _reload(self, request: dict[str, Any]) -> Reply:
        """Replace a controller that is not active with a new one built from the config file as it is on disk now
        (the same file the daemon started from); not loaded, it is loaded."""
        name = _required(request, "name")
        path = self.engine.loaded.path
        try:
            on_disk = await asyncio.to_thread(load_config, path)
        except ConfigError as exc:
            raise RequestError(f"{path} does not load, so nothing was reloaded:\n{exc}") from None
        section = on_disk.config.controllers.get(name)
        if section is None:
            raise RequestError(f"{path} has no controller {name!r}: nothing to reload it from")
        loaded = {c["name"] for c in self.engine.snapshot().controllers}
        raw = {"type": section.type, "params": section.params, "fallback_controllers": section.fallback_controllers}
        checked = self._checked(name, raw, loaded, str(path))
        load = Load(
            name, checked.type, checked.params, checked.fallbacks, replaces=name in loaded, source=f"from {path}"
        )
        return dict(await self.on_cycle(load))

    def _checked(self, name: str, section: dict[str, Any], loaded: set[str], source: str) -> Any:
        try:
            return check_controller(self.engine.loaded, name, section, loaded, source)
        except ConfigError as exc:
            raise RequestError(f"controller {name!r} was not loaded:\n{exc}") from None

    def _loaded(self, request: dict[str, Any]) -> str:
        name = _required(request, "name")
        loaded = {c["name"] for c in self.engine.snapshot().controllers}
        if name not in loaded:
            known = ", ".join(sorted(loaded)) or "none"
            raise RequestError(f"unknown controller {name!r} (loaded: {known})")
        return name

    # ---- parameters (docs/protocol.md, "Parameters while the robot runs") --------------------------------------------
    def _controller(self, request: dict[str, Any]) -> tuple[str, Any]:
        """The controller named in ``request`` (its API half: its params are what the cycle's are), or the daemon's
        own parameters (``controller_manager``: always active, so only its dynamic ones change)."""
        name = _required(request, "controller")
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
        spec = next(c for c in self.engine.snapshot().controllers if c["name"] == name)
        section = {"type": spec["type"], "params": params.model_dump(mode="json")}
        loaded = {c["name"] for c in self.engine.snapshot().controllers}
        checked = self._checked(name, section, loaded, "request")
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
        hold = {joint: (t.hold.kp, t.hold.kd) for joint, t in snapshot.tuning.joints.items()}
        try:
            text, changed = await asyncio.to_thread(tuned_copy, path, controllers, hold)
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


def _required(request: dict[str, Any], field: str) -> Any:
    if field not in request:
        raise RequestError(f"give the {field}: {{{field!r}: ...}}".replace("'", '"'))
    return request[field]
