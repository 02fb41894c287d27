"""The engine's cells in the shared region: carved by the main process (embedded: by the client domain's link),
found by the cycle process and by each client domain (docs/architecture.md, "What crosses").

Who writes what (one writer per cell, or per number of ``asks``, so nobody waits on anybody):

- client domain → cycle: ``asks`` (go, the e-stop counter) and the ``requests`` queue; the main process → cycle:
  ``asks`` (stop, the client-domain-lost counter);
- client domain → main process: ``client`` (its phase and pid); ``telemetry``, the ring its recorder reads (taken
  by the main process at the first start, by the cycle after a client domain's restart);
- cycle → client domain: ``replies`` and ``events`` queues, the ``snapshot`` (written when ``change_seq`` moves),
  ``loads`` (how each loaded controller was loaded: a restarted client domain builds their API halves from it),
  the e-stop reply, the start-up ``failure``, ``vitals`` (phase, cycle count, change_seq …), ``clock`` (the cycle
  clock and each joint's longest silence) and the loop statistics; ``cycle_log``, every cycle's row (read by the
  client domain's recorder process, which maps it from the region's fd and a ``CycleLogPlace``; only when
  ``recording.enabled``).
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from hild.crossing.cyclelog import CycleLog, CycleLogPlace, cycle_log_bytes
from hild.crossing.mailboxes import Latest, Queue, Shared
from hild.crossing.region import Region
from hild.crossing.stats import LoopStats, stats_bytes

REGION_BYTES = 2 << 30  # virtual: a memfd is backed only where written (goal queues are sized for 1 MiB goals)
REQUESTS = 64  # requests in flight; more are refused "busy" (as the engine's own queue does)
RECORD_BYTES = 256 * 1024  # a request or reply record (a request is at most 64 KiB of JSON)
EVENTS = 4096  # events in flight; the oldest are counted lost when the client domain does not drain them
EVENT_BYTES = 512 * 1024
SNAPSHOT_BYTES = 1 << 20
LOADS_BYTES = 16 << 20  # every loaded controller's type and params: MAX_CONTROLLERS of at most 64 KiB of JSON each
MAX_CONTROLLERS = 64  # loaded at once; a load beyond is refused
STATS_WINDOW = 10_000


class Phase(IntEnum):
    FAILED = -1
    STARTING = 0
    BROUGHT_UP = 1  # hardware configured and read, drives disabled: waiting for ``go``
    LIVE = 2
    STOPPED = 3


class Ask(IntEnum):  # written by the client domain (GO, ESTOP) or the main process (STOP, CLIENT_LOST)
    GO = 0
    STOP = 1
    ESTOP = 2  # a counter: each e-stop request adds one
    CLIENT_LOST = 3  # a counter: each client domain that ended while the cycle ran adds one


class ClientPhase(IntEnum):
    FAILED = -1  # start-up failed and the client domain has logged why: the main process does not say it again
    STARTING = 0
    OPEN = 1  # Zenoh is open and this robot's name is ours: the cycle process may touch the hardware
    SERVING = 2  # the API answers and the cycle is live
    STOPPED = 3


class ClientVital(IntEnum):  # the client domain's cells, read by the main process
    PHASE = 0
    PID = 1


class Vital(IntEnum):  # the cycle's cells
    PHASE = 0
    CYCLE = 1
    CHANGE_SEQ = 2
    ESTOP_DONE = 3  # the e-stop counter the last applied e-stop answered
    EVENTS_LOST = 4
    PYTHON_THREADS = 5  # threads of the cycle process (steady state: the cycle alone)
    STARTED = 6
    PID = 7  # the cycle process's pid
    CLIENT_LOST_SEEN = 8  # the CLIENT_LOST counter the cycle has acted on (goals aborted, joints held)


class EngineCells:
    """``cycle_log``: the cycle log's capacity in rows (``hild.crossing.cyclelog.capacity_of``; 0: no cycle log)."""

    def __init__(self, region: Region, joints: int, *, create: bool, cycle_log: int = 0) -> None:
        shared = Shared(region, create=create, prefix="engine/")
        self.requests: Queue[object] = shared.queue("requests", REQUESTS, RECORD_BYTES)
        self.replies: Queue[object] = shared.queue("replies", REQUESTS, RECORD_BYTES)
        self.events: Queue[object] = shared.queue("events", EVENTS, EVENT_BYTES)
        self.snapshot: Latest[object] = shared.latest("snapshot", SNAPSHOT_BYTES)
        self.loads: Latest[object] = shared.latest("loads", LOADS_BYTES)
        self.estop_reply: Latest[object] = shared.latest("estop_reply", RECORD_BYTES)
        self.failure: Latest[object] = shared.latest("failure", RECORD_BYTES)
        self.asks = shared.numbers("asks", len(Ask))
        self.client = shared.numbers("client", len(ClientVital))
        self.telemetry: Latest[object] = shared.latest("telemetry", 4096)  # the client's TelemetryRing, or None
        self.vitals = shared.numbers("vitals", len(Vital))
        self.clock = shared.numbers("clock", 1 + joints, np.float64)  # t, then each joint's longest silence (s)
        self.stats = LoopStats(STATS_WINDOW, buffer=shared.cell("stats", stats_bytes(STATS_WINDOW)))
        self.cycle_log: CycleLog | None = None
        self.cycle_log_place: CycleLogPlace | None = None
        if cycle_log:
            nbytes = cycle_log_bytes(joints, cycle_log)
            self.cycle_log = CycleLog(shared.cell("cycle_log", nbytes), joints, cycle_log, create=create)
            offset = next(at for name, at, _ in region.cells() if name == "engine/cycle_log")
            self.cycle_log_place = CycleLogPlace(region.size, offset, nbytes, joints, cycle_log)
