"""The seam between the client domain and the cycle, wherever the cycle runs (docs/architecture.md).

:class:`CycleLink` is what the API needs: the cycle's figures, its snapshot, and requests in. :class:`CycleHost` adds
what the daemon needs to bring the cycle up, watch it and stop it. Three classes meet both, and the daemon never asks
which it has: :class:`hild.daemon.remote.AttachedCycle` (``hild run``: the cycle process the main process started),
:class:`hild.daemon.remote.SpawnedCycle` (a cycle process this process starts: embedding, the bench) and
:class:`hild.daemon.local.LocalCycle` (the engine on a thread of this process: lockstep tests,
``realtime.cycle_process: false``).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
from collections.abc import Callable
from typing import Any, Protocol

from hild.config.loader import LoadedConfig
from hild.crossing.cyclelog import CycleLogPlace
from hild.crossing.events import Event, EventLog
from hild.crossing.requests import Request
from hild.crossing.snapshot import Snapshot
from hild.crossing.stats import LoopStats
from hild.main.notify import ServiceReport, SilentReport, SystemdNotifier


class StartupError(RuntimeError):
    """The daemon could not start; the message says why, for the log and systemd's status line."""


class StartRefused(StartupError):
    """Refused before any hardware was opened: the robot's name or the Zenoh port is taken."""


class CycleLink(Protocol):
    """What the API reads of the cycle and asks of it."""

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

    def cycle_log(self) -> tuple[int, CycleLogPlace] | None:
        """The memfd the cycle log is in and where in it (``CycleLog.attach`` maps it; the fd stays the link's: a
        recorder process gets its own through ``multiprocessing.reduction.send_handle``). None when
        ``recording.enabled`` is false: the cycle writes no cycle log then."""


class CycleHost(CycleLink, Protocol):
    """What the daemon does with the cycle, in the order it does it."""

    signals: tuple[int, ...]  # the signals this process handles (the top process of the unit takes SIGINT too)
    signal_meaning: str  # what a signal does, for the log
    restarted_after: str | None  # why the previous client domain ended, when this one replaces it
    main_pid: int  # the process systemd and an operator stop to stop this daemon (a refused second one names it)
    releases_hardware: bool  # this process's stop releases the hardware (else the main process's, which says so)
    realtime_report: dict[str, str]  # merged into the status reply's ``realtime``

    @property
    def telemetry_stats(self) -> LoopStats | None: ...  # loop statistics the recorder reads here, if any

    def service_report(self, notifier: SystemdNotifier) -> ServiceReport | SilentReport: ...

    def watch(self, loop: asyncio.AbstractEventLoop, on_events: Callable[[list[Event]], None]) -> None:
        """Whenever the cycle rings: answer the replies it sent (the request's own way back), then hand its events
        to ``on_events``, on ``loop``."""

    def take(self) -> list[Event]: ...  # the same, called: replies answered, events returned

    async def bring_up(self, telemetry: Any) -> None: ...  # hardware configured and read, drives disabled

    async def go_live(self) -> None: ...  # drives enabled and cycling

    def serving(self) -> None: ...  # the API is up

    def describe(self) -> str: ...  # for the "running" log line

    def gone(self) -> tuple[int, str | None] | None: ...  # (exit code, why) once the daemon must end, else None

    def stopping(self) -> bool: ...  # the daemon's stop has begun elsewhere: the main process is stopping the cycle

    async def stop(self, timeout: float) -> bool: ...  # True if the cycle stopped (or is not ours to stop)

    def refused(self) -> None: ...  # the API did not come up: release what was brought up

    def start_failed(self) -> None: ...  # a failed start was logged here: the main process must not say it again

    def close(self) -> None: ...
