"""A preallocated single-producer ring: the cycle writes samples, the client domain reads them.

The producer fills slot ``head % capacity`` in place and only then advances ``head``, so a reader that reads up
to ``head`` sees complete samples. A reader that falls more than ``capacity`` behind skips ahead and counts the
loss: outputs drop under congestion, they never block the cycle. The arrays live in ordinary memory, or in a
cell of the shared region (``buffer``) when the producer is the cycle process; then a reader also checks, after
copying a slot, that the producer did not overwrite it meanwhile.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

_HEADER = 64  # head, in its own cache line


def ring_bytes(width: int, fields: Sequence[str], capacity: int) -> int:
    """Size of the shared cell a ring of this shape needs."""
    return _HEADER + 8 * capacity * (2 + width * len(fields))


class SampleRing:
    def __init__(
        self, width: int, fields: Sequence[str], capacity: int = 256, buffer: memoryview | None = None
    ) -> None:
        self.width = width
        self.capacity = capacity
        self.fields = tuple(fields)
        if buffer is None:
            buffer = memoryview(bytearray(ring_bytes(width, self.fields, capacity)))
        elif len(buffer) != ring_bytes(width, self.fields, capacity):
            raise ValueError("the ring's buffer does not fit its shape")
        words = np.frombuffer(buffer, dtype=np.float64)
        self._head = words[:1].view(np.int64)
        at = _HEADER // 8
        self.stamp = words[at : at + capacity]
        self.seq = words[at + capacity : at + 2 * capacity].view(np.int64)
        at += 2 * capacity
        self.data = {}
        for f in self.fields:
            self.data[f] = words[at : at + capacity * width].reshape(capacity, width)
            at += capacity * width

    @property
    def head(self) -> int:
        """Number of samples ever written."""
        return int(self._head[0])

    def slot(self) -> int:
        """Index of the slot the producer fills next (then it calls ``commit``)."""
        return int(self._head[0]) % self.capacity

    def commit(self, stamp: float) -> None:
        head = int(self._head[0])
        i = head % self.capacity
        self.stamp[i] = stamp
        self.seq[i] = head
        self._head[0] = head + 1


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
            sample = (n, float(ring.stamp[i]), {f: ring.data[f][i].tolist() for f in ring.fields})
            if ring.seq[i] != n or ring.head - n >= ring.capacity:  # overwritten while we copied it
                self.dropped += 1
                continue
            out.append(sample)
        self.next = head
        return out
