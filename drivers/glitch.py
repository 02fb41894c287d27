"""Reading glitches for the simulated drivers (mock, twin): what a faulty encoder or readout would report.

The fault-injection suite uses these to check that no bad reading ever moves the arm. Only the *reported* state
is corrupted; the simulated shaft keeps its true position, as a real drive's readout glitch would. The CAN
emulators' firmwares carry one each (``MotorFirmware.glitch``, joint 0, actuator space), applied to the position
field of the replies they send.

Controls, per joint (plain attribute writes from a test, between cycles):
``offset`` rad added to the reported position for the next ``replies`` readings (-1: until cleared — a persistent
jump); ``value`` an absolute position reported instead (NaN: none; a spike beyond the limits); ``frozen`` the
reported position stops at its value while the velocity stays true; ``sign_flip`` reports −position.
"""

from __future__ import annotations

import math

import numpy as np


class ReadingGlitch:
    def __init__(self, n: int) -> None:
        self.offset = np.zeros(n)
        self.value = np.full(n, np.nan)
        self.replies = np.zeros(n, dtype=np.int64)  # readings left that carry offset/value; -1 = until cleared
        self.frozen = np.zeros(n, dtype=bool)
        self.sign_flip = np.zeros(n, dtype=bool)
        self._frozen_at = np.full(n, np.nan)
        self.active = False  # any control set: the read path checks this one flag and nothing else

    def set(self, i: int, *, offset: float = 0.0, value: float = math.nan, replies: int = -1) -> None:
        """Corrupt joint ``i``'s next ``replies`` readings (-1: until ``clear``) by ``offset`` or with ``value``."""
        self.offset[i], self.value[i], self.replies[i] = offset, value, replies
        self.active = True

    def freeze(self, i: int, on: bool = True) -> None:
        self.frozen[i] = on
        self._frozen_at[i] = math.nan
        self.active = True

    def flip(self, i: int, on: bool = True) -> None:
        self.sign_flip[i] = on
        self.active = True

    def clear(self) -> None:
        self.offset[:] = 0.0
        self.value[:] = np.nan
        self.replies[:] = 0
        self.frozen[:] = False
        self.sign_flip[:] = False
        self.active = False

    def apply(self, position: np.ndarray, fresh: np.ndarray) -> None:
        """Corrupt the fresh readings in ``position`` in place (after the driver filled it)."""
        for i in range(len(position)):
            if fresh[i]:
                position[i] = self.corrupt(i, float(position[i]))

    def corrupt(self, i: int, q: float) -> float:
        """Joint ``i``'s next reading, ``q`` as the sensor reports it (an emulated drive calls this per reply)."""
        if self.frozen[i]:
            if math.isnan(self._frozen_at[i]):
                self._frozen_at[i] = q
            q = float(self._frozen_at[i])
        if self.sign_flip[i]:
            q = -q
        if self.replies[i] != 0:
            q = float(self.value[i]) if not math.isnan(self.value[i]) else q + float(self.offset[i])
            if self.replies[i] > 0:
                self.replies[i] -= 1
        return q
