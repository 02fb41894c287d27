"""systemd's notification protocol (sd_notify(3)), hand-written, plus the rule for when a watchdog ping is earned.

The protocol is one ``AF_UNIX``/``SOCK_DGRAM`` datagram of newline-separated ``KEY=value`` lines sent to
``$NOTIFY_SOCKET`` (a path, or ``@name`` for an abstract socket). Twenty lines of our own beat a dependency: the
maintained packages either need libsystemd and a compiler or swallow every error silently.

The client never raises into the daemon: without ``NOTIFY_SOCKET`` (not under systemd) every call is a no-op, and
a failed send is counted and logged once, because a notification problem must never take the robot down. The socket
is non-blocking, so a full systemd queue drops a message instead of stalling the asyncio side.

``WatchdogGate`` is the daemon's "ping or not" decision, kept pure so it can be driven cycle by cycle in tests: a
ping is *earned* only while the cycle thread is alive, its cycle counter moved since the last decision and it is
not overrunning its deadline run after run. When the cycle wedges the pings stop, systemd kills and restarts the
daemon, and the drives' own command timeouts (e.g. Damiao's CAN timeout) hold or disable them meanwhile.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping
from typing import Protocol

from hild.crossing.stats import LoopStats
from hild.crossing.status import STATS_MAX_AGE

log = logging.getLogger("hild.notify")

# Ping this many times per WatchdogSec: sd_watchdog_enabled(3) asks for at least twice; four leaves room for one
# late asyncio wake-up (a slow Zenoh call, a long GC) without a false restart.
PINGS_PER_WATCHDOG_INTERVAL = 4


def socket_address(value: str) -> str | bytes:
    """``NOTIFY_SOCKET``'s value as a socket address: ``@name`` is the abstract name ``\\0name``.

    Raises ValueError for anything else than an absolute path or an abstract name (e.g. systemd's newer
    ``vsock:`` addresses, which hild does not need)."""
    if value.startswith("@") and len(value) > 1:
        return b"\0" + value[1:].encode()
    if value.startswith("/"):
        return value
    raise ValueError(f"unsupported NOTIFY_SOCKET {value!r} (want an absolute path or @abstract-name)")


def watchdog_interval(environ: Mapping[str, str], pid: int) -> float | None:
    """Seconds between systemd's watchdog deadlines, or None when the watchdog is off or meant for another process.

    ``WATCHDOG_PID``, when set, names the process the watchdog belongs to (sd_watchdog_enabled(3)): a child that
    inherited the environment must not ping on its parent's behalf."""
    owner = environ.get("WATCHDOG_PID", "")
    if owner:
        try:
            if int(owner) != pid:
                return None
        except ValueError:
            return None
    try:
        usec = int(environ.get("WATCHDOG_USEC", "0"))
    except ValueError:
        return None
    return usec / 1e6 if usec > 0 else None


class SystemdNotifier:
    """A ``NOTIFY_SOCKET`` client; a no-op outside systemd. ``errors`` counts failed sends, ``sent`` the rest."""

    def __init__(self, environ: Mapping[str, str] | None = None, pid: int | None = None) -> None:
        env = os.environ if environ is None else environ
        self.address: str | bytes | None = None
        self.errors = 0
        self.sent = 0
        self.last_error = ""
        raw = env.get("NOTIFY_SOCKET", "")
        if raw:
            try:
                self.address = socket_address(raw)
            except ValueError as exc:
                self._failed(str(exc))
        self.watchdog_interval = watchdog_interval(env, os.getpid() if pid is None else pid) if self.address else None
        self._sock: socket.socket | None = None

    @property
    def enabled(self) -> bool:
        return self.address is not None

    @property
    def ping_period(self) -> float | None:
        """How often to consider a ``WATCHDOG=1``; None when systemd does not watch us."""
        if self.watchdog_interval is None:
            return None
        return self.watchdog_interval / PINGS_PER_WATCHDOG_INTERVAL

    def send(self, *assignments: str) -> bool:
        """Send ``KEY=value`` lines in one datagram. Returns whether it went out; never raises."""
        if self.address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)
            self._sock.sendto("\n".join(assignments).encode(), self.address)
        except OSError as exc:
            self._failed(f"cannot notify systemd at {self.address!r}: {exc}")
            return False
        self.sent += 1
        return True

    def ready(self, status: str) -> bool:
        return self.send("READY=1", _status(status))

    def status(self, text: str) -> bool:
        return self.send(_status(text))

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def stopping(self, status: str) -> bool:
        return self.send("STOPPING=1", _status(status))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _failed(self, text: str) -> None:
        self.errors += 1
        self.last_error = text
        if self.errors == 1:  # one line for the first failure; the count shows the rest
            log.warning("%s (further notification errors are only counted)", text)


def _status(text: str) -> str:
    """One ``STATUS=`` line: a newline would start a new assignment."""
    return "STATUS=" + " ".join(text.split("\n"))


