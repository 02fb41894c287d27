"""The daemon's main process when the cycle runs in a process of its own: it starts both domains and keeps them.

``hild run`` with ``realtime.cycle_process`` is three processes: this one (small: no Zenoh, no controller
``update``), the client domain (:mod:`hild.daemon.process`: Zenoh, the API, telemetry) and the cycle
process (:mod:`hild.cycle.process`). This process carves the shared region, starts the client domain,
starts the cycle process once the client domain has opened Zenoh and made sure this robot's name is free (the
hardware is not touched before), and then:

- speaks for the unit to systemd: READY=1, the watchdog pings earned by the cycle's own counter, ``STATUS=``;
- when the client domain ends while the cycle runs, tells the cycle (its goals are aborted, the arm holds,
  streams time out on the cycle clock) and starts a new one, which finds the cycle live and the results of the
  aborted goals waiting; more than ``RESTARTS_ALLOWED`` restarts within ``RESTART_WINDOW`` stop the unit;
- when the cycle process ends unexpectedly, stops the client domain and exits 1 (the drives' own watchdogs act);
- on SIGTERM or SIGINT, stops the cycle first (descent, hold, release), then the client domain.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import os
import pickle
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

from hild.config.loader import LoadedConfig
from hild.crossing.attach import Attachment, Crossing
from hild.crossing.cells import Ask, ClientPhase, ClientVital, Phase
from hild.crossing.cyclelog import capacity_of
from hild.cycle.process import spawn
from hild.daemon.remote import RemoteCycle
from hild.main.notify import ServiceReport, SystemdNotifier

log = logging.getLogger("hild.daemon")

TICK = 0.05  # s: how often this process looks at both domains
START_TIMEOUT = 120.0  # s: the client domain must open Zenoh, and the cycle go live, within this
STOP_TIMEOUT = 5.0  # s: beyond the configured descent, for the cycle; then for the client domain
RESTARTS_ALLOWED = 5
RESTART_WINDOW = 60.0  # s
_SYSTEMD_VARIABLES = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID")  # only this process speaks for the unit


@dataclass(frozen=True)
class ClientSpec:
    """What the client process gets on its standard input."""

    loaded: LoadedConfig
    listen: list[str] | None
    attachment: Attachment
    log_level: str


class MainProcess:
    def __init__(self, loaded: LoadedConfig, listen: list[str] | None = None) -> None:
        self.loaded = loaded
        self.listen = listen
        self.crossing = Crossing.carve(len(loaded.config.joints), capacity_of(loaded.config))
        self.cells = self.crossing.cells
        self.cycle = RemoteCycle(loaded, self.crossing)  # only read here: the client domain drains and requests
        self.client: subprocess.Popen[bytes] | None = None
        self.notifier = SystemdNotifier()
        self.service = ServiceReport(self.notifier, loaded.config.safety.max_consecutive_overruns)
        self.restarts: collections.deque[float] = collections.deque()
        self._stopping = asyncio.Event()
        self._signals = 0

    @property
    def ready(self) -> bool:
        return self.service.ready

    @property
    def cycle_process(self) -> subprocess.Popen[bytes] | None:
        return self.cycle.process

    def request_stop(self) -> None:
        self._stopping.set()

    # ---- the two children ------------------------------------------------------------------------------------
    def _start_client(self, restarted_after: str | None = None) -> None:
        self.cells.client[ClientVital.PHASE] = ClientPhase.STARTING
        level = logging.getLevelName(logging.getLogger().getEffectiveLevel())
        spec = ClientSpec(self.loaded, self.listen, self.crossing.attachment(os.getpid(), restarted_after), level)
        env = {k: v for k, v in os.environ.items() if k not in _SYSTEMD_VARIABLES}
        self.client = subprocess.Popen(
            [sys.executable, "-m", "hild.daemon.process"],
            stdin=subprocess.PIPE,
            pass_fds=(self.crossing.region.fd, self.crossing.wakeup_fd),
            env=env,
        )
        assert self.client.stdin is not None
        with self.client.stdin as stdin:
            stdin.write(pickle.dumps(spec, pickle.HIGHEST_PROTOCOL))

    def _client_alive(self) -> bool:
        return self.client is not None and self.client.poll() is None

    @property
    def client_phase(self) -> ClientPhase:
        return ClientPhase(int(self.cells.client[ClientVital.PHASE]))

    # ---- run -------------------------------------------------------------------------------------------------
    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self._on_signal, sig)
        self.notifier.status("starting the client domain")
        self._start_client()
        failed: str | None = None
        try:
            failed = await self._start()
            code = 1 if failed else await self._keep()
        finally:
            await self._stop_both(quiet=failed is not None)
        if failed:
            self._report_failed_start(failed)
        else:
            self.notifier.status("stopped: hardware released" if self._released() else "stopped")
        return code

    def _on_signal(self, signum: int) -> None:
        self._signals += 1
        if self._signals > 1:
            log.error("second %s: forcing exit", signal.Signals(signum).name)
            os._exit(1)
        log.info("%s: holding every joint, then stopping", signal.Signals(signum).name)
        self._stopping.set()

    async def _start(self) -> str | None:
        """The client domain opens Zenoh; then the cycle process brings the hardware up and goes live. Start-up
        ends when the cycle is live (the client domain told it to go): a client domain lost after that, even before
        it says it serves, is replaced by :meth:`_keep` like any other, and the arm holds meanwhile. What went
        wrong, or None (started, or stopped while starting)."""
        deadline = time.monotonic() + START_TIMEOUT
        while self.client_phase is ClientPhase.STARTING:
            if not self._client_alive() or self._stopping.is_set() or time.monotonic() > deadline:
                return self._start_failed()
            await asyncio.sleep(TICK / 10)
        if self.client_phase is not ClientPhase.OPEN:  # it refused (name or port taken): the hardware stays shut
            return self._start_failed()
        self.notifier.status("bringing up the hardware")
        self.cycle.process = spawn(self.loaded, self.crossing, self.cells.telemetry.take())  # type: ignore[arg-type]
        while self.cycle.phase is not Phase.LIVE:
            if not (self._client_alive() and self.cycle.alive()) or self._stopping.is_set():
                return self._start_failed()
            if self.client_phase is ClientPhase.FAILED or time.monotonic() > deadline:
                return self._start_failed()
            await asyncio.sleep(TICK / 10)
        return None

    def _start_failed(self) -> str | None:
        """What went wrong (None when a signal stopped the start); reported once both children have ended."""
        if self._stopping.is_set():
            return None
        if self.client_phase is ClientPhase.FAILED:
            return "the client domain refused to start"
        if not self._client_alive():
            return f"the client domain ended during start-up (exit code {self._client_code()})"
        if self.cycle.process is not None and not self.cycle.alive():
            return f"the cycle process ended during start-up (exit code {self.cycle.exit_code})"
        return f"not started within {START_TIMEOUT:g} s"

    def _report_failed_start(self, what: str) -> None:
        """Once, and true: the client domain may have logged why (``ClientPhase.FAILED``); then only what became of
        the hardware is added, and only when the cycle process had opened it."""
        if self.cycle.process is None:
            hardware = "nothing was opened"
        else:
            hardware = "the hardware was released" if self._released() else "the cycle process did not stop cleanly"
        if self.client_phase is ClientPhase.FAILED:
            if self.cycle.process is not None:
                log.info("stopped: %s", hardware)
            self.notifier.status(f"start-up failed ({hardware}); the client domain's log says why")
            return
        log.error("start-up failed; %s: %s", hardware, what)
        self.notifier.status(f"start-up failed: {what}")

    def _client_code(self) -> int | None:
        return None if self.client is None else self.client.poll()

    async def _keep(self) -> int:
        """Until a signal: report to systemd, restart a lost client domain, end with a lost cycle."""
        loop = asyncio.get_running_loop()
        ping = self.notifier.ping_period
        tick = TICK if ping is None else min(TICK, ping)
        while not self._stopping.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), timeout=tick)
            if not self.cycle.alive():
                text = f"the cycle process ended unexpectedly (exit code {self.cycle.exit_code})"
                log.error("%s", text)
                self.notifier.status(text)
                return 1
            if not self._client_alive() and not self._stopping.is_set() and not self._restart_client():
                return 1
            self.service.tick(loop.time(), self.cycle, self.cycle.alive())
        return 0

    def _restart_client(self) -> bool:
        """The client domain ended while the cycle runs: tell the cycle, and start another (within limits)."""
        reason = f"the client domain ended unexpectedly (exit code {self._client_code()})"
        self.cells.asks[Ask.CLIENT_LOST] += 1  # the cycle aborts its goals and holds
        now = time.monotonic()
        self.restarts.append(now)
        while self.restarts and self.restarts[0] < now - RESTART_WINDOW:
            self.restarts.popleft()
        if len(self.restarts) > RESTARTS_ALLOWED:
            text = f"{reason}; {len(self.restarts) - 1} restarts within {RESTART_WINDOW:g} s already: stopping"
            log.error("%s", text)
            self.notifier.status(text)
            return False
        log.error("%s; the cycle holds the arm; starting another", reason)
        self._start_client(reason)
        return True

    async def _stop_both(self, quiet: bool = False) -> None:
        """The cycle first (descent, hold, release: the client domain still drains its events), then the client
        domain; a child that does not stop in time is killed. ``quiet``: a failed start, reported after this."""
        descent = self.loaded.config.safety.stop_descent
        words = f"a {descent:g} s damped descent" if descent else "holding every joint"
        self.notifier.stopping(f"stopping: {words}, then releasing the hardware")
        self.cells.asks[Ask.STOP] = 1
        if self.cycle.process is not None and not await asyncio.to_thread(self.cycle.join, STOP_TIMEOUT + descent):
            log.error("the cycle did not stop within %g s", STOP_TIMEOUT + descent)
            self.cycle.kill()  # the drives' own watchdogs take over, as on any crash
        if quiet and self.client is not None:  # a failed start: the client domain ends once it has said why
            with contextlib.suppress(subprocess.TimeoutExpired):
                await asyncio.to_thread(self.client.wait, STOP_TIMEOUT)
        if self.client is not None and self.client.poll() is None:
            self.client.terminate()
            try:
                await asyncio.to_thread(self.client.wait, STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                log.error("the client domain did not stop within %g s", STOP_TIMEOUT)
                self.client.kill()
                self.client.wait()
        if quiet:
            return
        if self._released():
            log.info("stopped: hardware released")
        else:
            log.info("stopped")

    def _released(self) -> bool:
        """The cycle process released the hardware and exited cleanly, or there was never one to open it."""
        return self.cycle.process is None or (self.cycle.exit_code == 0 and self.cycle.phase is Phase.STOPPED)


def run_main_process(loaded: LoadedConfig, listen: list[str] | None = None) -> int:
    try:
        main = MainProcess(loaded, listen)
    except ValueError as exc:  # a controller that cannot be built from this config
        log.error("cannot build %s: %s", loaded.path, exc)
        return 1
    try:
        return asyncio.run(main.run())
    finally:
        main.notifier.close()
