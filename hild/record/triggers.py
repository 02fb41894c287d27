"""When the flight recorder writes on its own: a fault newly latched, the e-stop engaged, the cycle stalled.

Watched from the client domain (an asyncio task of the daemon): faults and the e-stop from the snapshot whenever
``change_seq`` moves, a stall from the cycle count not moving for ``recording.stall_after`` while the cycle is live.
A trigger starts a burst: the file is written ``DELAY`` after its first trigger (so it shows what followed), and
every trigger until the burst has been quiet for ``QUIET`` joins it, so a fault that latches joint after joint, or an
e-stop that faults the arm, writes one file, not one per joint.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable, Iterable
from typing import Any, Protocol

log = logging.getLogger("hild.record")

FAULT, ESTOP, STALL = "fault", "estop", "stall"  # recording.blackbox_on's words, and the file names' reasons
DELAY = 0.5  # s after the first trigger before the file is written: it shows what followed too
QUIET = 2.0  # s without a trigger that end a burst
POLL = 0.05  # s between two looks at the cycle (the stall check polls at most stall_after / 4)


class Watched(Protocol):
    """What the triggers read of the cycle (a ``CycleLink``)."""

    @property
    def change_seq(self) -> int: ...

    @property
    def cycle(self) -> int: ...

    def snapshot(self) -> Any: ...


def faults_of(snapshot: Any) -> dict[str, str]:
    """The latched fault of every faulted joint."""
    return {j["name"]: j["fault"] for j in snapshot.joints if j.get("fault")}


class BlackBoxTriggers:
    """Calls ``write(reason)`` once per burst of triggers (``on``: the reasons that trigger)."""

    def __init__(
        self,
        cycle: Watched,
        write: Callable[[str], Awaitable[Any]],
        on: Iterable[str],
        stall_after: float,
        *,
        live: Callable[[], bool] = lambda: True,
        delay: float = DELAY,
        quiet: float = QUIET,
    ) -> None:
        self.cycle = cycle
        self.write = write
        self.on = frozenset(on)
        self.stall_after = stall_after
        self.live = live
        self.delay = delay
        self.quiet = quiet
        self.poll = min(POLL, stall_after / 4) if STALL in self.on and stall_after > 0 else POLL
        self.written: list[str] = []  # the reasons of the files written, in order (tests, status)
        self._seq: int | None = None
        self._faults: dict[str, str] = {}
        self._estop = False
        self._cycle = -1
        self._moved = time.monotonic()
        self._stalled = False
        self._burst: tuple[str, float] | None = None  # (reason, monotonic of the first trigger)
        self._last_trigger = -float("inf")

    # ---- watching --------------------------------------------------------------------------------------------
    def check(self, now: float | None = None) -> str | None:
        """Look at the cycle once; returns the reason of a trigger that fired now (for tests), else None."""
        now = time.monotonic() if now is None else now
        fired = None
        seq = self.cycle.change_seq
        if seq != self._seq:
            fired = self._changed(self.cycle.snapshot(), self._seq is None, now)
            self._seq = seq
        cycle = self.cycle.cycle
        if cycle != self._cycle:
            self._cycle, self._moved, self._stalled = cycle, now, False
        elif not self._stalled and now - self._moved >= self.stall_after and self.live():
            self._stalled = True  # once per stall: a cycle that moves again re-arms it
            if STALL in self.on and self.stall_after > 0:
                fired = self.trigger(STALL, f"no new cycle for {now - self._moved:.2f} s", now) or fired
        return fired

    def _changed(self, snapshot: Any, first: bool, now: float) -> str | None:
        faults, estop = faults_of(snapshot), snapshot.mode == "estop"
        new = {j: f for j, f in faults.items() if j not in self._faults}
        engaged = estop and not self._estop
        self._faults, self._estop = faults, estop
        if first:  # what was latched before we looked is not news
            return None
        fired = None
        if engaged and ESTOP in self.on:
            fired = self.trigger(ESTOP, "e-stop engaged", now)
        if new and FAULT in self.on:
            words = ", ".join(f"{j}: {f}" for j, f in new.items())
            fired = self.trigger(FAULT, f"fault latched ({words})", now) or fired
        return fired

    def trigger(self, reason: str, why: str, now: float | None = None) -> str | None:
        """A trigger: starts a burst (a file ``delay`` from now) or joins the one running. Returns ``reason`` if it
        started a burst."""
        now = time.monotonic() if now is None else now
        started = None
        if self._burst is None and now - self._last_trigger >= self.quiet:
            self._burst = (reason, now)
            started = reason
            log.info("black box: %s; writing the flight recorder in %g s", why, self.delay)
        self._last_trigger = now
        return started

    def due(self, now: float | None = None) -> str | None:
        """The reason of a burst whose file is due now (taken: it is written once)."""
        now = time.monotonic() if now is None else now
        if self._burst is not None and now - self._burst[1] >= self.delay:
            reason, self._burst = self._burst[0], None
            return reason
        return None

    # ---- the task ------------------------------------------------------------------------------------------------
    async def run(self) -> None:
        """Watch until cancelled (an asyncio task of the daemon)."""
        while True:
            try:
                self.check()
                reason = self.due()
                if reason is not None:
                    await self._write(reason)
            except asyncio.CancelledError:
                raise
            except Exception:  # a trigger must never take the daemon down
                log.exception("black box triggers failed")
            await asyncio.sleep(self.poll)

    async def flush(self) -> None:
        """A burst still waiting is written now (the daemon stops)."""
        if self._burst is not None:
            reason, self._burst = self._burst[0], None
            await self._write(reason)

    async def _write(self, reason: str) -> None:
        self.written.append(reason)
        try:
            await self.write(reason)
        except Exception as exc:
            log.error("black box (%s) not written: %s", reason, exc)
