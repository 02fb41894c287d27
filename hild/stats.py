"""Cheap rolling loop statistics.

The cycle thread only stores integers into preallocated windows and bumps counters; percentiles are computed on
demand by whoever asks (status, bench) on the asyncio side, from a copy of the window.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class RollingWindow:
    __slots__ = ("count", "max", "values")

    def __init__(self, size: int) -> None:
        self.values = np.zeros(size, dtype=np.int64)
        self.count = 0
        self.max = 0

    def add(self, value_ns: int) -> None:
        self.values[self.count % len(self.values)] = value_ns
        self.count += 1
        if value_ns > self.max:
            self.max = value_ns

    def summary_us(self) -> dict[str, float]:
        n = min(self.count, len(self.values))
        if n == 0:
            return {"p50": 0.0, "p99": 0.0, "p999": 0.0, "max": 0.0}
        window = self.values[:n].copy()
        p50, p99, p999 = np.percentile(window, [50, 99, 99.9]) / 1e3
        return {"p50": round(p50, 1), "p99": round(p99, 1), "p999": round(p999, 1), "max": round(self.max / 1e3, 1)}

    def reset(self) -> None:
        self.count = 0
        self.max = 0


@dataclass
class LoopStats:
    """Cycle duration (wake → write done), period error (|Δwake − T|), overruns (deadline missed)."""

    window: int = 10_000

    def __post_init__(self) -> None:
        self.duration = RollingWindow(self.window)
        self.period_error = RollingWindow(self.window)
        self.cycles = 0
        self.overruns = 0
        self.consecutive_overruns = 0

    def record(self, duration_ns: int, period_error_ns: int, overrun: bool) -> None:
        self.cycles += 1
        self.duration.add(duration_ns)
        self.period_error.add(period_error_ns)
        if overrun:
            self.overruns += 1
            self.consecutive_overruns += 1
        else:
            self.consecutive_overruns = 0

    def summary(self) -> dict[str, object]:
        return {
            "cycles": self.cycles,
            "overruns": self.overruns,
            "duration_us": self.duration.summary_us(),
            "period_error_us": self.period_error.summary_us(),
        }

    def reset(self) -> None:
        self.__post_init__()
