"""The in-process doors: between the asyncio loop and a cycle thread of the same process.

Used when the cycle runs in the daemon's own process (``realtime.cycle_process: false``, lockstep tests,
embedding); across processes the doors are cells of the shared region (:class:`hild.crossing.mailboxes.Shared`).
Both are lock-free under the GIL: a reference swap or a ``deque`` append/popleft is atomic, so the cycle thread
never waits on a lock held by the I/O side. Anything that allocates (parsing, validating, copying into a fresh
array) happens on the producer's side before the swap.
"""

from __future__ import annotations

import itertools
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestSlot(Generic[T]):
    """Keeps only the newest value (streamed commands): a slow consumer skips, it never queues up."""

    __slots__ = ("_item", "_seen", "_seq")

    def __init__(self) -> None:
        self._seq = itertools.count(1)
        self._item: tuple[int, T] | None = None
        self._seen = 0

    def put(self, value: T) -> None:
        self._item = (next(self._seq), value)

    def take(self) -> T | None:
        """The newest value if it was not taken before, else None."""
        item = self._item
        if item is None or item[0] == self._seen:
            return None
        self._seen = item[0]
        return item[1]

    def clear(self) -> None:
        """Forget anything pending (e.g. a command sent while the consumer was inactive)."""
        item = self._item
        if item is not None:
            self._seen = item[0]


class BoundedQueue(Generic[T]):
    """A FIFO that refuses instead of growing: a flood of requests cannot exhaust memory."""

    __slots__ = ("_items", "capacity")

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._items: deque[T] = deque()

    def offer(self, item: T) -> bool:
        if len(self._items) >= self.capacity:
            return False
        self._items.append(item)
        return True

    def poll(self) -> T | None:
        try:
            return self._items.popleft()
        except IndexError:
            return None

    def __len__(self) -> int:
        return len(self._items)
