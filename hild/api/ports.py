"""Controller inputs and outputs on Zenoh: one subscriber per input, one publisher per output ring.

Inputs arrive on Zenoh threads; each sample is size-checked there, then handed to the asyncio loop, where it is
decoded and given to the controller's input callable (which validates it and swaps it into a mailbox). Anything
wrong drops that sample and emits a warning event: nothing moves on bad input. Warnings are rate-limited per key
so a client streaming garbage at 1 kHz cannot flood the event log.

Outputs are read from each controller's :class:`~hild.ring.SampleRing` through a private reader and published
with congestion control DROP: under back-pressure old samples are lost, the loop is never held.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from hild.action import ActionServer
from hild.api.codec import MAX_PAYLOAD, PayloadError, decode, encode
from hild.api.keys import RESERVED, Keys, check_chunk
from hild.api.queries import BUSY, MAX_IN_FLIGHT, SHUTTING_DOWN, drop, read_payload, reply_json, too_large
from hild.api.session import declare_json_publisher
from hild.engine import Engine
from hild.ring import RingReader, SampleRing

log = logging.getLogger("hild.api")

REPORTS_PER_WINDOW = 10
REPORT_WINDOW = 1.0  # s


@dataclass
class Counters:
    """What the API has seen; cheap integers, read by tests and diagnostics."""

    commands: int = 0
    accepted: int = 0
    dropped: int = 0
    queries: int = 0
    published: int = 0
    publish_errors: int = 0


class DropReporter:
    """At most ``REPORTS_PER_WINDOW`` warnings per key per window; the rest are counted into the next one."""

    def __init__(self, emit: Callable[[str, str, str], None]) -> None:
        self._emit = emit
        self._windows: dict[str, tuple[float, int, int]] = {}  # key → (window start, reported, suppressed)

    def report(self, source: str, key: str, reason: str) -> None:
        now = time.monotonic()
        start, reported, suppressed = self._windows.get(key, (now, 0, 0))
        if now - start >= REPORT_WINDOW:
            start, reported = now, 0
        if reported >= REPORTS_PER_WINDOW:
            self._windows[key] = (start, reported, suppressed + 1)
            return
        more = f" (+{suppressed} more dropped)" if suppressed else ""
        self._emit("warning", source, f"dropped command on {key}: {reason}{more}")
        self._windows[key] = (start, reported + 1, 0)


@dataclass
class OutputPort:
    topic: str
    ring: SampleRing
    reader: RingReader
    publisher: zenoh.Publisher
    names: list[str] | None

    def messages(self) -> list[dict[str, Any]]:
        """New samples as messages: ``{"stamp", "seq", "name"?, <field>: [...]}``."""
        out = []
        for seq, stamp, fields in self.reader.read():
            msg: dict[str, Any] = {"stamp": stamp, "seq": seq}
            if self.names is not None:
                msg["name"] = self.names
            msg.update(fields)
            out.append(msg)
        return out


@dataclass
class ActionPort:
    """A controller's goal endpoint: queryables goal/cancel/result, publishers feedback/result."""

    server: ActionServer[Any]
    feedback: zenoh.Publisher
    result: zenoh.Publisher
    queryables: list[zenoh.Queryable[Any]] = field(default_factory=list)


@dataclass
class ControllerEndpoints:
    instance: object
    subscribers: list[zenoh.Subscriber[Any]] = field(default_factory=list)
    outputs: list[OutputPort] = field(default_factory=list)
    action: ActionPort | None = None


