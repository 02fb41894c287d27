"""Cheap rolling loop statistics.

The cycle only stores integers into preallocated windows and bumps counters; percentiles are computed on demand
by whoever asks (status, the service report, the bench), from a copy of the window. Windows and counters can
live in a given buffer (a cell of the shared region): the cycle process records, the client domain reads.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

Unit = Literal["s", "ms", "us", "ns"]
PER_SECOND: dict[str, float] = {"s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9}

_COUNT, _MAX = 0, 1
_CYCLES, _OVERRUNS, _CONSECUTIVE = 0, 1, 2


def percentiles(
    values: Sequence[float] | np.ndarray, unit: Unit, *, to: Unit = "us", digits: int = 1
) -> dict[str, float]:
    """p50/p99/p99.9/max of ``values`` measured in ``unit``, converted to ``to`` and rounded to ``digits``
    (all zeros for no values). The unit is named at every call because measuring code collects seconds,
    nanoseconds and milliseconds alike; numpy's linear interpolation over every value."""
    data = np.asarray(values, dtype=float)
    if data.size == 0:
        return {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0}
    scale = PER_SECOND[to] / PER_SECOND[unit]
    p50, p99, p999 = (float(v) * scale for v in np.percentile(data, [50, 99, 99.9]))
    top = float(data.max()) * scale
    return {
        "p50": round(p50, digits),
        "p99": round(p99, digits),
        "p999": round(p999, digits),
        "max": round(top, digits),
    }


def window_bytes(size: int) -> int:
    return 8 * (2 + size)


def stats_bytes(window: int) -> int:
    """The bytes a ``LoopStats`` of ``window`` occupies in a buffer."""
    return 8 * 3 + 2 * window_bytes(window)


class RollingWindow:
    __slots__ = ("_head", "values")

    def __init__(self, size: int, buffer: memoryview | None = None) -> None:
        cells = np.zeros(2 + size, dtype=np.int64) if buffer is None else np.frombuffer(buffer, dtype=np.int64)
        self._head = cells[:2]  # count, max
        self.values = cells[2 : 2 + size]

    @property
    def count(self) -> int:
        return int(self._head[_COUNT])

    @property
    def max(self) -> int:
        return int(self._head[_MAX])

    def add(self, value_ns: int) -> None:
        head = self._head
        count = int(head[_COUNT])
        self.values[count % len(self.values)] = value_ns
        head[_COUNT] = count + 1
        if value_ns > head[_MAX]:
            head[_MAX] = value_ns

    def summary_us(self) -> dict[str, float]:
        """Percentiles over the window, µs; ``max`` is the largest value since the last reset, which the window
        may no longer hold."""
        n = min(self.count, len(self.values))
        if n == 0:
            return percentiles((), "ns")
        return {**percentiles(self.values[:n], "ns"), "max": round(self.max / 1e3, 1)}

    def reset(self) -> None:
        self._head[:] = 0


@dataclass
class LoopStats:
    """Cycle duration (wake → write done), period error (|Δwake − T|), overruns (deadline missed)."""

    window: int = 10_000
    buffer: memoryview | None = None  # ``stats_bytes(window)`` to live in (shared memory); private when None

    def __post_init__(self) -> None:
        buffer, split = self.buffer, window_bytes(self.window)
        self._counters = np.zeros(3, dtype=np.int64) if buffer is None else np.frombuffer(buffer[:24], np.int64)
        self.duration = RollingWindow(self.window, None if buffer is None else buffer[24 : 24 + split])
        self.period_error = RollingWindow(self.window, None if buffer is None else buffer[24 + split : 24 + 2 * split])
        self._percentiles: tuple[dict[str, float], dict[str, float]] | None = None
        self._percentiles_at = 0.0

    @property
    def cycles(self) -> int:
        return int(self._counters[_CYCLES])

    @property
    def overruns(self) -> int:
        return int(self._counters[_OVERRUNS])

    @property
    def consecutive_overruns(self) -> int:
        return int(self._counters[_CONSECUTIVE])

    @consecutive_overruns.setter
    def consecutive_overruns(self, value: int) -> None:
        self._counters[_CONSECUTIVE] = value

    def record(self, duration_ns: int, period_error_ns: int, overrun: bool) -> None:
        counters = self._counters
        counters[_CYCLES] += 1
        self.duration.add(duration_ns)
        self.period_error.add(period_error_ns)
        if overrun:
            counters[_OVERRUNS] += 1
            counters[_CONSECUTIVE] += 1
        else:
            counters[_CONSECUTIVE] = 0

    def summary(self, max_age: float = 0.0) -> dict[str, object]:
        """Counters (always current) and percentiles over the window.

        The percentiles cost CPU (and the GIL) on every call over a full window (docs/performance.md); a caller
        that may be polled fast (status) passes ``max_age`` to reuse ones computed less than that many seconds ago."""
        now = time.monotonic()
        if self._percentiles is None or now - self._percentiles_at > max_age:
            self._percentiles = (self.duration.summary_us(), self.period_error.summary_us())
            self._percentiles_at = now
        duration, period_error = self._percentiles
        return {
            "cycles": self.cycles,
            "overruns": self.overruns,
            "duration_us": dict(duration),
            "period_error_us": dict(period_error),
        }

    def reset(self) -> None:
        self._counters[:] = 0
        self.duration.reset()
        self.period_error.reset()
        self._percentiles = None
