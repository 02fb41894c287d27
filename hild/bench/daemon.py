"""``hild run`` as the operator starts it, for the tests, the tools and ``hild bench``: one child process whose main
process, client domain and cycle process can be found, and the CAN pair (``hild emulate`` + ``hild run``).

``hild bench``'s scenarios run the daemon embedded instead (``hild.bench.host``): they need the daemon's
statistics and rigs in process. Both are a :class:`~hild.bench.children.LoggedChild`.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from drivers.can.emulator.runtime import request
from hild.api.client import HildClient, HildError
from hild.bench.children import WAIT, LoggedChild, distinct_free_ports, end_child, wait_for

START_TIMEOUT = 60.0  # s: a daemon imports MuJoCo and Zenoh before it answers; generous for a loaded machine
HILD = (sys.executable, "-m", "hild.cli")
CONFIGS = Path(__file__).resolve().parents[2] / "configs"


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
    """The one child of the daemon's main process running ``python -m <module>``."""
    found = [pid for pid in child_pids(main_pid) if module.encode() in _cmdline(pid)]
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


class HildRun(LoggedChild):
    """``hild run <config> --listen <endpoint> [args]``, its output in ``log`` (default ``<config dir>/daemon.log``).

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
        args: Sequence[str] = (),
    ) -> None:
        self.endpoint = endpoint
        self.robot = robot
        command = [*HILD, "run", str(config), "--listen", endpoint, *args]
        super().__init__(command, log or config.parent / "daemon.log", cwd=cwd, env=env)

    def __enter__(self) -> HildRun:
        try:
            self.started()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def started(self, timeout: float = START_TIMEOUT) -> HildRun:
        """Wait until the API answers and the cycle runs (AssertionError with the log if it exits first)."""
        wait_for(self.answers, timeout, "the daemon to answer", self._running, lambda: self.log, every=0.05)
        return self

    def _running(self) -> None:
        if self.process.poll() is not None:
            raise AssertionError(f"the daemon exited ({self.process.returncode}) before it answered:\n{self.log}")

    def connected(self, timeout: float = START_TIMEOUT) -> HildClient:
        """A client of the daemon once it answers and its cycle runs."""
        return self.started(timeout).client()

    def client_process(self) -> int:
        return domain_pid(self.pid, "hild.daemon.process")

    def cycle_process(self) -> int:
        return domain_pid(self.pid, "hild.cycle.process")

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
        """``condition()``'s first truthy value; AssertionError with the log after ``timeout`` s."""
        return wait_for(condition, timeout, what, logs=lambda: self.log, every=0.02)

    def wait_log(self, text: str, timeout: float = WAIT) -> None:
        self.wait(lambda: text in self.log, f"{text!r} in the log", timeout)

    def wait_gone(self, pid: int, what: str) -> None:
        self.wait(lambda: not running(pid), what)


