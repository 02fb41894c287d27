"""``hild run`` as the operator starts it, in a child process, for tests that need its process structure: the main
process, its client domain and its cycle process (found by their ``python -m`` module in /proc).

Everything waits for a condition with a timeout, never a fixed sleep.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

from hild.api.client import HildClient, HildError
from tests.faults.processes import domain_pid, running

WAIT = 30.0


class HildRun:
    """``hild run <config> --listen <endpoint>``, its output in ``<config dir>/daemon.log``."""

    def __init__(self, config: Path, endpoint: str, robot: str) -> None:
        self.endpoint = endpoint
        self.robot = robot
        self.log_path = config.parent / "daemon.log"
        with self.log_path.open("wb") as out:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "hild.cli", "run", str(config), "--listen", endpoint],
                stdout=out,
                stderr=subprocess.STDOUT,
            )

    def __enter__(self) -> HildRun:
        try:
            self.wait(self.answers, "the daemon to answer")
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    @property
    def log(self) -> str:
        return self.log_path.read_text()

    @property
    def pid(self) -> int:
        return self.process.pid

    def client_process(self) -> int:
        return domain_pid(self.pid, "client_process")

    def cycle_process(self) -> int:
        return domain_pid(self.pid, "cycle_process")

    def client(self, timeout: float = 5.0) -> HildClient:
        return HildClient(self.robot, [self.endpoint], timeout=timeout)

    def answers(self) -> bool:
        """The API answers and the cycle runs."""
        try:
            with self.client(timeout=1.0) as client:
                return client.status()["loop"]["cycles"] > 0
        except HildError:
            return False

    def wait(self, condition: Callable[[], Any], what: str, timeout: float = WAIT) -> Any:
        deadline = time.monotonic() + timeout
        while not (value := condition()):
            if self.process.poll() is not None and condition == self.answers:
                raise AssertionError(f"the daemon exited ({self.process.returncode}) before {what}:\n{self.log}")
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:g} s waiting for {what}:\n{self.log}")
            time.sleep(0.02)
        return value

    def wait_log(self, text: str, timeout: float = WAIT) -> None:
        self.wait(lambda: text in self.log, f"{text!r} in the log", timeout)

    def wait_gone(self, pid: int, what: str) -> None:
        self.wait(lambda: not running(pid), what)

    def stop(self, timeout: float = WAIT) -> int:
        """SIGTERM, as systemd stops it; the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        return self.process.wait(timeout)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(WAIT)