class WatchdogGate:
    """Decides, once per ping period, whether the daemon has earned a ``WATCHDOG=1``.

    Earned when the cycle thread is alive, ``cycle`` advanced since the previous decision, and fewer than
    ``max_consecutive_overruns`` cycles in a row missed their deadline (0 disables that check, as it does for the
    supervisor's overrun fault). ``reason`` says why the last ping was withheld ("" when it was earned).
    """

    def __init__(self, max_consecutive_overruns: int, cycle: int = 0) -> None:
        self.max_consecutive_overruns = max_consecutive_overruns
        self.last_cycle = cycle
        self.reason = ""

    def reset(self, cycle: int) -> None:
        """Start judging from ``cycle`` (the count when READY=1 went out)."""
        self.last_cycle = cycle
        self.reason = ""

    def earned(self, cycle: int, consecutive_overruns: int, cycle_alive: bool) -> bool:
        advanced = cycle > self.last_cycle
        self.last_cycle = cycle
        if not cycle_alive:
            self.reason = "the cycle thread has ended"
        elif not advanced:
            self.reason = f"the cycle is stalled at cycle {cycle}"
        elif self.max_consecutive_overruns and consecutive_overruns >= self.max_consecutive_overruns:
            self.reason = f"{consecutive_overruns} consecutive overruns"
        else:
            self.reason = ""
        return not self.reason


def status_line(mode: str, update_rate: float, loop: Mapping[str, object]) -> str:
    """``systemctl status``'s one line: overall mode and the loop's figures (from ``LoopStats.summary()``)."""
    duration, period = loop.get("duration_us"), loop.get("period_error_us")
    d99 = duration.get("p99", 0.0) if isinstance(duration, Mapping) else 0.0
    p99 = period.get("p99", 0.0) if isinstance(period, Mapping) else 0.0
    return (
        f"{mode} at {update_rate:g} Hz; cycle p99 {d99} µs, period error p99 {p99} µs; "
        f"{loop.get('overruns', 0)} overruns in {loop.get('cycles', 0)} cycles"
    )


class CycleFigures(Protocol):
    """What the service report reads of the cycle (met by ``hild.daemon.link.CycleLink``)."""

    update_rate: float
    stats: LoopStats

    @property
    def cycle(self) -> int: ...

    def overall_mode(self) -> str: ...


READY_AFTER_CYCLES = 5  # cycles the live loop must complete (read → supervise → write) before READY=1
STATUS_PERIOD = 2.0  # s: STATUS= refresh; a change of overall mode is sent at the next tick


class ServiceReport:
    """What the unit tells systemd while the cycle runs: READY=1 once the live cycle has run a few cycles, a
    watchdog ping only when the cycle earned it (:class:`WatchdogGate`), and a ``STATUS=`` kept current.

    Called on the asyncio side's housekeeping tick with the cycle's figures, wherever the cycle runs."""

    def __init__(self, notifier: SystemdNotifier, max_consecutive_overruns: int) -> None:
        self.notifier = notifier
        self.watchdog = WatchdogGate(max_consecutive_overruns)
        self.ready = False
        self._next_ping = 0.0
        self._next_status = 0.0
        self._last_mode = ""

    def tick(self, now: float, cycle: CycleFigures, cycle_alive: bool) -> None:
        if not self.ready:
            if cycle.cycle <= READY_AFTER_CYCLES:  # the counter counts cycles begun: this many have ended
                return
            self.ready = True
            self.watchdog.reset(cycle.cycle)
            self._last_mode = cycle.overall_mode()
            self._next_ping = self._next_status = now
            self.notifier.ready(self._status_text(cycle, self._last_mode))
            log.info("ready: the drives are live and %d cycles have run", cycle.cycle)
            return
        ping = self.notifier.ping_period
        if ping is not None and now >= self._next_ping:
            self._next_ping = now + ping
            was_withheld = bool(self.watchdog.reason)
            if self.watchdog.earned(cycle.cycle, cycle.stats.consecutive_overruns, cycle_alive):
                self.notifier.watchdog()
                if was_withheld:
                    log.info("systemd watchdog pings resumed: the cycle advances again")
            elif not was_withheld:  # one line per episode, not one per missed ping
                log.error("withholding the systemd watchdog ping: %s", self.watchdog.reason)
        if not self.notifier.enabled:  # not under systemd: no status line to build
            return
        mode = cycle.overall_mode()
        if mode != self._last_mode or now >= self._next_status:
            self._last_mode = mode
            self._next_status = now + STATUS_PERIOD
            self.notifier.status(self._status_text(cycle, mode))

    @staticmethod
    def _status_text(cycle: CycleFigures, mode: str) -> str:
        return status_line(mode, cycle.update_rate, cycle.stats.summary(STATS_MAX_AGE))


class SilentReport:
    """A client domain under the main process: the main process speaks for the unit (it alone has
    ``$NOTIFY_SOCKET``) and waits for the first cycles, so this one reports nothing and has nothing to wait for:
    its housekeeping ticks at the slow pace from the start instead of polling every 5 ms for its whole life."""

    ready = True
    watchdog = None

    def tick(self, now: float, cycle: CycleFigures, cycle_alive: bool) -> None:
        pass
