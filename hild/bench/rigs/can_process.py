"""The CAN bench rig in a process of its own, each bus served over loopback by the emulator's own loop.

Why: with ``realtime.cycle_process`` the daemon's drivers run in the cycle process, and a python-can ``virtual``
channel does not leave its process. The bench used to serve each channel with python-can-remote's stock
``RemoteServer`` inside the scenario's process: two threads per client, four blocking socket calls per frame, each
a GIL hand-over against the daemon's client domain and the emulated drives in that same process. Beside busy
Python threads a hand-over waits up to the 5 ms switch interval, so the cycle's frames queued — the [teleop]
issue's command → frame p50 195 ms, p99 1.06 s, 215/300 probes matched (docs/performance.md, "The command path:
the 195 ms finding"; reproduced by tests/bench/test_command_path.py). ``hild emulate --serve-remote`` had that fix
already (drivers/can/emulator/remote_host.py); this is the same for the bench: the emulated drives (the
``mit_can`` rig, :class:`hild.bench.rigs.mit_can.CanBenchRig`) run here, each bus a ``RemoteServerBus`` that their
service loop reads between two services — no thread per client, no GIL hand-over per frame, and no GIL shared with
the daemon. The scenario's process is then the daemon alone (client domain, main), as on a robot PC.

The probe frames are stamped here (``perf_counter_ns``: CLOCK_MONOTONIC, one clock for the machine) when the loop
reads them off the socket, and read back by the bench after the window.

Control: JSON lines on stdin/stdout (``listen`` on/off, ``counters``, ``stop``); the first line out is
``{"event": "ready", "pid", "channels": {virtual channel: ws:// address}}``. Run by :class:`CanRigProcess` (in the
daemon's bench host, ``hild.bench.host --can-bridge``), never by hand.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import queue
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO, Any

from hild.bench.children import end_child
from hild.bench.rigs.can_bridge import HOST, bridged_document, virtual_channels
from hild.config.documents import load_document

READY_TIMEOUT = 60.0  # s from spawning to the drives serving
REQUEST_TIMEOUT = 120.0  # s for one control request (listen off returns every probe frame)
STOP_TIMEOUT = 10.0


def serve(config: str, out: IO[str], rig_name: str = "mit_can") -> int:
    """The rig process: serve the config's virtual channels with the drives of rig ``rig_name``, answer control
    lines until ``stop`` or stdin's end."""
    from drivers.can.bus import BusSpec
    from drivers.can.emulator.remote_host import RemoteServerBus
    from hild.bench.rigs import rig_class
    from hild.config.loader import load_config

    served: dict[str, str] = {}

    def open_served(spec: BusSpec) -> Any:
        bus = RemoteServerBus(HOST, 0)  # closed by the rig's stop, with the emulators
        served[str(spec.channel)] = f"ws://{bus.address[0]}:{bus.address[1]}/"
        return bus

    rig: Any = rig_class(rig_name)(open_served)  # type: ignore[call-arg]  # a CAN rig: CanBenchRig or a subclass
    rig.start(load_config(config))
    try:
        out.write(json.dumps({"event": "ready", "pid": os.getpid(), "channels": served}) + "\n")
        out.flush()
        for line in sys.stdin:
            request = json.loads(line)
            op = request.get("op")
            if op == "stop":
                break
            if op == "listen":
                reply = {"ok": True, **rig.listen(bool(request.get("on")))}
            elif op == "counters":
                reply = {"ok": True, "counters": rig.counters()}
            else:
                reply = {"ok": False, "error": f"unknown op {op!r}"}
            out.write(json.dumps(reply) + "\n")
            out.flush()
    finally:
        rig.stop()  # shuts the RemoteServerBuses down: their clients are told the bus went away
    return 0