class ControllerPorts:
    def __init__(
        self,
        session: zenoh.Session,
        engine: Engine,
        keys: Keys,
        loop: asyncio.AbstractEventLoop,
        counters: Counters,
    ) -> None:
        self.session = session
        self.engine = engine
        self.keys = keys
        self.loop = loop
        self.counters = counters
        self.closing = False
        self._drops = DropReporter(engine.events.emit)
        self._controllers: dict[str, ControllerEndpoints] = {}
        self._answering: set[asyncio.Task[None]] = set()

    # ---- declaration ---------------------------------------------------------------------------------------
    def sync(self) -> None:
        """Declare endpoints for newly loaded controllers, undeclare those of unloaded ones (asyncio thread)."""
        try:
            current = {name: rec.instance for name, rec in list(self.engine.manager.records.items())}
        except RuntimeError:  # records changed while we copied; the next change_seq brings us back here
            return
        for name in [n for n, ep in self._controllers.items() if current.get(n) is not ep.instance]:
            self._undeclare(self._controllers.pop(name))
        for name, instance in current.items():
            if name not in self._controllers:
                self._controllers[name] = self._declare(name, instance)

    def _declare(self, name: str, instance: Any) -> ControllerEndpoints:
        endpoints = ControllerEndpoints(instance)
        try:
            check_chunk(name, "controller name")
            inputs = dict(instance.inputs())
            outputs = dict(instance.outputs())
        except Exception as exc:
            self.engine.events.emit("error", "api", f"controller {name}: not exposed on Zenoh: {exc}")
            return endpoints
        for input_name, accept in inputs.items():
            try:
                key = self.keys.input(name, check_chunk(input_name, "input name"))
                endpoints.subscribers.append(
                    self.session.declare_subscriber(key, self._sample_handler(key, name, accept))
                )
            except (ValueError, zenoh.ZError) as exc:
                self.engine.events.emit("error", "api", f"controller {name}: input {input_name!r} not declared: {exc}")
        taken = {p.topic for ep in self._controllers.values() for p in ep.outputs}
        for output_name, ring in outputs.items():
            try:
                check_chunk(output_name, "output name")
                topic = self.keys.topic(output_name)
                if output_name in RESERVED or topic in taken:
                    raise ValueError(f"{topic} is already used")
                publisher = declare_json_publisher(self.session, topic, priority=zenoh.Priority.DATA_HIGH, express=True)
            except (ValueError, zenoh.ZError) as exc:
                self.engine.events.emit(
                    "error", "api", f"controller {name}: output {output_name!r} not published: {exc}"
                )
                continue
            endpoints.outputs.append(OutputPort(topic, ring, RingReader(ring), publisher, self._names(ring)))
        try:
            server = instance.action_server()
            if server is not None:
                endpoints.action = self._declare_action(name, server)
        except (ValueError, zenoh.ZError) as exc:
            self.engine.events.emit("error", "api", f"controller {name}: goals not exposed: {exc}")
        return endpoints

    def _declare_action(self, name: str, server: ActionServer[Any]) -> ActionPort:
        key = functools.partial(self.keys.input, name)
        port = ActionPort(
            server,
            feedback=declare_json_publisher(self.session, key("feedback")),
            result=declare_json_publisher(self.session, key("result"), priority=zenoh.Priority.DATA_HIGH),
        )
        for verb, handle in (("goal", server.submit), ("cancel", server.cancel), ("result", server.result)):
            port.queryables.append(
                self.session.declare_queryable(key(verb), self._query_handler(key(verb), handle), complete=True)
            )
        return port

    def _names(self, ring: SampleRing) -> list[str] | None:
        """Element names of a ring: its own ``names`` if it has them, else the robot's joints when widths match."""
        names: Sequence[str] | None = getattr(ring, "names", None)
        if names is None and ring.width == len(self.engine.joints):
            names = self.engine.joints
        return list(names) if names is not None else None

    @staticmethod
    def _undeclare(endpoints: ControllerEndpoints) -> None:
        action = endpoints.action
        extra: list[Any] = [*action.queryables, action.feedback, action.result] if action else []
        for entity in [*endpoints.subscribers, *(p.publisher for p in endpoints.outputs), *extra]:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()

    def close(self) -> None:
        self.closing = True
        for task in self._answering:
            task.cancel()
        for endpoints in self._controllers.values():
            self._undeclare(endpoints)
        self._controllers.clear()

    # ---- outputs (asyncio thread) --------------------------------------------------------------------------
    def flush(self) -> None:
        """Publish every output sample written since the last flush."""
        for endpoints in self._controllers.values():
            for port in endpoints.outputs:
                for msg in port.messages():
                    try:
                        port.publisher.put(encode(msg))
                        self.counters.published += 1
                    except zenoh.ZError:
                        self.counters.publish_errors += 1
            if endpoints.action is not None:
                self._flush_action(endpoints.action)

    def _flush_action(self, port: ActionPort) -> None:
        messages = [(port.result, r.as_dict()) for r in port.server.collect()]
        messages += [(port.feedback, m) for m in port.server.feedback_messages()]
        for publisher, message in messages:
            try:
                publisher.put(encode(message))
                self.counters.published += 1
            except zenoh.ZError:
                self.counters.publish_errors += 1

    # ---- goal queries ---------------------------------------------------------------------------------------------
    def _query_handler(self, key: str, handle: Callable[[Any], dict[str, Any]]) -> Callable[[zenoh.Query], None]:
        def on_query(query: zenoh.Query) -> None:  # a Zenoh thread: size check, copy out, hop to the loop
            try:
                raw, size = read_payload(query)
                self.loop.call_soon_threadsafe(self._start_answer, key, query, handle, raw, size)
            except RuntimeError:  # the loop is closing: the querier times out
                drop(query)

        return on_query

    def _start_answer(
        self, key: str, query: zenoh.Query, handle: Callable[[Any], dict[str, Any]], raw: bytes | None, size: int
    ) -> None:
        self.counters.queries += 1
        if self.closing:
            reply_json(query, key, SHUTTING_DOWN)
        elif raw is None:
            reply_json(query, key, too_large(size))
        elif len(self._answering) >= MAX_IN_FLIGHT:  # the same cap as services: a flood cannot pile up planners
            reply_json(query, key, BUSY)
        else:
            task = self.loop.create_task(self._answer(key, query, handle, raw))
            self._answering.add(task)
            task.add_done_callback(self._answering.discard)

    async def _answer(self, key: str, query: zenoh.Query, handle: Callable[[Any], dict[str, Any]], raw: bytes) -> None:
        """Goals are parsed and planned in a worker thread: a long trajectory must not stall the event loop."""
        try:
            reply = await asyncio.to_thread(handle, decode(raw))
        except asyncio.CancelledError:
            reply_json(query, key, SHUTTING_DOWN)
            raise
        except Exception as exc:  # bad JSON, a bad request, or a plugin's bug: the client gets the reason
            reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
            reply = {"ok": False, "error": reason or type(exc).__name__}
        reply_json(query, key, reply)

    # ---- inputs -----------------------------------------------------------------------------------------------
    def _sample_handler(self, key: str, controller: str, accept: Callable[[Any], None]) -> Callable[[Any], None]:
        def on_sample(sample: zenoh.Sample) -> None:  # a Zenoh thread: copy out, then hop to the loop
            if self.closing:
                return
            try:
                payload = sample.payload
                size = len(payload)
                raw = payload.to_bytes() if size <= MAX_PAYLOAD else None
                self.loop.call_soon_threadsafe(self._deliver, key, controller, accept, raw, size)
            except RuntimeError:  # the loop is closing
                pass

        return on_sample

    def _deliver(self, key: str, controller: str, accept: Callable[[Any], None], raw: bytes | None, size: int) -> None:
        self.counters.commands += 1
        try:
            if raw is None:
                raise PayloadError(f"payload of {size} bytes exceeds the {MAX_PAYLOAD}-byte limit")
            accept(decode(raw))
        except Exception as exc:  # ValueError from validation, or a plugin's bug: the sample is dropped either way
            self.counters.dropped += 1
            reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
            self._drops.report(controller, key, reason or type(exc).__name__)
            return
        self.counters.accepted += 1
