"""Real-time settings: applied when permitted, and always reported with what happened."""

from __future__ import annotations

import os
import struct
import sys
import threading
from pathlib import Path

from hild.config.model import RealtimeSection
from hild.cycle.realtime import CpuLatencyRequest, apply_process_settings, apply_thread_settings


def test_the_cpu_latency_request_is_written_and_held_until_released(tmp_path: Path) -> None:
    device = tmp_path / "cpu_dma_latency"  # the kernel's file takes one native int32, as a regular file does
    device.write_bytes(b"")
    request = CpuLatencyRequest(str(device))
    assert request.hold(0) == "0 µs, held"
    assert request.held and struct.unpack("i", device.read_bytes()) == (0,)
    fd = request._fd
    assert fd is not None
    request.release()
    assert not request.held
    try:
        os.fstat(fd)
    except OSError:
        pass  # closed: the kernel withdraws the request
    else:
        raise AssertionError("the request's file stayed open")
    request.release()  # twice is harmless (shutdown, then run_daemon's finally)


def test_a_cpu_latency_request_that_cannot_be_made_says_why(tmp_path: Path) -> None:
    request = CpuLatencyRequest(str(tmp_path / "missing" / "cpu_dma_latency"))
    report = request.hold(0)
    assert report.startswith("not permitted:") and "udev rule" in report and not request.held
    assert CpuLatencyRequest(str(tmp_path / "unused")).hold(None) == "off"


def test_process_and_thread_settings_report_each_setting() -> None:
    before = sys.getswitchinterval()
    try:
        report = apply_process_settings(RealtimeSection(switch_interval=0.0002))
        assert abs(sys.getswitchinterval() - 0.0002) < 1e-9 and report["switch_interval"] == "0.2 ms"
        assert report["lock_memory"] == "off"
    finally:
        sys.setswitchinterval(before)
    result: dict[str, str] = {}
    thread = threading.Thread(target=lambda: result.update(apply_thread_settings(RealtimeSection(priority=10))))
    thread.start()
    thread.join()
    assert result["priority"] == "SCHED_FIFO 10" or result["priority"].startswith("not permitted:")
    assert result["spin"] == "200 µs before each deadline" and result["cpu_affinity"] == "any"
