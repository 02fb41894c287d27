"""What many tests need, in one place: free loopback ports, waiting for a condition, and ``hild run`` as the
operator starts it (a child process whose main process, client domain and cycle process a test can find).

Everything waits for a condition with a timeout, never a fixed sleep.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

from hild.api.client import HildClient, HildError

WAIT = 30.0
START_TIMEOUT = 60.0  # s: a daemon imports MuJoCo and Zenoh before it answers; generous for a loaded machine


def free_port() -> int:
    """A TCP port on 127.0.0.1 nobody listens on now (the OS's choice: a second checkout's tests get another)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def free_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


def distinct_free_ports(count: int) -> list[int]:
    ports: set[int] = set()
    while len(ports) < count:
        ports.add(free_port())
    return sorted(ports)


def child_pids(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(entry.name))
    return found


def domain_pid(main_pid: int, module: str) -> int:
    """The one child of the daemon's main process running ``hild.domains.<module>``."""
    found = [pid for pid in child_pids(main_pid) if f"hild.domains.{module}".encode() in _cmdline(pid)]
    assert len(found) == 1, f"the daemon {main_pid} has {len(found)} {module} children: {child_pids(main_pid)}"
    return found[0]


def _cmdline(pid: int) -> bytes:
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_bytes()
    except OSError:
        return b""


def running(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie (an orphan's exit is reaped by whoever adopted it, or not)."""
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def wait_for(
    condition: Callable[[], Any],
    timeout: float = WAIT,
    what: str = "condition",
    tick: Callable[[], None] | None = None,
) -> Any:
    """``condition()``'s first truthy value; AssertionError after ``timeout`` s. ``tick`` runs between tries."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        if tick is not None:
            tick()
        time.sleep(0.005)


class HildRun:
    """``hild run <config> --listen <endpoint>``, its output in ``log`` (default ``<config dir>/daemon.log``).

    ``cwd`` is where relative paths of the run land (recordings); ``env`` replaces the environment (e.g. a fake
    systemd's ``NOTIFY_SOCKET``). Entering waits until the API answers and the cycle runs; leaving kills what
    is still running (``stop`` first for an orderly stop)."""

    def __init__(
        self,
        config: Path,
        endpoint: str,
        robot: str,
        *,
        log: Path | None = None,
        cwd: Path | None = None,
        env: dict[str, str] | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.robot = robot
        self.log_path = log or config.parent / "daemon.log"
        with self.log_path.open("wb") as out:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "hild.cli", "run", str(config), "--listen", endpoint],
                stdout=out,
                stderr=subprocess.STDOUT,
                cwd=cwd,
                env=env,
            )

    def __enter__(self) -> HildRun:
        try:
            self.started()
        except BaseException:
            self.close()
            raise
        return self

    def started(self) -> HildRun:
        """Wait until the API answers and the cycle runs (AssertionError with the log if it exits first)."""
        self.wait(self.answers, "the daemon to answer", START_TIMEOUT)
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

    def stop(self, timeout: float = WAIT, sig: signal.Signals = signal.SIGTERM) -> int:
        """SIGTERM, as systemd stops it (or ``sig``: SIGINT is a terminal's Ctrl-C); the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        return self.process.wait(timeout)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(WAIT)
