"""Controller inputs and outputs on Zenoh: one subscriber per input, one publisher per output ring.

Inputs arrive on Zenoh threads; each sample is size-checked there and parked in its input's one-sample slot (a
newer sample replaces one not read yet, like the controllers' own latest-value mailboxes). The Zenoh thread that
finds the slot idle delivers it: decodes the newest sample and gives it to the controller's input callable (which
validates it and swaps it into a mailbox), until the slot is empty. Small samples never wake the asyncio loop:
one thread takes the GIL once per sample, which is what a 1 kHz stream costs the cycle (docs/performance.md).
Large ones are handed to the loop, which decodes them in the heavy lane. A flood can neither queue up payloads nor
run one input's callable twice at once. Anything wrong drops that sample and emits a warning event: nothing moves
on bad input. Warnings are rate-limited per key so a client streaming garbage at 1 kHz cannot flood the event log.

Outputs are read from each controller's :class:`~hild.ring.SampleRing` through a private reader and published
with congestion control DROP: under back-pressure old samples are lost, the loop is never held.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from hild.action import ActionServer
from hild.api.codec import GOAL_CONTAINERS, MAX_PAYLOAD, PayloadError, decode, encode
from hild.api.keys import RESERVED, Keys, check_chunk
from hild.api.queries import SHUTTING_DOWN, Admitted, Gate, HeavyLane, clip, drop, reply_json
from hild.api.session import declare_json_publisher
from hild.engine import Engine
from hild.ring import RingReader, SampleRing

log = logging.getLogger("hild.api")

REPORTS_PER_WINDOW = 10
REPORT_WINDOW = 1.0  # s


@dataclass
class Counters:
    """What the API has seen; cheap integers, read by tests and diagnostics.

    Counters written on Zenoh threads (all but the publication counts) are changed under ``lock``."""

    lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)
    commands: int = 0  # samples received
    accepted: int = 0
    rejected: int = 0  # decoded or validated and found wrong
    superseded: int = 0  # replaced in their slot by a newer sample before the loop read them (Zenoh threads)
    queries: int = 0
    published: int = 0
    publish_errors: int = 0

    @property
    def dropped(self) -> int:
        """Samples that moved nothing: rejected, or superseded before they were read."""
        return self.rejected + self.superseded


class DropReporter:
    """At most ``REPORTS_PER_WINDOW`` warnings per key per window; the rest are counted into the next one."""

    def __init__(self, emit: Callable[[str, str, str], None]) -> None:
        self._emit = emit
        self._windows: dict[str, tuple[float, int, int]] = {}  # key → (window start, reported, suppressed)
        self._lock = threading.Lock()  # reports come from Zenoh threads and the loop

    def report(self, source: str, key: str, reason: str) -> None:
        now = time.monotonic()
        with self._lock:
            start, reported, suppressed = self._windows.get(key, (now, 0, 0))
            if now - start >= REPORT_WINDOW:
                start, reported = now, 0
            if reported >= REPORTS_PER_WINDOW:
                self._windows[key] = (start, reported, suppressed + 1)
                return
            self._windows[key] = (start, reported + 1, 0)
        more = f" (+{suppressed} more dropped)" if suppressed else ""
        self._emit("warning", source, f"dropped command on {key}: {clip(reason)}{more}")


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
class InputSlot:
    """The newest undelivered sample of one input; ``busy`` while the loop is delivering from it."""

    key: str
    controller: str
    accept: Callable[[Any], None]
    lock: threading.Lock = field(default_factory=threading.Lock)
    pending: tuple[bytes | None, int] | None = None  # (payload, or None when over the limit; its size)
    busy: bool = False


@dataclass
class ControllerEndpoints:
    instance: object
    subscribers: list[zenoh.Subscriber[Any]] = field(default_factory=list)
    slots: list[InputSlot] = field(default_factory=list)  # the subscribers' callbacks hold them weakly
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
        lane: HeavyLane | None = None,
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
        self.lane = lane or HeavyLane()
        self._gate = Gate()  # goal, cancel and result queries of every controller, like the services' gate
        self._delivering: set[asyncio.Task[None]] = set()

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
                slot = InputSlot(key, name, accept)
                endpoints.slots.append(slot)
                endpoints.subscribers.append(self.session.declare_subscriber(key, self._sample_handler(slot)))
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
        for task in [*self._answering, *self._delivering]:
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
        # Zenoh may hold callbacks past undeclare and session close: hold the ports and the controller's handler
        # weakly, so a kept callback cannot keep the engine alive to interpreter exit.
        owner, handler = weakref.ref(self), weakref.WeakMethod(handle)  # type: ignore[arg-type]

        def on_query(query: zenoh.Query) -> None:  # a Zenoh thread: admit (size, cap), copy out, hop to the loop
            me, answer = owner(), handler()
            if me is None or answer is None:
                drop(query)
                return
            admitted = me._gate.admit(query)  # a flood cannot pile up planners
            if not isinstance(admitted, Admitted):
                reply_json(query, key, admitted)
                return
            try:
                me.loop.call_soon_threadsafe(me._start_answer, key, query, answer, admitted)
            except RuntimeError:  # the loop is closing: the querier times out
                admitted.release()
                drop(query)

        return on_query

    def _start_answer(
        self, key: str, query: zenoh.Query, handle: Callable[[Any], dict[str, Any]], admitted: Admitted
    ) -> None:
        with self.counters.lock:
            self.counters.queries += 1
        if self.closing:
            admitted.release()
            reply_json(query, key, SHUTTING_DOWN)
            return
        task = self.loop.create_task(self._answer(key, query, handle, admitted.raw))
        self._answering.add(task)
        task.add_done_callback(self._answering.discard)
        task.add_done_callback(lambda _: admitted.release())

    async def _answer(self, key: str, query: zenoh.Query, handle: Callable[[Any], dict[str, Any]], raw: bytes) -> None:
        """Goals are decoded, parsed and planned in a worker thread (large ones in the heavy lane, one at a time):
        a long trajectory must stall neither the loop nor, with others, the cycle."""

        def work() -> dict[str, Any]:
            return handle(decode(raw, GOAL_CONTAINERS))

        try:
            reply = await (self.lane.run(work) if self.lane.needed(raw) else asyncio.to_thread(work))
        except asyncio.CancelledError:
            reply_json(query, key, SHUTTING_DOWN)
            raise
        except Exception as exc:  # bad JSON, a bad request, or a plugin's bug: the client gets the reason
            reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
            reply = {"ok": False, "error": reason or type(exc).__name__}
        reply_json(query, key, reply)

    # ---- inputs -----------------------------------------------------------------------------------------------
    def _sample_handler(self, input_slot: InputSlot) -> Callable[[Any], None]:
        owner, slot_of = weakref.ref(self), weakref.ref(input_slot)  # weakly, as for queries

        def on_sample(sample: zenoh.Sample) -> None:  # a Zenoh thread: copy out, park in the slot, deliver
            me, slot = owner(), slot_of()
            if me is None or slot is None or me.closing:
                return
            payload = sample.payload
            size = len(payload)
            raw = payload.to_bytes() if size <= MAX_PAYLOAD else None
            with slot.lock:
                superseded = slot.pending is not None  # the deliverer has not read the previous one: the newest counts
                slot.pending = (raw, size)
                deliver = not slot.busy
                slot.busy = True
            with me.counters.lock:
                me.counters.commands += 1
                me.counters.superseded += superseded
            if deliver:
                me._deliver_here(slot)

        return on_sample

    def _deliver_here(self, slot: InputSlot) -> None:
        """Deliver on the Zenoh thread that found the slot idle, until it is empty; a large sample goes to the loop.

        A small sample costs one decode and one validation while this thread holds the GIL anyway; hopping to the
        loop would wake a second thread and take the GIL twice more per sample, each a chance to delay the cycle
        (docs/performance.md). One deliverer per slot at a time (``busy``), so ``accept`` never runs concurrently
        with itself."""
        while True:
            with slot.lock:
                item = slot.pending
                if item is not None and item[0] is not None and self.lane.needed(item[0]):
                    hand_over = True  # stays pending and busy: the loop decodes it in the heavy lane
                else:
                    hand_over = False
                    slot.pending = None
                    if item is None:
                        slot.busy = False
                        return
            if hand_over:
                with contextlib.suppress(RuntimeError):  # the loop is closed: nothing reads the slot again
                    self.loop.call_soon_threadsafe(self._start_delivery, slot)
                return
            self._accept(slot, *item)

    def _start_delivery(self, slot: InputSlot) -> None:
        task = self.loop.create_task(self._deliver(slot))
        self._delivering.add(task)
        task.add_done_callback(self._delivering.discard)

    async def _deliver(self, slot: InputSlot) -> None:
        """Deliver the slot's samples on the loop, large ones decoded in the heavy lane, until none is left.

        One sample per turn of the loop: a stream arriving as fast as it is read must not starve the services."""
        while True:
            with slot.lock:
                item, slot.pending = slot.pending, None
                if item is None:
                    slot.busy = False
                    return
            raw, size = item
            if raw is not None and self.lane.needed(raw):
                try:
                    payload = await self.lane.run(functools.partial(decode, raw))
                except Exception as exc:
                    self._reject(slot, exc)
                    continue
                self._hand_over(slot, payload)
            else:
                self._accept(slot, raw, size)
            await asyncio.sleep(0)

    def _accept(self, slot: InputSlot, raw: bytes | None, size: int) -> None:
        """Decode a small sample and hand it to the controller."""
        try:
            payload = decode_input(raw, size)
        except Exception as exc:
            self._reject(slot, exc)
            return
        self._hand_over(slot, payload)

    def _hand_over(self, slot: InputSlot, payload: Any) -> None:
        """The controller validates and takes the sample; anything wrong drops it and is reported."""
        if self.closing:
            return
        try:
            slot.accept(payload)
        except Exception as exc:  # ValueError from validation, or a plugin's bug: the sample is dropped either way
            self._reject(slot, exc)
        else:
            with self.counters.lock:
                self.counters.accepted += 1

    def _reject(self, slot: InputSlot, exc: Exception) -> None:
        with self.counters.lock:
            self.counters.rejected += 1
        reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
        self._drops.report(slot.controller, slot.key, reason or type(exc).__name__)


def decode_input(raw: bytes | None, size: int) -> Any:
    """A parked sample's payload; None stands for one refused unread for its size."""
    if raw is None:
        raise PayloadError(f"payload of {size} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    return decode(raw)
