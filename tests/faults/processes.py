"""Two processes on loopback: ``hild emulate`` (Damiao drives and the arm6 twin behind them, holding brakes on) and
``hild run`` (the daemon), on configs/arm6_can_loopback.yaml with free ports. The emulator outlives the daemon, so
a daemon can be killed and restarted against an arm that stayed where it was.

Everything here is on the wall clock: each wait is for a condition with a generous timeout, never a fixed sleep.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers.can.emulator.runtime import request
from hild.api.client import HildClient, HildUnreachable
from tests.conftest import CONFIGS
from tests.helpers import HildRun, distinct_free_ports, domain_pid
from tests.test_e2e_can import stop

HOST = "127.0.0.1"
CONFIG = "arm6_can_loopback.yaml"
START_TIMEOUT = 60.0


class ProcessError(AssertionError):
    pass


class CanProcesses:
    """The emulator process, started at once; daemons on demand (``start_daemon``)."""

    def __init__(self, directory: Path, emulator_args: Sequence[str] = ()) -> None:
        self.directory = directory
        remote, control, zenoh = distinct_free_ports(3)
        self.control = (HOST, control)
        self.endpoint = f"tcp/{HOST}:{zenoh}"
        self.emulator_log = directory / "emulator.log"
        self.daemon_logs: list[Path] = []
        self.daemon: subprocess.Popen[bytes] | None = None
        with self.emulator_log.open("wb") as out:
            command = ["emulate", str(CONFIGS / CONFIG), "--serve-remote", f"{HOST}:{remote}"]
            self.emulator = subprocess.Popen(
                [*_hild(), *command, "--control", f"{HOST}:{control}", *emulator_args],
                stdout=out,
                stderr=subprocess.STDOUT,
                cwd=directory,
            )
        try:
            self._wait(lambda: self._answers(), START_TIMEOUT, "the emulator's control socket")
            text = (CONFIGS / CONFIG).read_text()
            self.config = directory / CONFIG
            self.config.write_text(
                text.replace("ws://127.0.0.1:54701/", f"ws://{HOST}:{remote}/").replace(
                    "model: arm6.xml", f"model: {CONFIGS / 'arm6.xml'}"
                )
            )
        except BaseException:
            self.close()
            raise

    # ---- the emulator -----------------------------------------------------------------------------------------
    def _answers(self) -> bool:
        try:
            request(self.control, {"op": "status"}, timeout=2.0)
            return True
        except OSError:
            if self.emulator.poll() is not None:
                raise ProcessError(f"the emulator exited:\n{self.emulator_log.read_text()}") from None
            return False

    def drives(self) -> list[dict[str, Any]]:
        reply = request(self.control, {"op": "status"}, timeout=10.0)
        assert reply["ok"], reply
        return list(reply["joints"])

    def positions(self) -> np.ndarray:
        return np.array([j["position"] for j in self.drives()])

    # ---- daemons ------------------------------------------------------------------------------------------------
    def start_daemon(self) -> HildClient:
        """Start ``hild run`` and return a client once its robot is alive."""
        log = self.directory / f"daemon{len(self.daemon_logs) + 1}.log"
        self.daemon_logs.append(log)
        self.daemon = HildRun(self.config, self.endpoint, "arm6", log=log, cwd=self.directory).process
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            try:
                client = HildClient(robot="arm6", connect=[self.endpoint], timeout=5.0)
                break
            except HildUnreachable:
                self._check_daemon(deadline)
                time.sleep(0.2)
        try:
            client.wait_alive(timeout=START_TIMEOUT)
        except BaseException:
            client.close()
            raise
        return client

    def kill_daemon(self) -> None:
        """SIGKILL the daemon's main process: its cycle process and client domain find themselves orphaned and
        stop on their own."""
        assert self.daemon is not None
        self.daemon.kill()
        self.daemon.wait(10)

    def cycle_process(self) -> int:
        assert self.daemon is not None
        return domain_pid(self.daemon.pid, "cycle_process")

    def client_process(self) -> int:
        assert self.daemon is not None
        return domain_pid(self.daemon.pid, "client_process")

    def kill_cycle_process(self) -> None:
        """SIGKILL the cycle process: no hold cycle, no disable frames, nothing; the daemon sees it and exits 1."""
        os.kill(self.cycle_process(), signal.SIGKILL)
        assert self.daemon is not None
        self.daemon.wait(20)

    def daemon_log(self) -> str:
        return self.daemon_logs[-1].read_text() if self.daemon_logs else ""

    def _check_daemon(self, deadline: float) -> None:
        if self.daemon is not None and self.daemon.poll() is not None:
            raise ProcessError(f"the daemon exited ({self.daemon.returncode}):\n{self.daemon_log()}")
        if time.monotonic() > deadline:
            raise ProcessError(f"the daemon did not come up:\n{self.daemon_log()}")

    def _wait(self, condition: Any, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise ProcessError(f"timed out after {timeout:g} s waiting for {what}\n{self.logs()}")
            time.sleep(0.02)

    def wait(self, condition: Any, what: str, timeout: float = 20.0) -> None:
        self._wait(condition, timeout, what)

    def logs(self) -> str:
        return f"--- emulator:\n{self.emulator_log.read_text()}\n--- daemon:\n{self.daemon_log()}"

    def close(self) -> None:
        if self.daemon is not None:
            stop(self.daemon)
        if self.emulator.poll() is None:
            try:
                request(self.control, {"op": "stop"}, timeout=5.0)
                self.emulator.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                pass
        stop(self.emulator)


def _hild() -> list[str]:
    return [sys.executable, "-m", "hild.cli"]
