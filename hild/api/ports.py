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
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from hild.api.codec import MAX_PAYLOAD, PayloadError, decode, encode
from hild.api.keys import RESERVED, Keys, check_chunk
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
class ControllerEndpoints:
    instance: object
    subscribers: list[zenoh.Subscriber[Any]] = field(default_factory=list)
    outputs: list[OutputPort] = field(default_factory=list)


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
        return endpoints

    def _names(self, ring: SampleRing) -> list[str] | None:
        """Element names of a ring: its own ``names`` if it has them, else the robot's joints when widths match."""
        names: Sequence[str] | None = getattr(ring, "names", None)
        if names is None and ring.width == len(self.engine.joints):
            names = self.engine.joints
        return list(names) if names is not None else None

    @staticmethod
    def _undeclare(endpoints: ControllerEndpoints) -> None:
        for entity in [*endpoints.subscribers, *(p.publisher for p in endpoints.outputs)]:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()

    def close(self) -> None:
        self.closing = True
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
