"""A preallocated single-producer ring: the cycle writes samples, the asyncio side reads them.

The producer fills slot ``head % capacity`` in place and only then advances ``head``, so a reader that reads up
to ``head`` sees complete samples. A reader that falls more than ``capacity`` behind skips ahead and counts the
loss: outputs drop under congestion, they never block the cycle.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class SampleRing:
    def __init__(self, width: int, fields: Sequence[str], capacity: int = 256) -> None:
        self.width = width
        self.capacity = capacity
        self.fields = tuple(fields)
        self.stamp = np.zeros(capacity)
        self.seq = np.zeros(capacity, dtype=np.int64)
        self.data = {f: np.zeros((capacity, width)) for f in self.fields}
        self.head = 0  # number of samples ever written

    def slot(self) -> int:
        """Index of the slot the producer fills next (then it calls ``commit``)."""
        return self.head % self.capacity

    def commit(self, stamp: float) -> None:
        i = self.head % self.capacity
        self.stamp[i] = stamp
        self.seq[i] = self.head
        self.head += 1


class RingReader:
    """One consumer's position in a ring."""

    def __init__(self, ring: SampleRing, start_at_head: bool = True) -> None:
        self.ring = ring
        self.next = ring.head if start_at_head else 0
        self.dropped = 0

    def read(self) -> list[tuple[int, float, dict[str, list[float]]]]:
        """New samples as ``(seq, stamp, {field: values})``, oldest first."""
        ring = self.ring
        head = ring.head
        if head - self.next > ring.capacity - 1:  # keep one slot of margin against the producer
            skip = head - (ring.capacity - 1)
            self.dropped += skip - self.next
            self.next = skip
        out = []
        for n in range(self.next, head):
            i = n % ring.capacity
            out.append((n, float(ring.stamp[i]), {f: ring.data[f][i].tolist() for f in ring.fields}))
        self.next = head
        return out
