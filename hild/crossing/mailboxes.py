"""Mailboxes: how a controller (or the engine) gets the doors between its two halves.

A controller has an API half (``inputs()``, and its goals' client half ``hild.api.goals.GoalEndpoint``: validation and
planning) and a cycle half (``update``, and the ``hild.action.ActionServer`` it declares). In one process both halves
share an instance and the doors are plain objects (:class:`InProcess`). With the cycle in a process of its own, each
process builds the controller and the doors are cells of the shared region (:class:`Shared`): what one half puts in, the
other half's instance takes out. Nothing crosses as client bytes: the client's JSON is decoded and validated before
anything crosses. Streamed inputs the cycle takes every cycle cross as fixed-size float64 records (``latest_numbers``: a
copy into an array the door owns: no allocation, no unpickling). Requests, goals, replies and the status snapshot cross
as pickles of what their writer prepared (numpy arrays, dataclasses of them, segment tables), unpickled only when one
arrives.

The interfaces are those of :mod:`hild.crossing.inprocess` and :mod:`hild.crossing.ring`, so controller code is the
same either way.
"""

from __future__ import annotations

import pickle
import threading
from collections.abc import Sequence
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from hild.crossing.inprocess import BoundedQueue, LatestSlot
from hild.crossing.latest import LatestCell, NumbersCell, as_record, latest_bytes, numbers_bytes
from hild.crossing.queue import ByteQueue, queue_bytes
from hild.crossing.region import Region
from hild.crossing.ring import SampleRing, ring_bytes

T = TypeVar("T")

LATEST_BYTES = 64 * 1024  # a streamed command: a few hundred numbers at most
RECORD_BYTES = 64 * 1024  # a request or result record
_PROTOCOL = pickle.HIGHEST_PROTOCOL


class Latest(Protocol[T]):
    def put(self, value: T) -> None: ...
    def take(self) -> T | None: ...
    def clear(self) -> None: ...


class LatestNumbers(Protocol):
    """A latest-value door for a fixed number of float64s. ``take`` returns :attr:`values`, the door's own array,
    overwritten by the next take (even one that returns None): the cycle reads it without allocating."""

    width: int
    values: np.ndarray

    def put(self, values: Sequence[float] | np.ndarray) -> None: ...
    def take(self) -> np.ndarray | None: ...
    def clear(self) -> None: ...


class Queue(Protocol[T]):
    def offer(self, item: T) -> bool: ...
    def poll(self) -> T | None: ...
    def __len__(self) -> int: ...


class Flag:
    """A boolean one half sets and the other reads (e.g. a controller's ``active``)."""

    __slots__ = ("_cell",)

    def __init__(self, cell: np.ndarray | None = None) -> None:
        self._cell = np.zeros(1, dtype=np.int64) if cell is None else cell

    def __bool__(self) -> bool:
        return bool(self._cell[0])

    def set(self, value: bool) -> None:
        self._cell[0] = 1 if value else 0


class Mailboxes(Protocol):
    def latest(self, name: str, max_bytes: int = LATEST_BYTES) -> Latest[Any]: ...
    def latest_numbers(self, name: str, width: int) -> LatestNumbers: ...
    def queue(self, name: str, capacity: int, max_bytes: int = RECORD_BYTES) -> Queue[Any]: ...
    def ring(self, name: str, width: int, fields: Sequence[str], capacity: int = 256) -> SampleRing: ...
    def flag(self, name: str) -> Flag: ...
    def scoped(self, prefix: str) -> Mailboxes: ...


class InProcess:
    """Both halves in one process: the plain lock-free objects of :mod:`hild.crossing.inprocess`."""

    def latest(self, name: str, max_bytes: int = LATEST_BYTES) -> Latest[Any]:
        return LatestSlot()

    def latest_numbers(self, name: str, width: int) -> LatestNumbers:
        return NumbersSlot(width)

    def queue(self, name: str, capacity: int, max_bytes: int = RECORD_BYTES) -> Queue[Any]:
        return BoundedQueue(capacity)

    def ring(self, name: str, width: int, fields: Sequence[str], capacity: int = 256) -> SampleRing:
        return SampleRing(width, fields, capacity)

    def flag(self, name: str) -> Flag:
        return Flag()

    def scoped(self, prefix: str) -> InProcess:
        return self


