"""Optional real-time settings, applied when permitted and reported either way (docs/architecture.md, "The cycle").

Per-thread settings (SCHED_FIFO, CPU affinity, timer slack) are applied from inside the thread that runs the cycle
(the cycle process's main thread, or the cycle thread of a single daemon process), so the asyncio loop and Zenoh's
threads keep normal scheduling. Process settings (switch interval, locked memory) and the heap freeze go to the
process that runs the cycle; the client domain sets only its CPUs (``apply_client_settings``) and holds the CPU
DMA latency request. ``mlockall`` always carries ``MCL_ONFAULT``: without it, locking a process that loaded rerun
and MuJoCo balloons its resident memory by gigabytes and stalls for seconds.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import gc
import os
import struct
import sys
from collections.abc import Sequence

from hild.config.model import RealtimeSection

MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4
PR_SET_TIMERSLACK = 29
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def apply_process_settings(settings: RealtimeSection) -> dict[str, str]:
    """Settings for the whole process: GIL switch interval and locked memory."""
    report = {}
    sys.setswitchinterval(settings.switch_interval)
    report["switch_interval"] = f"{settings.switch_interval * 1e3:g} ms"
    if settings.lock_memory:
        if _libc().mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0:
            report["lock_memory"] = "locked (MCL_CURRENT|MCL_FUTURE|MCL_ONFAULT)"
        else:
            err = ctypes.get_errno()
            report["lock_memory"] = f"not permitted: {os.strerror(err)} (needs CAP_IPC_LOCK or LimitMEMLOCK=infinity)"
    else:
        report["lock_memory"] = "off"
    return report


class CpuLatencyRequest:
    """A PM QoS request on ``/dev/cpu_dma_latency``, held by the client domain while it runs.

    While the file stays open with a value written, no CPU enters an idle state that takes longer than that to
    leave; closing it withdraws the request (the kernel's contract, also what cyclictest does). A cycle that
    starts on a core coming out of a deep C-state pays several times its work (docs/performance.md)."""

    def __init__(self, path: str = CPU_DMA_LATENCY) -> None:
        self.path = path
        self._fd: int | None = None

    def hold(self, latency_us: int | None) -> str:
        """Open and write the request; the report line says what happened."""
        if latency_us is None:
            return "off"
        try:
            fd = os.open(self.path, os.O_WRONLY)
        except OSError as exc:
            return (
                f"not permitted: {exc.strerror or exc} (needs write access to {self.path}: root, or the udev rule "
                "in systemd/examples/)"
            )
        try:
            os.write(fd, struct.pack("i", latency_us))
        except OSError as exc:
            os.close(fd)
            return f"not applied: {exc.strerror or exc}"
        self._fd = fd
        return f"{latency_us} µs, held"

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)


def freeze_heap(settings: RealtimeSection) -> str:
    """Move every start-up object out of the collector's reach so a full collection cannot stall the cycle."""
    if not settings.gc_freeze:
        return "off"
    gc.collect()
    gc.freeze()
    return f"frozen {gc.get_freeze_count()} objects"


def thaw_heap() -> None:
    """At exit: give the frozen objects back to the collector, so extension objects are freed before the
    interpreter ends (nanobind-based modules such as ruckig report leaks otherwise)."""
    gc.unfreeze()
    gc.collect()


def apply_client_settings(settings: RealtimeSection) -> dict[str, str]:
    """The client domain's CPUs, set on its main thread before Zenoh starts its threads (they inherit them)."""
    if not settings.client_cpu_affinity:
        return {"client_cpu_affinity": "any"}
    try:
        os.sched_setaffinity(0, set(settings.client_cpu_affinity))
    except OSError as exc:
        return {"client_cpu_affinity": f"not applied: {exc.strerror or exc}"}
    return {"client_cpu_affinity": ",".join(map(str, sorted(settings.client_cpu_affinity)))}


def apply_thread_settings(settings: RealtimeSection) -> dict[str, str]:
    """Settings for the calling thread: the one that runs the cycle."""
    report = {}
    if settings.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(settings.priority))
            report["priority"] = f"SCHED_FIFO {settings.priority}"
        except (PermissionError, OSError) as exc:
            report["priority"] = (
                f"not permitted: {exc.strerror or exc} (needs CAP_SYS_NICE or LimitRTPRIO>={settings.priority})"
            )
    else:
        report["priority"] = "normal (SCHED_OTHER)"
    if settings.cpu_affinity:
        try:
            os.sched_setaffinity(0, set(settings.cpu_affinity))
            report["cpu_affinity"] = ",".join(map(str, sorted(settings.cpu_affinity)))
        except OSError as exc:
            report["cpu_affinity"] = f"not applied: {exc.strerror or exc}"
    else:
        report["cpu_affinity"] = "any"
    report["spin"] = f"{settings.spin_us} µs before each deadline"
    if _libc().prctl(PR_SET_TIMERSLACK, settings.timer_slack_ns, 0, 0, 0) == 0:
        report["timer_slack"] = f"{settings.timer_slack_ns} ns"
    else:
        report["timer_slack"] = f"not applied: {os.strerror(ctypes.get_errno())}"
    return report


def lower_priority(nice: int, avoid_cpus: Sequence[int]) -> None:
    """A helper process's own settings (the telemetry and episode recorders): ``nice`` and, when ``avoid_cpus`` (the
    cycle's) leaves other CPUs, off them. Best effort: a refusal leaves the process as it was."""
    with contextlib.suppress(OSError):
        os.nice(nice)
    with contextlib.suppress(OSError, AttributeError):
        others = os.sched_getaffinity(0) - set(avoid_cpus)
        if avoid_cpus and others:
            os.sched_setaffinity(0, others)
