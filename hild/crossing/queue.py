"""A bounded queue of byte records in shared memory, one producer and one consumer, no lock between them.

The producer writes a record, then advances ``head``; the consumer reads up to ``head``, then advances
``tail``. Each counter has one writer, so neither side ever waits for the other: a full queue refuses the record
(the caller answers "busy"), an empty one returns None. Records are a length word and the bytes, 8-byte aligned;
one that does not fit before the end of the buffer is preceded by a wrap marker and written at its start.

Both ends may be shared by several threads of *one* process (the client domain's Zenoh and worker threads):
give that end a ``threading.Lock``. The cycle process has a single thread and takes no lock.
"""

from __future__ import annotations

import struct
import threading
from contextlib import nullcontext

import numpy as np

HEADER = 128  # producer's words in the first cache line, consumer's in the second
_WORD = struct.Struct("<q")
_WRAP = -1


def _padded(n: int) -> int:
    return (n + 7) & ~7


def queue_bytes(capacity: int) -> int:
    """Cell size for a queue with ``capacity`` bytes of records (lengths included)."""
    return HEADER + _padded(capacity)


class ByteQueue:
    """Records of at most ``max_record`` bytes (half the buffer, so one always fits once the queue drains)."""

    def __init__(
        self,
        cell: memoryview,
        *,
        producer_lock: threading.Lock | None = None,
        consumer_lock: threading.Lock | None = None,
    ) -> None:
        self.capacity = len(cell) - HEADER
        if self.capacity <= 16 or self.capacity % 8:
            raise ValueError(f"a queue cell needs a multiple of 8 bytes beyond its {HEADER}-byte header")
        self.max_record = self.capacity // 2 - 8
        words = np.frombuffer(cell, dtype=np.int64, count=HEADER // 8)
        self._head, self._tail = words[0:2], words[8:10]  # [bytes, records] for each end
        self._data = cell[HEADER:]
        self._put_lock = producer_lock or nullcontext()
        self._take_lock = consumer_lock or nullcontext()

    def __len__(self) -> int:
        return max(0, int(self._head[1]) - int(self._tail[1]))

    def offer(self, record: bytes | bytearray | memoryview) -> bool:
        """Append ``record``; False when there is no room now (never waits)."""
        n = len(record)
        if n > self.max_record:
            raise ValueError(f"a record of {n} bytes exceeds this queue's {self.max_record}-byte limit")
        with self._put_lock:
            head, capacity = int(self._head[0]), self.capacity
            at = head % capacity
            need = 8 + _padded(n)
            skip = capacity - at if at + need > capacity else 0
            if head + skip + need - int(self._tail[0]) > capacity:
                return False
            if skip:
                if skip >= 8:
                    _WORD.pack_into(self._data, at, _WRAP)
                at = 0
            self._data[at + 8 : at + 8 + n] = record
            _WORD.pack_into(self._data, at, n)
            self._head[0] = head + skip + need  # the record is complete before the consumer can see it
            self._head[1] += 1
            return True

    def poll(self) -> bytes | None:
        """The oldest record, or None when the queue is empty."""
        with self._take_lock:
            tail, capacity = int(self._tail[0]), self.capacity
            if tail == int(self._head[0]):
                return None
            at = tail % capacity
            if capacity - at < 8 or _WORD.unpack_from(self._data, at)[0] == _WRAP:
                tail += capacity - at
                at = 0
            n = _WORD.unpack_from(self._data, at)[0]
            record = bytes(self._data[at + 8 : at + 8 + n])
            self._tail[0] = tail + 8 + _padded(n)
            self._tail[1] += 1
            return record
