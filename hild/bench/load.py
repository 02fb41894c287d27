"""The bench's clients: the work every scenario carries, and the interference some windows add.

Each runs on its own thread with its own ``HildClient`` (its own Zenoh session), as separate client programs
would. All are bounded: they stop when told, and pace themselves to an absolute schedule so a slow answer makes
them late rather than bursty.

* ``TrajectoryKeeper`` — sends the standard trajectory (``hild.motion.reference``) to a joint_trajectory
  controller, waits for its result, sends it again, until stopped; counts results by status and keeps, for each
  goal, when it was sent and how long the daemon took to accept it (the operator's view).
* ``Poller`` — calls one service (``status``, ``list_controllers``) at a fixed rate.
* ``ServoStreamer`` — publishes servo targets at a fixed rate: a slow sine around a start pose.
* ``Flooder`` — an observer sending 1 MiB queries as fast as they are answered, a few in flight on one session:
  the rate its link allows.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from hild.api.client import GoalHandle, HildClient, HildError
from hild.motion.reference import standard_trajectory

RESULT_TIMEOUT = 30.0  # s: a standard trajectory takes ~4 s plus settling
SERVO_AMPLITUDE = 0.05  # rad
SERVO_FREQUENCY = 0.5  # Hz


class _Worker(threading.Thread):
    def __init__(self, name: str) -> None:
        super().__init__(name=name, daemon=True)
        self.stopping = threading.Event()
        self.error: str | None = None

    def stop(self) -> None:
        self.stopping.set()
        self.join(RESULT_TIMEOUT + 5.0)


class TrajectoryKeeper(_Worker):
    def __init__(
        self,
        connect: Sequence[str],
        robot: str,
        controller: str,
        joints: Sequence[str],
        start: Sequence[float],
        scale: float,
    ) -> None:
        super().__init__(f"bench-trajectory-{controller}")
        self.client = HildClient(robot, connect, timeout=5.0)
        self.controller = controller
        self.goal = standard_trajectory(list(joints), list(start), scale=scale)
        self.results: dict[str, int] = {}
        self.accepts: list[tuple[float, float]] = []  # (perf_counter at send, seconds until accepted)
        self._handle: GoalHandle | None = None

    def run(self) -> None:
        try:
            while not self.stopping.is_set():
                self.results["sent"] = self.results.get("sent", 0) + 1
                sent = time.perf_counter()
                try:
                    with self.client.send_goal(self.controller, self.goal) as handle:
                        self.accepts.append((sent, time.perf_counter() - sent))
                        self._handle = handle
                        result = handle.wait(RESULT_TIMEOUT)
                except HildError as exc:
                    self.results["refused"] = self.results.get("refused", 0) + 1
                    self.error = str(exc)
                    self.stopping.wait(0.1)
                    continue
                finally:
                    self._handle = None
                status = str(result.get("status")) if not self.stopping.is_set() else "ended at stop"
                self.results[status] = self.results.get(status, 0) + 1
        finally:
            self.client.close()

    def stop(self) -> None:
        """No new goal; cancel the one in flight (its result then comes at once) and wait for the thread."""
        self.stopping.set()
        handle = self._handle
        if handle is not None and self.is_alive():
            with contextlib.suppress(HildError):
                handle.cancel()
        self.join(RESULT_TIMEOUT + 5.0)


class Paced(_Worker):
    """Calls ``once()`` at ``rate`` Hz on an absolute schedule until stopped; counts calls and failures."""

    def __init__(self, name: str, rate: float) -> None:
        super().__init__(name)
        self.rate = rate
        self.calls = 0
        self.failures = 0
        self.started_at = 0.0
        self.stopped_at = 0.0

    def once(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def run(self) -> None:
        period = 1.0 / self.rate
        self.started_at = next_call = time.perf_counter()
        try:
            while not self.stopping.is_set():
                try:
                    self.once()
                    self.calls += 1
                except HildError as exc:
                    self.failures += 1
                    self.error = str(exc)
                next_call += period
                delay = next_call - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -period:  # fell behind by more than one call: drop the backlog
                    next_call = time.perf_counter()
        finally:
            self.stopped_at = time.perf_counter()
            self.close()

    @property
    def achieved_rate(self) -> float:
        span = self.stopped_at - self.started_at
        return round(self.calls / span, 1) if span > 0 else 0.0


class Poller(Paced):
    def __init__(self, connect: Sequence[str], robot: str, service: str, rate: float) -> None:
        super().__init__(f"bench-poll-{service}", rate)
        self.client = HildClient(robot, connect, timeout=2.0)
        self.service = service

    def once(self) -> None:
        self.client.call(self.service)

    def close(self) -> None:
        self.client.close()


class ServoStreamer(Paced):
    def __init__(
        self, connect: Sequence[str], robot: str, controller: str, start: Sequence[float], rate: float
    ) -> None:
        super().__init__(f"bench-servo-{controller}", rate)
        self.client = HildClient(robot, connect, timeout=2.0)
        self.stream = self.client.servo_stream(controller)
        self.start_pose = list(start)
        self._t0 = time.perf_counter()

    def once(self) -> None:
        phase = math.sin(2 * math.pi * SERVO_FREQUENCY * (time.perf_counter() - self._t0))
        self.stream.send([p + SERVO_AMPLITUDE * phase for p in self.start_pose])

    def close(self) -> None:
        self.client.close()


FLOOD_BYTES = 1 << 20
FLOOD_IN_FLIGHT = 4  # the daemon admits this many large queries at once (hild.api.queries.MAX_LARGE_IN_FLIGHT)
FLOOD_TIMEOUT = 2.0  # s


def flood_payload(size: int = FLOOD_BYTES) -> bytes:
    """A JSON object of exactly ``size`` bytes (one padding string): a well-formed query far over any limit."""
    head, tail = b'{"pad": "', b'"}'
    return head + b"x" * (size - len(head) - len(tail)) + tail


class Flooder(_Worker):
    """An observer flooding ``service`` with ``size``-byte queries: ``in_flight`` threads of one session, each
    sending the next query as soon as the last is answered. Counts answers (any reply, a refusal included: the
    daemon answered) and failures (no reply)."""

    def __init__(
        self,
        connect: Sequence[str],
        robot: str,
        service: str = "status",
        size: int = FLOOD_BYTES,
        in_flight: int = FLOOD_IN_FLIGHT,
    ) -> None:
        super().__init__(f"bench-flood-{service}")
        self.client = HildClient(robot, connect, timeout=FLOOD_TIMEOUT)
        self.key = self.client.keys.service(service)
        self.payload = flood_payload(size)
        self.in_flight = in_flight
        self.calls = 0
        self.failures = 0
        self.started_at = 0.0
        self.stopped_at = 0.0
        self._lock = threading.Lock()

    def run(self) -> None:
        self.started_at = time.perf_counter()
        senders = [threading.Thread(target=self._send, daemon=True) for _ in range(self.in_flight)]
        try:
            for sender in senders:
                sender.start()
            for sender in senders:
                sender.join()
        finally:
            self.stopped_at = time.perf_counter()
            self.client.close()

    def _send(self) -> None:
        while not self.stopping.is_set():
            answered = False
            try:
                for reply in self.client.session.get(self.key, payload=self.payload, timeout=FLOOD_TIMEOUT):
                    answered = reply.ok is not None
                    break
            except Exception as exc:  # the session closing under us at stop, or Zenoh refusing
                self.error = f"{type(exc).__name__}: {exc}"
            with self._lock:
                if answered:
                    self.calls += 1
                else:
                    self.failures += 1

    @property
    def achieved_rate(self) -> float:
        span = self.stopped_at - self.started_at
        return round(self.calls / span, 1) if span > 0 else 0.0


class Counter:
    """A thread-safe tally of messages by one key (e.g. events by level), for a subscription callback."""

    def __init__(self, key: Callable[[dict[str, Any]], str]) -> None:
        self._key = key
        self._lock = threading.Lock()
        self.counts: dict[str, int] = {}
        self.last: list[dict[str, Any]] = []

    def __call__(self, message: dict[str, Any]) -> None:
        with self._lock:
            k = self._key(message)
            self.counts[k] = self.counts.get(k, 0) + 1
            if k in ("warning", "error") and len(self.last) < 20:
                self.last.append(message)
