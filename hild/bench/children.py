"""The measuring room's child processes: free loopback ports, waiting for a condition, and a child whose output goes
to a log file (the base of ``hild run`` as the tests and tools start it, and of ``hild bench``'s scenario host).

Everything waits for a condition with a timeout, never a fixed sleep.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

WAIT = 30.0  # s: the default wait for a condition, and for a child to exit once asked
END_TIMEOUT = 5.0  # s for a child to end by itself once its stdin is closed


def free_port() -> int:
    """A TCP port on 127.0.0.1 nobody listens on now (the OS's choice: a second checkout's run gets another)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def free_endpoint() -> str:
    """A Zenoh TCP endpoint on 127.0.0.1 nobody listens on now."""
    return f"tcp/127.0.0.1:{free_port()}"


def distinct_free_ports(count: int) -> list[int]:
    ports: set[int] = set()
    while len(ports) < count:
        ports.add(free_port())
    return sorted(ports)


def wait_for(
    condition: Callable[[], Any],
    timeout: float = WAIT,
    what: str = "condition",
    tick: Callable[[], None] | None = None,
    logs: Callable[[], str] | None = None,
    every: float = 0.005,
) -> Any:
    """``condition()``'s first truthy value, tried ``every`` s; AssertionError after ``timeout`` s, with ``logs()``
    when given. ``tick`` runs between tries (it may raise, e.g. when the process waited for has exited)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}" + (f":\n{logs()}" if logs else ""))
        if tick is not None:
            tick()
        time.sleep(every)


def end_child(process: subprocess.Popen[str] | subprocess.Popen[bytes], timeout: float = END_TIMEOUT) -> None:
    """Close the child's stdin (its sign to stop), wait for it, and kill it if it does not end in time."""
    if process.stdin is not None:
        with contextlib.suppress(OSError):  # a child that is gone leaves a broken pipe
            process.stdin.close()
    try:
        process.wait(timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


class LoggedChild:
    """A child process whose output goes to ``log_path``: stdout and stderr, or with ``control`` stderr only, its
    stdin and stdout then being a text channel to it. Stopping asks first (a signal) and kills what stays."""

    def __init__(
        self,
        command: Sequence[str],
        log: Path,
        *,
        control: bool = False,
        cwd: Path | None = None,
        env: dict[str, str] | None = None,
    ) -> None:
        self.log_path = log
        with log.open("wb") as out:  # the child has its own copy of the descriptor
            pipes: dict[str, Any] = (
                {"stdin": subprocess.PIPE, "stdout": subprocess.PIPE, "stderr": out, "text": True, "bufsize": 1}
                if control
                else {"stdout": out, "stderr": subprocess.STDOUT}
            )
            self.process: subprocess.Popen[Any] = subprocess.Popen(command, cwd=cwd, env=env, **pipes)

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def log_tail(self, lines: int = 15) -> str:
        """The log's last ``lines``, indented after a colon, for an error message ("" when it is empty)."""
        text = self.log.strip().splitlines()[-lines:]
        return (":\n    " + "\n    ".join(text)) if text else ""

    def stop(self, timeout: float = WAIT, sig: signal.Signals = signal.SIGTERM) -> int:
        """SIGTERM, as systemd stops it (or ``sig``: SIGINT is a terminal's Ctrl-C); the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        return int(self.process.wait(timeout))

    def end(self, timeout: float = WAIT, sig: signal.Signals = signal.SIGTERM) -> int:
        """``stop``, then kill it if it has not exited within ``timeout`` s; the exit code."""
        try:
            return self.stop(timeout, sig)
        except subprocess.TimeoutExpired:
            return self.kill()

    def kill(self) -> int:
        """Kill it if it is still running; the exit code."""
        if self.process.poll() is None:
            self.process.kill()
        return int(self.process.wait(WAIT))

    def close(self) -> int | None:
        """Leave nothing running (here: kill it); the exit code."""
        return self.kill()
