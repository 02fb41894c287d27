"""The bench's clients: the work every scenario carries, and the interference some windows add.

Each runs on its own thread with its own ``HildClient`` (its own Zenoh session), as separate client programs
would. All are bounded: they stop when told, and pace themselves to an absolute schedule so a slow answer makes
them late rather than bursty.

* ``TrajectoryKeeper`` — sends the standard trajectory (``hild.motion.reference``) to a joint_trajectory
  controller, waits for its result, sends it again, until stopped; counts results by status.
* ``Poller`` — calls one service (``status``, ``list_controllers``) at a fixed rate.
* ``ServoStreamer`` — publishes servo targets at a fixed rate: a slow sine around a start pose.
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
        self._handle: GoalHandle | None = None

    def run(self) -> None:
        try:
            while not self.stopping.is_set():
                self.results["sent"] = self.results.get("sent", 0) + 1
                try:
                    with self.client.send_goal(self.controller, self.goal) as handle:
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