class NumbersSlot:
    """The in-process :class:`LatestNumbers`: a :class:`LatestSlot` of copies, taken into the door's own array so
    the cycle half sees what it sees across processes (an array it may not keep)."""

    __slots__ = ("_slot", "values", "width")

    def __init__(self, width: int) -> None:
        self.width = width
        self.values = np.zeros(width)
        self._slot: LatestSlot[np.ndarray] = LatestSlot()

    def put(self, values: Sequence[float] | np.ndarray) -> None:
        self._slot.put(as_record(values, self.width))

    def take(self) -> np.ndarray | None:
        fresh = self._slot.take()
        if fresh is None:
            return None
        self.values[...] = fresh
        return self.values

    def clear(self) -> None:
        self._slot.clear()


class SharedLatest(Generic[T]):
    def __init__(self, cell: LatestCell) -> None:
        self._cell = cell

    def put(self, value: T) -> None:
        self._cell.put(pickle.dumps(value, _PROTOCOL))

    def take(self) -> T | None:
        raw = self._cell.take()
        return None if raw is None else pickle.loads(raw)

    def clear(self) -> None:
        self._cell.clear()


class SharedQueue(Generic[T]):
    """Bounded by bytes and by ``capacity`` records: a full queue refuses (the caller answers "busy")."""

    def __init__(self, queue: ByteQueue, capacity: int) -> None:
        self._queue = queue
        self.capacity = capacity

    def offer(self, item: T) -> bool:
        if len(self._queue) >= self.capacity:
            return False
        return self._queue.offer(pickle.dumps(item, _PROTOCOL))

    def poll(self) -> T | None:
        raw = self._queue.poll()
        return None if raw is None else pickle.loads(raw)

    def __len__(self) -> int:
        return len(self._queue)


class Shared:
    """Cells of a shared region, named ``<prefix><name>``: the region's creator carves them (``create``), the cycle
    process and the client domain find them. Each end may be used by several threads of the client domain, so each
    cell gets a process-local lock for its writers and one for its readers; in the single-threaded cycle process
    they are never contended."""

    def __init__(self, region: Region, *, create: bool, prefix: str = "") -> None:
        self.region = region
        self.create = create
        self.prefix = prefix

    def _cell(self, name: str, nbytes: int) -> memoryview:
        full = self.prefix + name
        return self.region.carve(full, nbytes) if self.create else self.region.find(full, nbytes)

    def cell(self, name: str, nbytes: int) -> memoryview:
        """A raw cell, for a structure that lays itself out (e.g. ``hild.crossing.stats.LoopStats``)."""
        return self._cell(name, nbytes)

    def numbers(self, name: str, count: int, dtype: type[np.generic] = np.int64) -> np.ndarray:
        """``count`` numbers one side writes and the other reads; each is one aligned 8-byte store, never torn."""
        return np.frombuffer(self._cell(name, 8 * count), dtype=dtype, count=count)

    def latest(self, name: str, max_bytes: int = LATEST_BYTES) -> Latest[Any]:
        return SharedLatest(LatestCell(self._cell(name, latest_bytes(max_bytes)), writer_lock=threading.Lock()))

    def latest_numbers(self, name: str, width: int) -> LatestNumbers:
        return NumbersCell(self._cell(name, numbers_bytes(width)), width, writer_lock=threading.Lock())

    def queue(self, name: str, capacity: int, max_bytes: int = RECORD_BYTES) -> Queue[Any]:
        cell = self._cell(name, queue_bytes(2 * (max_bytes + 16)))
        return SharedQueue(ByteQueue(cell, producer_lock=threading.Lock(), consumer_lock=threading.Lock()), capacity)

    def ring(self, name: str, width: int, fields: Sequence[str], capacity: int = 256) -> SampleRing:
        return SampleRing(width, fields, capacity, buffer=self._cell(name, ring_bytes(width, fields, capacity)))

    def flag(self, name: str) -> Flag:
        return Flag(self.numbers(name, 1))

    def scoped(self, prefix: str) -> Shared:
        return Shared(self.region, create=self.create, prefix=f"{self.prefix}{prefix}/")

    def carving(self) -> Shared:
        """The same cells, carved rather than found: a client domain's, for a controller loaded while it runs."""
        return Shared(self.region, create=True, prefix=self.prefix)

    def finding(self) -> Shared:
        """The same cells, found rather than carved: given-back cells a new load uses again."""
        return Shared(self.region, create=False, prefix=self.prefix)
