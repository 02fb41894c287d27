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
from collections.abc import Callable
from typing import Any

from hild.api.codec import MAX_PAYLOAD, encode
from hild.api.fields import (
    EMPTY_REQUEST,
    FIELDS_REQUEST,
    MAX_NAMES,
    Reply,
    RequestError,
    Service,
    boolean,
    joint_name,
    names,
    ok,
    parse_request,
    text,
)
from hild.api.lifecycle import ControllerLifecycle, loaded_names
from hild.api.parameters import ControllerParameters
from hild.api.queries import LargePayloadWorker, clip
from hild.api.record import RecorderFace, RecordServices
from hild.api.teach import TeachService
from hild.crossing.requests import Enable, Estop, Home, Refused, Request, Reset, SetHardwareState, SetZero, Switch
from hild.daemon.link import CycleLink
from hild.record.events import reply_event, request_event
from hild.record.model import RecordedEvent

__all__ = [  # the request checks live in hild.api.fields; these names stay importable from here too
    "DEFAULT_TIMEOUT",
    "EMPTY_REQUEST",
    "FIELDS_REQUEST",
    "MAX_NAMES",
    "Reply",
    "RequestError",
    "Services",
    "boolean",
    "joint_name",
    "names",
    "parse_request",
]

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


class Services:
    def __init__(
        self,
        engine: CycleLink,
        timeout: float = DEFAULT_TIMEOUT,
        *,
        lane: LargePayloadWorker | None = None,
        recorder: RecorderFace | None = None,
    ) -> None:
        """``recorder``: the daemon's episode recorder (hild/record/recorder.py); None when recording is disabled,
        which the ``record`` and ``blackbox`` services then say."""
        self.engine = engine
        self.timeout = timeout
        self.lane = lane or LargePayloadWorker()
        # Every request sent to the cycle goes into the recording (its type and fields, never the client's bytes).
        self._record: Callable[[RecordedEvent], None] | None = getattr(recorder, "log", None)
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
            "home": Service({"joint": joint_name}, self._home),
            "enable": Service({"joints": names}, self._enable),
            "set_hardware_state": Service({"name": text, "state": text}, self._set_hardware_state),
        }
        lifecycle = ControllerLifecycle(engine, self.on_cycle)
        self.table.update(lifecycle.services())
        self.table.update(ControllerParameters(engine, self.on_cycle, lifecycle.checked).services())
        self.table.update(TeachService(engine, self.on_cycle, lifecycle).services())
        self.table.update(RecordServices(recorder, engine.update_rate).services())

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
        except Exception as exc:  # sent as encoded here: clipped here, as the API clips every other reply's error
            failed = self._failed(name, exc)
            return encode({**failed, "error": clip(failed["error"])})
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
        return await self._recorded(request, self.engine.request(request))

    async def _recorded(self, request: Request, future: concurrent.futures.Future[Any]) -> Any:
        """Await the cycle's answer to ``request``; the recorder is handed the request as it is sent and the answer
        (or the error the client gets) when it comes, both on the loop's thread (``log`` never blocks)."""
        record = self._record
        if record is None:
            return await self.wait_cycle(future)
        record(request_event(request, self.engine.t))
        try:
            reply = await self.wait_cycle(future)
        except Exception as exc:
            record(reply_event(request, self.engine.t, str(exc) or type(exc).__name__))
            raise
        record(reply_event(request, self.engine.t, None))
        return reply

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
        snapshot = self.engine.snapshot()
        sensors = [
            {"name": name, "sensor": s["name"], "available": s["available"]}
            for s in snapshot.sensors
            for name in s["state_interfaces"]
        ]
        return {"interfaces": [dict(i) for i in snapshot.interfaces], "state_interfaces": sensors}

    def _list_hardware(self, request: dict[str, Any]) -> Reply:
        snapshot = self.engine.snapshot()
        return {
            "hardware": [
                {**h, "sensors": [dict(s) for s in snapshot.sensors if s["hardware"] == h["name"]]}
                for h in snapshot.hardware
            ]
        }

    async def _switch(self, request: dict[str, Any]) -> Reply:
        activate = request.get("activate", [])
        deactivate = request.get("deactivate", [])
        strict = request.get("strict", True)
        if not activate and not deactivate:
            raise RequestError("nothing to switch: give activate and/or deactivate")
        if strict:
            loaded = loaded_names(self.engine)
            unknown = [n for n in (*activate, *deactivate) if n not in loaded]
            if unknown:
                known = ", ".join(sorted(loaded)) or "none"
                raise RequestError(f"unknown controller(s) {', '.join(map(repr, unknown))} (loaded: {known})")
        return dict(await self.on_cycle(Switch(tuple(activate), tuple(deactivate), strict)))  # its own ok/error

    async def _estop(self, request: dict[str, Any]) -> Reply:
        # Bypasses the request queue, so a flood of other requests can never delay or refuse an e-stop.
        return dict(await self._recorded(Estop(), self.engine.request_estop()))

    async def _reset(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Reset()))

    async def _set_zero(self, request: dict[str, Any]) -> Reply:
        if "joint" not in request:
            raise RequestError('give the joint: {"joint": NAME, "confirm": true}')
        if request.get("confirm") is not True:
            raise RequestError('set-zero redefines the joint\'s position: confirm it with "confirm": true')
        return dict(await self.on_cycle(SetZero(request["joint"])))

    async def _home(self, request: dict[str, Any]) -> Reply:
        """Starts the drive's homing and answers at once (it takes longer than a reply may wait): the status's
        ``homing`` entry of the joint, and the events, tell how it ends (docs/protocol.md, ``home``)."""
        if "joint" not in request:
            raise RequestError('give the joint: {"joint": NAME}')
        return dict(await self.on_cycle(Home(request["joint"])))

    async def _enable(self, request: dict[str, Any]) -> Reply:
        return dict(await self.on_cycle(Enable(tuple(request.get("joints", ())))))

    async def _set_hardware_state(self, request: dict[str, Any]) -> Reply:
        """``inactive``: the component's joints are held and no controller may command them; ``active`` again."""
        if "name" not in request or "state" not in request:
            raise RequestError('give the component and its state: {"name": NAME, "state": "active" | "inactive"}')
        return dict(await self.on_cycle(SetHardwareState(request["name"], request["state"])))
