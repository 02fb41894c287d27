"""The daemon's Zenoh face: state out, services and commands in (docs/protocol.md has the wire format).

Threads: Zenoh calls our handlers on its own threads; every handler only copies the payload out and hops to the
asyncio loop, where all the work happens. The cycle thread is reached only through ``engine.submit`` and read
back through ring readers and ``engine.status()``, so the API shares no lock with it. Every publisher uses
congestion control DROP: a slow subscriber loses samples, it never stalls the loop or the cycle.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from hild.api.codec import encode
from hild.api.keys import SERVICES, Keys
from hild.api.ports import ControllerPorts, Counters
from hild.api.queries import BUSY, MAX_IN_FLIGHT, SHUTTING_DOWN, drop, read_payload, reply_json, too_large
from hild.api.services import DEFAULT_TIMEOUT, Reply, Services
from hild.api.session import declare_json_publisher, open_session, server_config
from hild.config.model import ZenohSection
from hild.engine import Engine
from hild.events import Event

log = logging.getLogger("hild.api")

STATUS_PERIOD = 0.2  # s: status is published at 5 Hz, and at once when modes, faults or controllers change


class ApiServer:
    def __init__(
        self,
        engine: Engine,
        settings: ZenohSection,
        listen: list[str] | None = None,
        *,
        request_timeout: float = DEFAULT_TIMEOUT,
        status_period: float = STATUS_PERIOD,
    ) -> None:
        self.engine = engine
        self.settings = settings
        self.listen = listen
        self.keys = Keys(engine.robot)
        self.services = Services(engine, request_timeout)
        self.status_period = status_period
        self.counters = Counters()
        self.session: zenoh.Session | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ports: ControllerPorts | None = None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._queryables: list[zenoh.Queryable[Any]] = []
        self._token: zenoh.LivelinessToken | None = None
        self._status_task: asyncio.Task[None] | None = None
        self._requests: set[asyncio.Task[None]] = set()
        self._last_change: int | None = None
        self._closing = False

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    async def start(self) -> None:
        """Open the session and declare everything; the liveliness token comes last, once services answer."""
        self._loop = asyncio.get_running_loop()
        directory = getattr(getattr(self.engine, "loaded", None), "directory", None)
        config = server_config(self.settings, self.listen, directory)
        endpoints = endpoints_of(self.settings, self.listen)
        try:
            self.session = open_session(config)
        except ConnectionError as exc:
            what = f"{self.settings.mode}, listen {endpoints}"
            raise ConnectionError(f"cannot open the Zenoh session ({what}): {exc}") from None
        try:
            self._declare(self.session, self._loop)
        except BaseException:
            await self.close()
            raise
        self._status_task = self._loop.create_task(self._status_loop(), name="hild-api-status")
        log.info("Zenoh API up: %s (%s, listen %s)", self.keys.root, self.settings.mode, endpoints)

    def _declare(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        for name in (self.keys.status, self.keys.events):
            self._publishers[name] = declare_json_publisher(session, name)
        self._ports = ControllerPorts(session, self.engine, self.keys, loop, self.counters)
        self._ports.sync()
        self._last_change = self.engine.change_seq
        for service in SERVICES:
            self._queryables.append(
                session.declare_queryable(self.keys.service(service), self._query_handler(service), complete=True)
            )
        self._publish_status()
        self._token = session.liveliness().declare_token(self.keys.alive)

    async def close(self) -> None:
        """Withdraw the token first (clients see the daemon go), answer pending requests, then close."""
        self._closing = True
        if self._ports is not None:
            self._ports.closing = True
        if self._token is not None:
            with contextlib.suppress(zenoh.ZError):
                self._token.undeclare()
            self._token = None
        if self._status_task is not None:
            self._status_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._status_task
            self._status_task = None
        for task in list(self._requests):
            task.cancel()
        if self._requests:
            await asyncio.gather(*self._requests, return_exceptions=True)
        if self._ports is not None:
            self._ports.close()
            self._ports = None
        entities: list[Any] = [*self._queryables, *self._publishers.values()]
        self._queryables.clear()
        self._publishers.clear()
        for entity in entities:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()
        if self.session is not None:
            with contextlib.suppress(zenoh.ZError):
                self.session.close()
            self.session = None

    # ---- publishing (asyncio thread) ----------------------------------------------------------------------------
    def publish(self, events: list[Event]) -> None:
        """The doorbell rang: publish events, new output samples, and status if anything changed."""
        if self.session is None or self._closing:
            return
        events_pub = self._publishers[self.keys.events]
        for event in events:
            self._put(events_pub, event.as_dict())
        self._check_changes()
        assert self._ports is not None
        self._ports.flush()

    def _check_changes(self) -> bool:
        seq = self.engine.change_seq
        if seq == self._last_change:
            return False
        self._last_change = seq
        assert self._ports is not None
        self._ports.sync()
        self._publish_status()
        return True

    def _publish_status(self) -> None:
        try:
            status = self.engine.status()
        except Exception:  # read back while the cycle changes it (rare); the next period retries
            log.debug("status read failed", exc_info=True)
            return
        self._put(self._publishers[self.keys.status], status)

    def _put(self, publisher: zenoh.Publisher, message: dict[str, Any]) -> None:
        try:
            publisher.put(encode(message))
            self.counters.published += 1
        except zenoh.ZError:
            self.counters.publish_errors += 1

    async def _status_loop(self) -> None:
        while True:
            await asyncio.sleep(self.status_period)
            try:
                if not self._check_changes():
                    self._publish_status()
            except Exception:
                log.exception("status publication failed")

    # ---- services -----------------------------------------------------------------------------------------------
    def _query_handler(self, service: str) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:  # a Zenoh thread: size check, copy out, hop to the loop
            try:
                raw, size = read_payload(query)
                if raw is None:
                    self._reply(service, query, too_large(size))
                    return
                assert self._loop is not None
                self._loop.call_soon_threadsafe(self._start_request, service, query, raw)
            except RuntimeError:  # the loop is closed: let the client time out quickly
                drop(query)

        return on_query

    def _start_request(self, service: str, query: zenoh.Query, raw: bytes) -> None:
        self.counters.queries += 1
        if self._closing:
            self._reply(service, query, SHUTTING_DOWN)
        elif len(self._requests) >= MAX_IN_FLIGHT:
            self._reply(service, query, BUSY)
        else:
            assert self._loop is not None
            task = self._loop.create_task(self._serve(service, query, raw))
            self._requests.add(task)
            task.add_done_callback(self._requests.discard)

    async def _serve(self, service: str, query: zenoh.Query, raw: bytes) -> None:
        try:
            reply = await self.services.handle(service, raw)
        except asyncio.CancelledError:
            self._reply(service, query, SHUTTING_DOWN)
            raise
        self._reply(service, query, reply)

    def _reply(self, service: str, query: zenoh.Query, reply: Reply) -> None:
        reply_json(query, self.keys.service(service), reply)


def endpoints_of(settings: ZenohSection, listen: Sequence[str] | None) -> list[str]:
    """Where the daemon listens: the command-line override, else the config."""
    return list(listen if listen is not None else settings.listen)
