"""The daemon's Zenoh face: state out, services and commands in (docs/protocol.md has the wire format).

It runs in the client domain and reaches the cycle only through a ``CycleLink`` (``self.engine``): requests through
``request`` and ``request_estop``, read back through ``status()``, ``snapshot()``, ``change_seq`` and the
controllers' output rings, so the API shares no lock with the cycle (docs/architecture.md, "Three processes").

Threads: no thread takes the GIL per poll. Controller input samples, with the cycle in its own process (the default:
``inputs_on_arrival``), are decoded and validated on the Zenoh thread they arrive on, whose GIL is the client
domain's alone, and go into the controller's cell of the shared region. In the in-process case (the cycle a thread
of this process) Zenoh queues them without Python and the cycle takes them at the start of each cycle
(``ControllerPorts.take_inputs``, handed to the engine as its ``take_inputs``): one GIL hand-over per cycle, not per
sample (docs/performance.md, "Where the time goes"). Read-only queries (status, list_*) are queued by Zenoh as well
and answered in batches on the asyncio loop when it wakes anyway, or every ``READ_PERIOD``, from a recent reply.
Other queries (switch, e-stop, goals …) call our handlers on Zenoh's threads, which copy them out and hop to the
loop, where they run. Every publisher uses congestion control DROP: a slow subscriber loses samples, it never stalls
the loop or the cycle.

Goal senders' liveliness tokens are watched (hild/api/goal_senders.py): when one goes away, each controller's goal
endpoint hands the sender's running goals to the cycle (``_client_gone``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import zenoh

from hild.api.goal_senders import watch_clients
from hild.api.goals import GoalEndpoint
from hild.api.keys import SERVICES, Keys
from hild.api.ports import ControllerPorts, Counters
from hild.api.queries import (
    SHUTTING_DOWN,
    Admitted,
    LargePayloadWorker,
    QueryAdmission,
    ReadBacklog,
    drop,
    reply_json,
)
from hild.api.record import RecorderFace
from hild.api.services import DEFAULT_TIMEOUT, Reply, Services
from hild.api.session import declare_json_publisher, open_session, server_config
from hild.api.unique import DaemonIdentity, check_unique, describe_other
from hild.config.model import Ros2Section, ZenohSection
from hild.crossing.events import Event
from hild.daemon.link import CycleLink

if TYPE_CHECKING:
    from hild.api.ros2.face import RosFace

log = logging.getLogger("hild.api")

STATUS_PERIOD = 0.2  # s: status is published at 5 Hz, and at once when modes, faults or controllers change
PRIORITY_SERVICES = frozenset({"estop"})  # their own gate: a flood of other requests never refuses an e-stop
READ_PERIOD = 0.01  # s: queued read-only queries wait at most this long when nothing else wakes the loop


class ApiServer:
    def __init__(
        self,
        engine: CycleLink,
        settings: ZenohSection,
        listen: list[str] | None = None,
        *,
        request_timeout: float = DEFAULT_TIMEOUT,
        status_period: float = STATUS_PERIOD,
        pid: int | None = None,
        recorder: RecorderFace | None = None,
    ) -> None:
        """``pid``: the process an operator stops to stop this daemon, which a refused second daemon names (under
        ``hild run``, the main process; default: this one). ``recorder``: what the ``record`` and ``blackbox``
        services ask (None: recording is disabled)."""
        self.engine = engine
        self.pid = pid
        self.settings = settings
        self.listen = listen
        self.keys = Keys(engine.robot)
        self.lane = LargePayloadWorker()  # shared by services and controller endpoints: one large payload at a time
        self.services = Services(engine, request_timeout, lane=self.lane, recorder=recorder)
        self.status_period = status_period
        self.counters = Counters()
        self.session: zenoh.Session | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ports: ControllerPorts | None = None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._queryables: list[zenoh.Queryable[Any]] = []
        self._token: zenoh.LivelinessToken | None = None
        self._identity: DaemonIdentity | None = None
        self._client_watch: zenoh.Subscriber[Any] | None = None
        self._status_task: asyncio.Task[None] | None = None
        self._reads_task: asyncio.Task[None] | None = None
        self._read_queues: list[tuple[str, ReadBacklog]] = []  # each read-only service's waiting queries
        self._requests: set[asyncio.Task[None]] = set()
        self._gate = QueryAdmission()
        self._priority_gate = QueryAdmission()
        self._last_change: int | None = None
        self._closing = False
        self._ros: RosFace | None = None  # when the config has a ros2 section (docs/ros2.md)

    # ---- lifecycle ----------------------------------------------------------------------------------------------
    async def open(self) -> None:
        """Open the session and claim the robot's name: raise ``RobotNameTaken`` if another daemon of this robot is
        on the network. The daemon calls this before it touches any hardware (one of the same arm on the same bus
        must not even open it); ``start`` then declares the rest."""
        self._loop = asyncio.get_running_loop()
        directory = getattr(getattr(self.engine, "loaded", None), "directory", None)
        config = server_config(self.settings, self.listen, directory, timestamping=self._ros_settings() is not None)
        endpoints = endpoints_of(self.settings, self.listen)
        try:
            self.session = open_session(config)
        except ConnectionError as exc:
            what = f"{self.settings.mode}, listen {endpoints}"
            raise ConnectionError(f"cannot open the Zenoh session ({what}): {exc}") from None
        try:
            check_unique(self.session, self.keys)  # before anything is declared
            # Claimed at once, so a daemon of this robot starting while our hardware comes up sees us.
            on_other = self._other_daemon(self._loop)
            self._identity = DaemonIdentity(self.session, self.keys, endpoints, on_other, self.pid)
        except BaseException:
            await self.close()
            raise

    async def start(self) -> None:
        """Declare everything (opening the session first unless ``open`` did); the liveliness token comes last,
        once services answer."""
        if self.session is None:
            await self.open()
        assert self.session is not None and self._loop is not None
        try:
            self._declare(self.session, self._loop)
        except BaseException:
            await self.close()
            raise
        self._status_task = self._loop.create_task(self._status_loop(), name="hild-api-status")
        self._reads_task = self._loop.create_task(self._read_loop(), name="hild-api-reads")
        endpoints = endpoints_of(self.settings, self.listen)
        log.info("Zenoh API up: %s (%s, listen %s)", self.keys.root, self.settings.mode, endpoints)

    def _declare(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        for name in (self.keys.status, self.keys.events):
            self._publishers[name] = declare_json_publisher(session, name)
        self._ports = ControllerPorts(session, self.engine, self.keys, loop, self.counters, self.lane)
        self._ports.sync()
        self.engine.take_inputs = self._ports.take_inputs
        self._last_change = self.engine.change_seq
        for service in SERVICES:
            key = self.keys.service(service)
            if service in self.services.read_only:  # held as they arrive, answered in batches on the loop
                backlog = ReadBacklog(key)
                self._read_queues.append((service, backlog))
                self._queryables.append(session.declare_queryable(key, backlog, complete=True))
            else:
                self._queryables.append(session.declare_queryable(key, self._query_handler(service), complete=True))
        self._publish_status()
        self._watch_clients(session, loop)
        self._start_ros(session, loop)
        self._token = session.liveliness().declare_token(self.keys.alive)

    def withdraw(self) -> None:
        """Withdraw the ``alive`` token: clients watching it see the robot go at once, though its stop (a descent,
        the hardware's release) has only begun. The ``daemon/<zid>`` token stays until ``close``: the name is not
        free for a second daemon of this arm while this one still drives it."""
        if self._token is not None:
            with contextlib.suppress(zenoh.ZError):
                self._token.undeclare()
            self._token = None

    async def close(self) -> None:
        """Withdraw the token first (clients see the daemon go), answer pending requests, then close."""
        self._closing = True
        self.engine.take_inputs = None
        if self._ports is not None:
            self._ports.closing = True
        self.withdraw()
        if self._ros is not None:
            self._ros.close()
            self._ros = None
        if self._identity is not None:
            self._identity.close()
            self._identity = None
        if self._client_watch is not None:
            with contextlib.suppress(zenoh.ZError):
                self._client_watch.undeclare()
            self._client_watch = None
        for task in (self._status_task, self._reads_task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._status_task = self._reads_task = None
        for task in list(self._requests):
            task.cancel()
        if self._requests:
            await asyncio.gather(*self._requests, return_exceptions=True)
        if self._ports is not None:
            self._ports.close()
            self._ports = None
        entities: list[Any] = [*self._queryables, *self._publishers.values()]
        for service, backlog in self._read_queues:  # what still waits gets its one reply
            while (query := backlog.take()) is not None:
                self._reply(service, query, SHUTTING_DOWN)
        self._read_queues.clear()
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
        """The cycle woke us: publish events, new output samples, and status if anything changed. Between ``open``
        and ``start`` nothing is declared yet: the daemon logs the events, none are published."""
        if self.session is None or self._closing or self._ports is None:
            return
        self.answer_reads()  # the loop is awake anyway: answer what queued since
        events_pub = self._publishers[self.keys.events]
        for event in events:
            self.counters.publish(events_pub, event.as_dict())
        self._check_changes()
        assert self._ports is not None
        self._ports.flush()
        if self._ros is not None:
            self._ros.flush()

    def _ros_settings(self) -> Ros2Section | None:
        return getattr(getattr(getattr(self.engine, "loaded", None), "config", None), "ros2", None)

    def _start_ros(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        """The ROS 2 face (docs/ros2.md), only when the config asks for it: rosbags is imported only then."""
        settings = self._ros_settings()
        if settings is None:
            return
        from hild.api.ros2.face import RosFace

        self._ros = RosFace(session, self.engine, self.services, settings, loop)
        self._ros.start()

    def _check_changes(self) -> bool:
        seq = self.engine.change_seq
        if seq == self._last_change:
            return False
        self._last_change = seq
        assert self._ports is not None
        self._ports.sync()
        if self._ros is not None:
            self._ros.sync()
        self._publish_status()
        return True

    def _publish_status(self) -> None:
        try:
            status = self.engine.status()
        except Exception:  # read back while the cycle changes it (rare); the next period retries
            log.debug("status read failed", exc_info=True)
            return
        self.counters.publish(self._publishers[self.keys.status], status)

    # ---- read-only services, in batches (asyncio thread) -------------------------------------------------------
    def answer_reads(self) -> None:
        """Answer every waiting status/list_* query. They wait in a bounded backlog (``ReadBacklog``: one beyond it
        is answered "busy" as it arrives); answering them here, when the loop wakes anyway (publishing) or every
        ``READ_PERIOD``, costs no loop wake-up per query (docs/performance.md, "Where the time goes")."""
        if self._closing:
            return
        for service, backlog in self._read_queues:
            while (query := backlog.take()) is not None:
                self._answer_read(service, query)

    def _answer_read(self, service: str, query: zenoh.Query) -> None:
        admitted = self._gate.admit(query, self.services.limit(service))
        if not isinstance(admitted, Admitted):
            self._reply(service, query, admitted)
        elif self.services.readable(service, admitted.raw):
            self._read(service, query, admitted)
        else:  # a large payload on a read-only service: parsed by the large-payload worker, like any other request
            self._start_request(service, query, admitted)

    async def _read_loop(self) -> None:
        while True:
            await asyncio.sleep(READ_PERIOD)
            try:
                self.answer_reads()
            except Exception:
                log.exception("answering queued queries failed")

    async def _status_loop(self) -> None:
        while True:
            await asyncio.sleep(self.status_period)
            try:
                if not self._check_changes():
                    self._publish_status()
            except Exception:
                log.exception("status publication failed")

    # ---- one robot name, one daemon -----------------------------------------------------------------------------
    def _other_daemon(self, loop: asyncio.AbstractEventLoop) -> Callable[[str], None]:
        owner = weakref.ref(self)

        def on_other(zid: str) -> None:  # a Zenoh thread: hop to the loop (the report queries, which may block)
            me = owner()
            if me is not None:
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(lambda: loop.create_task(me._report_other(zid)))

        return on_other

    async def _report_other(self, zid: str) -> None:
        if self._closing or self.session is None:
            return
        where = await asyncio.to_thread(describe_other, self.session, self.keys, zid)
        text = (
            f"another daemon of robot {self.engine.robot!r} appeared on this Zenoh network ({where}): both obey every "
            "command sent to this robot. Stop one of them"
        )
        log.error("%s", text)
        self.engine.events.emit("error", "api", text)

    # ---- goal senders' liveliness -------------------------------------------------------------------------------
    def _watch_clients(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        owner = weakref.ref(self)  # weakly, as for queries

        def on_gone(client: str) -> None:  # a Zenoh thread: hop to the loop
            me = owner()
            if me is None:
                return
            with contextlib.suppress(RuntimeError):  # the loop is closed
                loop.call_soon_threadsafe(me._client_gone, client)

        self._client_watch = watch_clients(session, self.engine.robot, on_gone)

    def _client_gone(self, client: str) -> None:
        """A goal sender's token went away: every controller running its goals is told (asyncio thread)."""
        if self._closing:
            return
        try:
            instances = list(self.engine.controllers().values())
        except RuntimeError:  # controllers loaded meanwhile: try again on the next turn of the loop
            assert self._loop is not None
            self._loop.call_soon(self._client_gone, client)
            return
        told: list[str] = []
        for instance in instances:
            try:
                server = instance.action_server()
                if server is not None:
                    told += GoalEndpoint.of(server).client_lost(client)
            except Exception:  # a plugin's bug must not keep the other controllers from being told
                log.exception("telling %s that client %s is gone failed", type(instance).__name__, client)
        if told:
            self.engine.events.emit(
                "warning", "api", f"client {client} is gone; its running goals {told} follow on_client_lost"
            )

    # ---- services -----------------------------------------------------------------------------------------------
    def _query_handler(self, service: str) -> Callable[[zenoh.Query], None]:
        gate = self._priority_gate if service in PRIORITY_SERVICES else self._gate
        limit = self.services.limit(service)  # bytes: larger is refused before it is copied
        # Zenoh may hold the callback past undeclare and session close; a weak reference keeps it from holding
        # the server, and through it the engine, alive until the interpreter exits.
        server = weakref.ref(self)

        def on_query(query: zenoh.Query) -> None:  # a Zenoh thread: admit (size, cap), copy out, hop to the loop
            me = server()
            if me is None or me._loop is None:
                drop(query)
                return
            admitted = gate.admit(query, limit)
            if not isinstance(admitted, Admitted):
                me._reply(service, query, admitted)
                return
            try:
                me._loop.call_soon_threadsafe(me._start_request, service, query, admitted)
            except RuntimeError:  # the loop is closed: let the client time out quickly
                admitted.release()
                drop(query)

        return on_query

    def _start_request(self, service: str, query: zenoh.Query, admitted: Admitted) -> None:
        with self.counters.lock:
            self.counters.queries += 1
        if self._closing:
            admitted.release()
            self._reply(service, query, SHUTTING_DOWN)
            return
        assert self._loop is not None
        task = self._loop.create_task(self._serve(service, query, admitted.raw))
        self._requests.add(task)
        task.add_done_callback(self._requests.discard)
        task.add_done_callback(lambda _: admitted.release())

    def _read(self, service: str, query: zenoh.Query, admitted: Admitted) -> None:
        """A read-only service, answered from the services' recent reply."""
        with self.counters.lock:
            self.counters.queries += 1
        try:
            self._reply(service, query, SHUTTING_DOWN if self._closing else self.services.read(service, admitted.raw))
        finally:
            admitted.release()

    async def _serve(self, service: str, query: zenoh.Query, raw: bytes) -> None:
        try:
            reply = await self.services.handle(service, raw)
        except asyncio.CancelledError:
            self._reply(service, query, SHUTTING_DOWN)
            raise
        self._reply(service, query, reply)

    def _reply(self, service: str, query: zenoh.Query, reply: Reply | bytes) -> None:
        reply_json(query, self.keys.service(service), reply)


def endpoints_of(settings: ZenohSection, listen: Sequence[str] | None) -> list[str]:
    """Where the daemon listens: the command-line override, else the config."""
    return list(listen if listen is not None else settings.listen)