class CanRigProcess:
    """A CAN rig (``mit_can``, ``cia402``) as the bench host sees it when the buses are bridged (a ``BenchRig``,
    plus ``serve`` and ``processes``): the drives in a child process, reached over loopback."""

    def __init__(self, rig_name: str = "mit_can") -> None:
        from hild.bench.rigs import rig_class

        self.rig_name = rig_name
        self.trajectory_scale = rig_class(rig_name).trajectory_scale
        self.process: subprocess.Popen[str] | None = None
        self.drivers: list[Any] = []
        self._lines: queue.Queue[str] = queue.Queue()
        self._lock = threading.Lock()  # one request at a time (listen runs in a worker thread of the host)

    def robot_config(self, joints: int, rate: float) -> dict[str, Any]:
        from hild.bench.rigs import rig_class

        return rig_class(self.rig_name).robot_config(joints, rate)

    def serve(self, config: Path) -> Path:
        """Start the rig process on ``config``'s virtual channels; write and return the daemon's config (the same
        robot, its buses ``interface: remote`` at the rig process's servers)."""
        data: dict[str, Any] = load_document(config)
        if not virtual_channels(data):
            raise ValueError(f"{config}: no hardware component on a virtual CAN channel to bridge")
        command = [sys.executable, "-m", "hild.bench.rigs.can_process", str(config), "--rig", self.rig_name]
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
        threading.Thread(
            target=self._read, args=(self.process.stdout,), name="bench-can-rig-reader", daemon=True
        ).start()
        ready = self._answer(READY_TIMEOUT)
        if ready.get("event") != "ready":
            raise RuntimeError(f"the CAN rig process did not start: {ready}")
        bridged = config.with_name(f"{config.stem}-bridged{config.suffix}")
        bridged.write_text(json.dumps(bridged_document(data, ready["channels"]), indent=1))  # JSON is YAML
        return bridged

    def _read(self, stdout: IO[str]) -> None:
        for line in stdout:
            self._lines.put(line)
        self._lines.put("")

    def _answer(self, timeout: float) -> dict[str, Any]:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            raise RuntimeError(f"the CAN rig process did not answer within {timeout:g} s") from None
        if not line:
            raise RuntimeError(f"the CAN rig process ended (exit {self.process and self.process.poll()})")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def request(self, op: str, **fields: Any) -> dict[str, Any]:
        process = self.process
        assert process is not None and process.stdin is not None
        with self._lock:
            process.stdin.write(json.dumps({"op": op, **fields}) + "\n")
            process.stdin.flush()
            reply = self._answer(REQUEST_TIMEOUT)
        if not reply.get("ok"):
            raise RuntimeError(f"CAN rig process: {op}: {reply.get('error', reply)}")
        reply.pop("ok")
        return reply

    def start(self, loaded: Any) -> None:
        """Nothing: ``serve`` started the drives (before the daemon configures, as it must)."""

    def attach(self, engine: Any) -> None:
        """Keep the daemon's CAN drivers for their frame counters (only when the cycle is a thread of the host)."""
        self.drivers = [s.component for s in engine.hardware if hasattr(s.component, "statistics")]

    def threads(self) -> dict[str, int]:
        return {}  # none in the daemon's process

    def processes(self) -> dict[str, int]:
        """The rig's process, for its CPU (the emulated drives and their loopback servers, one loop)."""
        return {"emulator": self.process.pid} if self.process is not None else {}

    def counters(self) -> dict[str, int]:
        out: dict[str, int] = dict(self.request("counters")["counters"])
        for driver in self.drivers:
            for key, value in driver.statistics.items():
                out[f"driver {key}"] = out.get(f"driver {key}", 0) + value
        return out

    def listen(self, on: bool) -> dict[str, Any]:
        return self.request("listen", on=on)

    def stop(self) -> None:
        process, self.process = self.process, None
        if process is None:
            return
        with contextlib.suppress(OSError, ValueError):  # gone already, or its stdin closed: end_child still ends it
            assert process.stdin is not None
            process.stdin.write(json.dumps({"op": "stop"}) + "\n")
        end_child(process, STOP_TIMEOUT)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="The CAN bench rig's process (run by hild.bench.host).")
    parser.add_argument("config")
    parser.add_argument("--rig", default="mit_can", help="the CAN rig whose drives to serve (mit_can, cia402)")
    args = parser.parse_args(argv)
    out = os.fdopen(os.dup(1), "w", buffering=1)  # the control channel
    os.dup2(2, 1)  # anything else printed goes to the log
    return serve(args.config, out, args.rig)


if __name__ == "__main__":
    sys.exit(main())
