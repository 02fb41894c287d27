"""What the client domain (the API, the daemon's housekeeping) needs of the cycle, wherever the cycle runs."""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable
from typing import Any, Protocol

from hild.config.loader import LoadedConfig
from hild.crossing.events import EventLog
from hild.crossing.requests import Request
from hild.crossing.snapshot import Snapshot
from hild.crossing.stats import LoopStats


class CycleLink(Protocol):
    """Met by :class:`hild.cycle.engine.Engine` (the cycle in this process) and :class:`hild.daemon.remote.RemoteCycle`
    (the cycle in a process of its own)."""

    robot: str
    joints: tuple[str, ...]
    update_rate: float
    loaded: LoadedConfig
    events: EventLog  # where the client domain's own events go; the daemon drains it
    stats: LoopStats  # readable from the client domain
    take_inputs: Callable[[], None] | None  # set by the API: the cycle takes inputs with it, unless inputs_on_arrival
    inputs_on_arrival: bool  # inputs are handed over as they arrive (the cycle is elsewhere: nothing for it to take)

    @property
    def change_seq(self) -> int: ...

    @property
    def cycle(self) -> int: ...

    @property
    def t(self) -> float: ...  # the cycle clock: wall time since start, or the sim clock t = k·dt

    def request(self, request: Request) -> concurrent.futures.Future[Any]: ...

    def request_estop(self) -> concurrent.futures.Future[Any]: ...

    def snapshot(self) -> Snapshot: ...

    def overall_mode(self) -> str: ...

    def status(self) -> dict[str, Any]: ...

    def controllers(self) -> dict[str, Any]: ...
