"""Plausibility before trust, for sensors: each sensor's reading is checked before a controller sees it.

A sensor's reading (all its values together) is **accepted** only when

* every value is finite,
* every limited value lies within its range (``hardware.<c>.sensors.<s>.limits``: force, torque, angular velocity,
  linear acceleration; orientation is unbounded), and
* it is not **frozen**: bit-identical to the readings before it for ``frozen_cycles`` readings in a row. A real
  sensor's values carry noise; a reading that never changes is a dead sensor or a stuck driver buffer.

A rejected reading is replaced by the last accepted one and the sensor marked not fresh, as a missing reading is.
A sensor without an accepted reading for ``safety.stale_feedback_cycles`` cycles gets a **sensor fault**: an error
event and a fault in status, latched until an operator ``reset`` clears it. A sensor fault never faults a joint
(nothing commands the arm from a sensor yet); controllers see ``fresh`` false. Each episode of rejections is
reported once when it starts (with its reason) and once when it ends, never per cycle.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from hild.arrays import SensorValues
from hild.interfaces import SensorLayout

NONE, NON_FINITE, OUT_OF_RANGE, FROZEN = 0, 1, 2, 3

EmitFn = Callable[[str, str, str], None]  # (level, source, message)


class SensorGate:
    """Checks the drivers' sensor readings (``raw``) and keeps the accepted ones (``accepted``, ``fresh``)."""

    def __init__(self, layout: SensorLayout, frozen_cycles: Sequence[int], stale_cycles: int, emit: EmitFn) -> None:
        self.layout = layout
        self.emit = emit
        n = len(layout.sensors)
        self.raw = SensorValues.zeros(layout.width, n)  # what the drivers write
        self.accepted = np.full(layout.width, np.nan)  # published: the last accepted values (NaN: none yet)
        self.fresh = np.zeros(n, dtype=bool)  # published: this cycle's values are a new accepted reading
        self.fault_text: list[str] = [""] * n  # published: the latched sensor fault, "" when none
        self.cause = [NONE] * n  # why the current episode of rejections began
        self.reason: list[str] = [""] * n
        self.change_seq = 0  # bumped when a fault latches or clears
        self._parts = [s.part for s in layout.sensors]
        self._bounds = [list(s.bounds) for s in layout.sensors]
        self._frozen_cycles = list(frozen_cycles)
        self._stale_cycles = stale_cycles
        self._last_raw: list[list[float]] = [[math.nan] * s.width for s in layout.sensors]
        self._repeats = [0] * n  # readings in a row bit-identical to the one before (the first counts as 1)
        self._silent = [0] * n  # cycles since the last accepted reading
        self._rejections = [0] * n

    # ---- the cycle -----------------------------------------------------------------------------------------
    def filter(self) -> None:
        """Accept or reject each sensor's reading; a sensor silent too long faults (once, until reset)."""
        raw, fresh_in, accepted = self.raw.values, self.raw.fresh, self.accepted
        fresh_out = self.fresh
        isfinite = math.isfinite
        for k, part in enumerate(self._parts):
            if not fresh_in[k]:
                self._missing(k)
                continue
            values = raw[part].tolist()
            why = NONE
            bounds = self._bounds[k]
            for i, v in enumerate(values):
                if not isfinite(v):
                    why = NON_FINITE
                    break
                if v > bounds[i] or v < -bounds[i]:
                    why = OUT_OF_RANGE
                    break
            if why == NONE:
                if values == self._last_raw[k]:
                    self._repeats[k] += 1
                    if self._repeats[k] >= self._frozen_cycles[k]:
                        why = FROZEN
                else:
                    self._repeats[k] = 1
                self._last_raw[k] = values
            if why != NONE:
                if self.cause[k] == NONE:
                    self._begin_episode(k, why, values)
                self._rejections[k] += 1
                self._missing(k)
                continue
            accepted[part] = raw[part]
            self._silent[k] = 0
            if not fresh_out[k]:
                fresh_out[k] = True
            if self.cause[k] != NONE:
                self._end_episode(k)

    def _missing(self, k: int) -> None:
        """No accepted reading for sensor ``k`` this cycle: the last accepted values stay, not fresh."""
        if self.fresh[k]:
            self.fresh[k] = False
        self._silent[k] += 1
        if self._silent[k] >= self._stale_cycles and not self.fault_text[k]:
            name = self.layout.sensors[k].name
            why = f" (last rejected: {self.reason[k]})" if self.cause[k] != NONE else ""
            self.fault_text[k] = f"no accepted reading for {self._silent[k]} cycles{why}"
            self.change_seq += 1
            self.emit("error", name, f"sensor {name} fault: {self.fault_text[k]}")

    def _begin_episode(self, k: int, why: int, values: list[float]) -> None:
        spec = self.layout.sensors[k]
        self.cause[k] = why
        self._rejections[k] = 0
        if why == NON_FINITE:
            text = f"non-finite value in {dict(zip(spec.values, values, strict=True))}"
        elif why == OUT_OF_RANGE:
            i = next(i for i, v in enumerate(values) if abs(v) > self._bounds[k][i])
            text = f"{spec.values[i]} = {values[i]:.4g} beyond its range ±{self._bounds[k][i]:g}"
        else:
            text = f"values bit-identical for {self._repeats[k]} readings in a row (frozen)"
        self.reason[k] = text
        self.emit("warning", spec.name, f"sensor {spec.name}: reading rejected: {text}; the last accepted one stays")

    def _end_episode(self, k: int) -> None:
        name = self.layout.sensors[k].name
        self.cause[k] = NONE
        self.emit("info", name, f"sensor {name}: readings plausible again after {self._rejections[k]} rejected")

    # ---- between cycles ------------------------------------------------------------------------------------
    def reset(self) -> list[str]:
        """Clear latched sensor faults (an operator ``reset``); a sensor still silent faults again. What cleared."""
        cleared = []
        for k, text in enumerate(self.fault_text):
            if text:
                cleared.append(f"sensor {self.layout.sensors[k].name}: {text}")
                self.fault_text[k] = ""
                self._silent[k] = 0
        if cleared:
            self.change_seq += 1
        return cleared

    def faulted(self) -> bool:
        return any(self.fault_text)
