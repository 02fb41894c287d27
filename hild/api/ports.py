"""Controller inputs and outputs on Zenoh: one subscriber per input, one publisher per output ring.

An input sample is decoded and given to the controller's input callable (its API half, which validates it and puts
it into a door), at one of two places, chosen by the link's ``inputs_on_arrival``:

- **With the cycle in its own process** (the default), on the Zenoh thread the sample arrives on
  (:meth:`ControllerPorts._arrival_handler`): that GIL is the client domain's alone, and the validated value crosses
  into the cycle process through a cell of the shared region, so no cycle period is added to its way to the drive.
- **With the cycle a thread of this process** (the in-process case), Zenoh queues the samples in a small ring per
  input (``RingChannel``: no Python runs when a sample arrives) and the cycle takes them itself at the start of each
  cycle (:meth:`ControllerPorts.take_inputs`): the newest is decoded and handed over, older ones are superseded, like
  the controllers' own latest-value doors. A callback per sample on another thread would cost that cycle more than
  the decode and validation themselves, because every time another thread takes the GIL the cycle may have to wait
  for it and be woken again (measured: ``tools/cycle_causes.py`` part 3, docs/performance.md): a deliberate
  exception to parsing on the producer's side.

Either way the work per sample is bounded: one decode of at most ``CYCLE_DECODE`` bytes and one validation; larger
samples are decoded on the asyncio loop by the large-payload worker and handed over only if nothing newer was. Of
those, each input keeps at most one waiting (a newer one replaces it undecoded) and one being decoded: 200 puts of
1 MiB once became 200 tasks, each holding its payload until decoded, and decoded before they were found superseded
(the daemon grew by 400 MiB and its cycle overran for a minute after the flood). Samples for an inactive controller
are refused unread. Anything wrong drops that sample and emits a warning event: nothing moves on bad input. Warnings
are rate-limited per key so a client streaming garbage at 1 kHz cannot flood the event log.

Outputs are read from each controller's :class:`~hild.crossing.ring.SampleRing` through a private reader and
published with congestion control DROP: under back-pressure old samples are lost, the loop is never held."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from hild.action import ActionServer
from hild.api.codec import FAST_DECODE, GOAL_LIMITS, MAX_PAYLOAD, REQUEST_LIMITS, Limits, PayloadError, decode, encode
from hild.api.goals import GoalEndpoint
from hild.api.keys import RESERVED, Keys, check_chunk
from hild.api.queries import SHUTTING_DOWN, Admitted, LargePayloadWorker, QueryAdmission, clip, drop, reply_json
from hild.api.session import declare_json_publisher
from hild.controller import ShapedOutput
from hild.crossing.ring import RingReader, SampleRing
from hild.daemon.link import CycleLink

log = logging.getLogger("hild.api")

INTAKE_CAPACITY = 64  # samples one input queues between two cycles; beyond that Zenoh drops the oldest, uncounted
CYCLE_DECODE = FAST_DECODE  # bytes: a sample up to this size is decoded where it is handed over, larger by the loop
GOAL_ID_REQUEST = 1024  # bytes: a cancel or result request is {"goal_id": "<32 hex digits>"}
VERBS = {  # a goal endpoint's queries: size limit in bytes (refused larger before copying), decoding caps
    "goal": (MAX_PAYLOAD, GOAL_LIMITS),
    "cancel": (GOAL_ID_REQUEST, REQUEST_LIMITS),
    "result": (GOAL_ID_REQUEST, REQUEST_LIMITS),
}
REPORTS_PER_WINDOW = 10
REPORT_WINDOW = 1.0  # s


@dataclass
class InputCounts:
    """Input samples as one side counted them, without a lock: in the in-process case ``cycle`` has one writer (the
    cycle's ``take_inputs``), so the cycle never takes a lock; on arrival, Zenoh threads write it under each input's
    own lock, none across inputs, so two inputs counted at the same instant may lose a count."""

    commands: int = 0  # samples received
    accepted: int = 0
    rejected: int = 0  # decoded or validated and found wrong
    superseded: int = 0  # a newer sample on the same input arrived before this one was handed over


@dataclass
class Counters:
    """What the API has seen; cheap integers, read by tests and diagnostics.

    Input samples are counted where they are handed over (``cycle``: the cycle's ``take_inputs`` in the in-process
    case, Zenoh's threads on arrival) and, for large ones, on the asyncio loop (``loop``); queries are counted on
    Zenoh threads under ``lock``; publications on the loop."""

    lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)
    cycle: InputCounts = field(default_factory=InputCounts)
    loop: InputCounts = field(default_factory=InputCounts)
    queries: int = 0
    published: int = 0
    publish_errors: int = 0

    def publish(self, publisher: zenoh.Publisher, message: dict[str, Any]) -> None:
        """Put one JSON message; a failed put is counted, never raised: the loop publishes on (asyncio thread)."""
        try:
            publisher.put(encode(message))
            self.published += 1
        except zenoh.ZError:
            self.publish_errors += 1

    @property
    def commands(self) -> int:
        return self.cycle.commands  # the hand-over sees every sample first

    @property
    def accepted(self) -> int:
        return self.cycle.accepted + self.loop.accepted

    @property
    def rejected(self) -> int:
        return self.cycle.rejected + self.loop.rejected

    @property
    def superseded(self) -> int:
        return self.cycle.superseded + self.loop.superseded

    @property
    def dropped(self) -> int:
        """Samples that moved nothing: rejected, or superseded before they were handed over."""
        return self.rejected + self.superseded


class DropReporter:
    """At most ``REPORTS_PER_WINDOW`` warnings per key per window; the rest are counted into the next one."""

    def __init__(self, emit: Callable[[str, str, str], None]) -> None:
        self._emit = emit
        self._windows: dict[str, tuple[float, int, int]] = {}  # key → (window start, reported, suppressed)
        self._lock = threading.Lock()  # reports come from the hand-over and the loop (bad input only)

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
    shape: Callable[[int, float, dict[str, list[float]]], dict[str, Any]] | None = None  # a ShapedOutput's

    def messages(self) -> list[dict[str, Any]]:
        """New samples as messages: ``{"stamp", "seq", "name"?, <field>: [...]}``, or a shaped output's own."""
        out = []
        for seq, stamp, fields in self.reader.read():
            if self.shape is not None:
                out.append(self.shape(seq, stamp, fields))
                continue
            msg: dict[str, Any] = {"stamp": stamp, "seq": seq}
            if self.names is not None:
                msg["name"] = self.names
            msg.update(fields)
            out.append(msg)
        return out


@dataclass
class ActionPort:
    """A controller's goal endpoint: queryables goal/cancel/result, publishers feedback/result."""

    server: GoalEndpoint[Any]
    feedback: zenoh.Publisher
    result: zenoh.Publisher
    queryables: list[zenoh.Queryable[Any]] = field(default_factory=list)


def _always() -> bool:
    return True


def _activity(instance: Any) -> Callable[[], bool]:
    """Whether a controller is active: its ``active`` flag, which its controller manager sets (a shared cell when the
    cycle runs in its own process). A plugin without the flag is taken as always active: its ``accept`` decides."""
    return lambda: bool(getattr(instance, "active", True))


@dataclass
class InputSlot:
    """One controller input, handed over on arrival (a Zenoh thread) or, in the in-process case, queued by Zenoh in a
    ring for the cycle's ``take_inputs`` to take the newest.

    A large sample waits in ``pending`` (one place: a newer one replaces it, undecoded) for the input's one
    delivery task on the loop. The hand-over writes ``taken``, ``large`` and ``pending``; the loop pops ``pending``
    and owns ``delivered``, ``kicked`` (cleared) and ``delivery``: no lock, nothing the cycle waits on.
    """

    key: str
    controller: str
    accept: Callable[[Any], None]
    subscriber: Any = None  # zenoh.Subscriber on a RingChannel, once declared
    active: Callable[[], bool] = _always  # whether the controller is active (read at each hand-over)
    quiet: bool = False  # a subscription to another robot's output: dropped unreported while inactive
    taken: int = 0  # samples handed over so far (hand-over); a large one on the loop checks it is still newest
    pending: deque[tuple[Any, int, int]] = field(default_factory=lambda: deque(maxlen=1))  # (payload, taken, large)
    large: int = 0  # large samples put in ``pending`` so far (hand-over)
    delivered: int = 0  # the last of those the loop took (loop thread): the gap was superseded undecoded
    kicked: bool = False  # the loop has been asked to look at ``pending`` and has not yet
    delivery: asyncio.Task[None] | None = None  # the one task decoding this input's large samples (loop thread)


@dataclass
class ControllerEndpoints:
    instance: object
    subscribers: list[zenoh.Subscriber[Any]] = field(default_factory=list)
    slots: list[InputSlot] = field(default_factory=list)
    outputs: list[OutputPort] = field(default_factory=list)
    action: ActionPort | None = None


class ControllerPorts:
    def __init__(
        self,
        session: zenoh.Session,
        engine: CycleLink,
        keys: Keys,
        loop: asyncio.AbstractEventLoop,
        counters: Counters,
        lane: LargePayloadWorker | None = None,
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
        self.lane = lane or LargePayloadWorker()
        self._gate = QueryAdmission()  # goal, cancel and result queries of every controller, like the services' gate
        self._delivering: set[asyncio.Task[None]] = set()
        self._taken_inputs: tuple[InputSlot, ...] = ()  # what take_inputs reads; replaced whole, never changed

    # ---- declaration ---------------------------------------------------------------------------------------
    def sync(self) -> None:
        """Declare endpoints for newly loaded controllers, undeclare those of unloaded ones (asyncio thread)."""
        try:
            current = self.engine.controllers()
        except RuntimeError:  # records changed while we copied; the next change_seq brings us back here
            return
        stale = [n for n, ep in self._controllers.items() if current.get(n) is not ep.instance]
        gone = [self._controllers.pop(n) for n in stale]
        for name, instance in current.items():
            if name not in self._controllers:
                self._controllers[name] = self._declare(name, instance)
        self._taken_inputs = tuple(slot for ep in self._controllers.values() for slot in ep.slots)  # one swap
        for endpoints in gone:
            self._undeclare(endpoints)

    def _declare(self, name: str, instance: Any) -> ControllerEndpoints:
        endpoints = ControllerEndpoints(instance)
        try:
            check_chunk(name, "controller name")
            inputs = dict(instance.inputs())
            outputs = dict(instance.outputs())
            subscriptions = dict(getattr(instance, "subscriptions", dict)())  # a plugin may predate the method
        except Exception as exc:
            self.engine.events.emit("error", "api", f"controller {name}: not exposed on Zenoh: {exc}")
            return endpoints
        for input_name, accept in inputs.items():
            try:
                key = self.keys.input(name, check_chunk(input_name, "input name"))
                self._subscribe(endpoints, InputSlot(key, name, accept, None, _activity(instance)))
            except (ValueError, zenoh.ZError) as exc:
                self.engine.events.emit("error", "api", f"controller {name}: input {input_name!r} not declared: {exc}")
        for key, accept in subscriptions.items():  # other robots' outputs (Controller.subscriptions)
            try:
                self._subscribe(endpoints, InputSlot(str(key), name, accept, None, _activity(instance), quiet=True))
            except (ValueError, zenoh.ZError) as exc:
                self.engine.events.emit("error", "api", f"controller {name}: subscription {key!r} not declared: {exc}")
        taken = {p.topic for ep in self._controllers.values() for p in ep.outputs}
        for output_name, output in outputs.items():
            shaped = output if isinstance(output, ShapedOutput) else None
            ring = output.ring if isinstance(output, ShapedOutput) else output
            try:
                check_chunk(output_name, "output name")
                if shaped is not None:  # under the controller's own name: two of one type never collide
                    topic = self.keys.controller_topic(name, output_name)
                    reserved = name in RESERVED
                else:
                    topic = self.keys.topic(output_name)
                    reserved = output_name in RESERVED
                if reserved or topic in taken:
                    raise ValueError(f"{topic} is already used")
                publisher = declare_json_publisher(self.session, topic, priority=zenoh.Priority.DATA_HIGH, express=True)
            except (ValueError, zenoh.ZError) as exc:
                self.engine.events.emit(
                    "error", "api", f"controller {name}: output {output_name!r} not published: {exc}"
                )
                continue
            shape = shaped.message if shaped is not None else None
            endpoints.outputs.append(OutputPort(topic, ring, RingReader(ring), publisher, self._names(ring), shape))
        try:
            server = instance.action_server()
            if server is not None:
                endpoints.action = self._declare_action(name, server)
        except (ValueError, zenoh.ZError) as exc:
            self.engine.events.emit("error", "api", f"controller {name}: goals not exposed: {exc}")
        return endpoints

    def _subscribe(self, endpoints: ControllerEndpoints, slot: InputSlot) -> None:
        """An input's (or a subscription's) subscriber: handed over on arrival when the cycle is in its own
        process, else queued for the cycle's ``take_inputs``."""
        if self.engine.inputs_on_arrival:
            slot.subscriber = self.session.declare_subscriber(slot.key, self._arrival_handler(slot))
        else:
            slot.subscriber = self.session.declare_subscriber(slot.key, zenoh.handlers.RingChannel(INTAKE_CAPACITY))
            endpoints.slots.append(slot)
        endpoints.subscribers.append(slot.subscriber)

    def _declare_action(self, name: str, action: ActionServer[Any]) -> ActionPort:
        server = GoalEndpoint.of(action)
        key = functools.partial(self.keys.input, name)
        port = ActionPort(
            server,
            feedback=declare_json_publisher(self.session, key("feedback")),
            result=declare_json_publisher(self.session, key("result"), priority=zenoh.Priority.DATA_HIGH),
        )
        for verb, handle in (("goal", server.submit), ("cancel", server.cancel), ("result", server.result)):
            handler = self._query_handler(key(verb), handle, *VERBS[verb])
            port.queryables.append(self.session.declare_queryable(key(verb), handler, complete=True))
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
        self._taken_inputs = ()
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
                    self.counters.publish(port.publisher, msg)
            if endpoints.action is not None:
                self._flush_action(endpoints.action)

    def _flush_action(self, port: ActionPort) -> None:
        messages = [(port.result, r.as_dict()) for r in port.server.collect()]
        messages += [(port.feedback, m) for m in port.server.feedback_messages()]
        for publisher, message in messages:
            self.counters.publish(publisher, message)

    # ---- goal queries ---------------------------------------------------------------------------------------------
    def _query_handler(
        self, key: str, handle: Callable[[Any], dict[str, Any]], limit: int, limits: Limits
    ) -> Callable[[zenoh.Query], None]:
        # Zenoh may hold callbacks past undeclare and session close: hold the ports and the controller's handler
        # weakly, so a kept callback cannot keep the engine alive to interpreter exit.
        owner, handler = weakref.ref(self), weakref.WeakMethod(handle)  # type: ignore[arg-type]

        def on_query(query: zenoh.Query) -> None:  # a Zenoh thread: admit (size, cap), copy out, hop to the loop
            me, answer = owner(), handler()
            if me is None or answer is None:
                drop(query)
                return
            admitted = me._gate.admit(query, limit)  # a flood cannot pile up planners
            if not isinstance(admitted, Admitted):
                reply_json(query, key, admitted)
                return
            try:
                me.loop.call_soon_threadsafe(me._start_answer, key, query, answer, admitted, limits)
            except RuntimeError:  # the loop is closing: the querier times out
                admitted.release()
                drop(query)

        return on_query

    def _start_answer(
        self, key: str, query: zenoh.Query, handle: Callable[[Any], dict[str, Any]], admitted: Admitted, limits: Limits
    ) -> None:
        with self.counters.lock:
            self.counters.queries += 1
        if self.closing:
            admitted.release()
            reply_json(query, key, SHUTTING_DOWN)
            return
        task = self.loop.create_task(self._answer(key, query, handle, admitted.raw, limits))
        self._answering.add(task)
        task.add_done_callback(self._answering.discard)
        task.add_done_callback(lambda _: admitted.release())

    async def _answer(
        self, key: str, query: zenoh.Query, handle: Callable[[Any], dict[str, Any]], raw: bytes, limits: Limits
    ) -> None:
        """Goals are decoded, parsed and planned in a worker thread (large ones by the large-payload worker, one at
        a time): a long trajectory must stall neither the loop nor, with others, a cycle thread in this process."""

        def work() -> dict[str, Any]:
            return handle(decode(raw, limits))

        try:
            reply = await (self.lane.run(work) if self.lane.needed(raw) else asyncio.to_thread(work))
        except asyncio.CancelledError:
            reply_json(query, key, SHUTTING_DOWN)
            raise
        except Exception as exc:  # bad JSON, a bad request, or a plugin's bug: the client gets the reason
            reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
            reply = {"ok": False, "error": reason or type(exc).__name__}
        reply_json(query, key, reply)

    # ---- inputs (handed over) ----------------------------------------------------------------------------------
    def take_inputs(self) -> None:
        """In the in-process case, at the start of each cycle, on the cycle thread: per input, take every queued
        sample and hand the newest to its controller, which validates it and swaps it into its mailbox; the rest
        are superseded.

        Bounded work: per input a few ``try_recv`` calls (Zenoh queued the samples without Python), and for the
        newest one decode of at most ``CYCLE_DECODE`` bytes and one validation. A larger sample replaces the one
        waiting for the loop, if any, undecoded. Nothing is decoded for an inactive controller."""
        for slot in self._taken_inputs:
            newest, count = None, 0
            try:
                while (sample := slot.subscriber.try_recv()) is not None:
                    newest, count = sample, count + 1
            except Exception:  # undeclared meanwhile (controller unloaded, closing): nothing more to take
                continue
            if newest is not None:
                self._hand_over(slot, newest, count)

    def _arrival_handler(self, slot: InputSlot) -> Callable[[zenoh.Sample], None]:
        """With the cycle in its own process, a sample is handed over on the Zenoh thread it arrives on: its GIL
        is the client domain's alone, and no cycle period is added to the command's way to the hardware."""
        owner = weakref.ref(self)
        lock = threading.Lock()  # one input's samples one at a time, so a later one is never overtaken

        def on_sample(sample: zenoh.Sample) -> None:
            me = owner()
            if me is not None and not me.closing:
                with lock:
                    me._hand_over(slot, sample, 1)

        return on_sample

    def _hand_over(self, slot: InputSlot, newest: zenoh.Sample, count: int) -> None:
        """The newest of ``count`` samples of one input: refused for an inactive controller, decoded and handed
        to the controller when small, queued for the loop's large-payload worker when large."""
        tally = self.counters.cycle
        tally.commands += count
        tally.superseded += count - 1
        slot.taken += 1
        if not slot.active():  # refused unread: a flood at an inactive controller costs a count per cycle
            if slot.quiet:  # another robot's stream, not a command to this controller: nothing to report
                return
            tally.rejected += 1
            self._report(slot, ValueError(f"controller {slot.controller} is not active"))
            return
        payload = newest.payload
        size = len(payload)
        if CYCLE_DECODE < size <= MAX_PAYLOAD:
            slot.large += 1
            slot.pending.append((payload, slot.taken, slot.large))  # replaces the one waiting, undecoded
            if not slot.kicked:
                slot.kicked = True
                with contextlib.suppress(RuntimeError):  # the loop is closed: the sample is lost with it
                    self.loop.call_soon_threadsafe(self._start_delivery, slot)
            return
        try:
            if size > MAX_PAYLOAD:
                raise PayloadError(f"payload of {size} bytes exceeds the {MAX_PAYLOAD}-byte limit")
            slot.accept(decode(payload.to_bytes()))
        except Exception as exc:  # ValueError from validation, or a plugin's bug: the sample is dropped
            tally.rejected += 1
            self._report(slot, exc)
        else:
            tally.accepted += 1

    def _start_delivery(self, slot: InputSlot) -> None:
        """The hand-over put a large sample in ``slot.pending``: start the input's delivery task unless it runs."""
        slot.kicked = False  # before looking: a sample put after this line kicks again
        if self.closing:
            slot.pending.clear()
            return
        if slot.delivery is not None and not slot.delivery.done():
            return  # it takes the pending sample when its decode is done
        if not slot.pending:
            return
        task = self.loop.create_task(self._deliver(slot))
        slot.delivery = task
        self._delivering.add(task)
        task.add_done_callback(self._delivering.discard)

    async def _deliver(self, slot: InputSlot) -> None:
        """Large samples of one input, the newest pending each time, decoded by the large-payload worker one at a
        time; each handed over only if nothing newer was handed over meanwhile (checked before decoding, and after)."""
        tally = self.counters.loop
        while not self.closing:
            try:
                payload, seq, index = slot.pending.popleft()
            except IndexError:
                return
            tally.superseded += index - slot.delivered - 1  # replaced while waiting, never decoded
            slot.delivered = index
            if slot.taken != seq:  # a newer, small one was handed over meanwhile
                tally.superseded += 1
                continue
            try:
                if not slot.active():
                    raise ValueError(f"controller {slot.controller} is not active")
                value = await self.lane.run(functools.partial(decode, payload.to_bytes()))
                del payload  # the decoded value is all that is kept
                if self.closing:
                    return
                if slot.taken != seq:
                    tally.superseded += 1
                    continue
                slot.accept(value)
            except Exception as exc:
                tally.rejected += 1
                self._report(slot, exc)
            else:
                tally.accepted += 1

    def _report(self, slot: InputSlot, exc: Exception) -> None:
        reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
        self._drops.report(slot.controller, slot.key, reason or type(exc).__name__)