class CanProcesses:
    """``hild emulate`` (Damiao drives and the arm6 twin behind them, holding brakes on) and ``hild run`` on
    configs/arm6_can_loopback.yaml (``CONFIG``, ``FILES``: a subclass may name another loopback config) with free
    loopback ports: the emulator at once, daemons on demand
    (``start_daemon``). The emulator outlives a daemon, so one can be killed and restarted against an arm that
    stayed where it was.

    The emulator runs as that config's header says, at ``--priority 50`` (SCHED_FIFO where permitted, reported
    otherwise; ``emulator_args`` may override it): it stands in for drives that answer from silicon. At normal
    priority, beside a second checkout's test run, whose daemon cycles run at SCHED_FIFO 40, it went without a
    core for longer than the drives' 200 ms watchdog (docs/operations.md, "The loopback rig under load")."""

    HOST = "127.0.0.1"
    CONFIG = "arm6_can_loopback.yaml"
    FILES: tuple[str, ...] = ("arm6.xml",)  # files the config names relative to configs/ (robot.model, an EDS):
    # made absolute in the copy the daemon runs
    SERVED = "ws://127.0.0.1:54701/"  # the bus channel the config names, replaced by the free port's
    PATCHES: tuple[tuple[str, str], ...] = ()  # (text, replacement) in the daemon's copy (e.g. another mode)
    EMULATOR_PRIORITY = 50

    def __init__(self, directory: Path, emulator_args: Sequence[str] = ()) -> None:
        self.directory = directory
        remote, control, zenoh = distinct_free_ports(3)
        self.control = (self.HOST, control)
        self.endpoint = f"tcp/{self.HOST}:{zenoh}"
        self.daemon_logs: list[Path] = []
        self.run: HildRun | None = None
        bus, control_at = f"{self.HOST}:{remote}", f"{self.HOST}:{control}"
        command = [*HILD, "emulate", str(CONFIGS / self.CONFIG), "--serve-remote", bus, "--control", control_at]
        command += ["--priority", str(self.EMULATOR_PRIORITY), *emulator_args]
        self.emulator_child = LoggedChild(command, directory / "emulator.log", cwd=directory)
        self.emulator = self.emulator_child.process
        try:
            self.wait(self._answers, "the emulator's control socket", START_TIMEOUT)
            text = (CONFIGS / self.CONFIG).read_text()
            self.config = directory / self.CONFIG
            text = text.replace(self.SERVED, f"ws://{bus}/")
            for name in self.FILES:
                text = text.replace(f": {name}", f": {CONFIGS / name}")
            for old, new in self.PATCHES:
                if old not in text:
                    raise ValueError(f"{self.CONFIG} has no {old!r} to patch")
                text = text.replace(old, new)
            self.config.write_text(text)
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
                raise AssertionError(f"the emulator exited:\n{self.emulator_child.log}") from None
            return False

    def status(self) -> dict[str, Any]:
        """The emulator's status: its drives (``joints``) and its loop."""
        reply: dict[str, Any] = request(self.control, {"op": "status"}, timeout=10.0)
        assert reply["ok"], reply
        return reply

    def drives(self) -> list[dict[str, Any]]:
        return list(self.status()["joints"])

    def positions(self) -> np.ndarray:
        return np.array([j["position"] for j in self.drives()])

    # ---- daemons ------------------------------------------------------------------------------------------------
    @property
    def daemon(self) -> subprocess.Popen[bytes] | None:
        """The running (or last) daemon's process, None before the first."""
        return self.run.process if self.run is not None else None

    def start_daemon(self) -> HildClient:
        """Start ``hild run`` and return a client once it answers and its cycle runs."""
        log = self.directory / f"daemon{len(self.daemon_logs) + 1}.log"
        self.daemon_logs.append(log)
        self.run = HildRun(self.config, self.endpoint, "arm6", log=log, cwd=self.directory)
        return self.run.connected()

    def kill_daemon(self) -> None:
        """SIGKILL the daemon's main process: its cycle process and client domain find themselves orphaned and
        stop on their own."""
        assert self.run is not None
        self.run.close()

    def cycle_process(self) -> int:
        assert self.run is not None
        return self.run.cycle_process()

    def client_process(self) -> int:
        assert self.run is not None
        return self.run.client_process()

    def kill_cycle_process(self) -> None:
        """SIGKILL the cycle process: no hold cycle, no disable frames, nothing; the daemon sees it and exits 1."""
        os.kill(self.cycle_process(), signal.SIGKILL)
        assert self.run is not None
        self.run.process.wait(20)

    def daemon_log(self) -> str:
        return self.daemon_logs[-1].read_text() if self.daemon_logs else ""

    def wait(self, condition: Callable[[], Any], what: str, timeout: float = 20.0) -> None:
        wait_for(condition, timeout, what, logs=self.logs, every=0.02)

    def logs(self) -> str:
        return f"--- emulator:\n{self.emulator_child.log}\n--- daemon:\n{self.daemon_log()}"

    def close(self) -> None:
        if self.run is not None:
            self.run.close()
        if self.emulator.poll() is None:
            with contextlib.suppress(OSError):
                request(self.control, {"op": "stop"}, timeout=5.0)
        end_child(self.emulator, 10.0)
