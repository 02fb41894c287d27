"""The command path's bridge in isolation: frames through a loopback CAN server, with or without busy Python threads.

Why: the 195 ms command → frame p50 of the [teleop] issue came from the bench's own bridge. Its stock
``can_remote.RemoteServer`` reads every frame with four blocking socket calls in a thread of its own, each a GIL
hand-over; beside CPU-bound Python threads in the same process (the client domain, the emulated drives) every
hand-over waits up to ``sys.getswitchinterval()`` (5 ms), so the server moves a few dozen frames a second while
the cycle sends a thousand and they queue. A ``drivers.can.emulator.remote_host.RemoteServerBus`` served by the
emulator's own loop in a process of its own (what the bench's rig does now) reads them all between two services.

``run_bridge(kind, busy, frames)`` starts a server process (``python -m hild.bench.rigs.bridge_stall``) of one
``kind`` (``stock``: RemoteServer + a virtual channel + a drive loop reading it; ``loop``: RemoteServerBus read by
the drive loop itself) with ``busy`` CPU-bound threads beside it, sends ``frames`` frames at ``rate`` from this
process through python-can's ``remote`` client (as the cycle process's driver does), each carrying its send time
(``perf_counter_ns``, CLOCK_MONOTONIC: one clock for the machine), and returns each frame's delay to the drive
loop, ``None`` for a frame that never arrived. tests/bench/test_command_path.py and tools/command_hops.py use it.
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass

HOST = "127.0.0.1"
KINDS = ("stock", "loop")
DRIVE_PERIOD = 0.0002  # s, the bench emulator's service period
STAMP = struct.Struct("<Q")
FRAME_ID = 0x01
LINGER_S = 1.0  # s the server keeps reading after the last frame was sent
START_TIMEOUT = 30.0


@dataclass(frozen=True)
class BridgeRun:
    kind: str
    busy: int
    delays_ns: list[int | None]  # per frame sent, in order; None: never reached the drive

    def within(self, deadline_s: float) -> int:
        """How many frames reached the drive within ``deadline_s`` of their send."""
        limit = round(deadline_s * 1e9)
        return sum(1 for d in self.delays_ns if d is not None and d <= limit)

    @property
    def delivered(self) -> int:
        return sum(1 for d in self.delays_ns if d is not None)


def _spin(stop: threading.Event) -> None:
    while not stop.is_set():
        sum(range(500))  # pure Python: holds the GIL until the interpreter's switch interval takes it


def _serve(kind: str, busy: int) -> None:
    """The server process: print the address, drive-loop every frame until stdin closes, print the arrivals."""
    import can

    from drivers.can.emulator.remote_host import RemoteServerBus

    stop = threading.Event()
    server = None
    if kind == "stock":
        from can_remote import RemoteServer

        channel = f"bridge-stall-{uuid.uuid4().hex[:8]}"
        server = RemoteServer(HOST, 0, interface="virtual", channel=channel, receive_own_messages=False)
        threading.Thread(target=server.serve_forever, name="stock-server", daemon=True).start()
        bus: can.BusABC = can.Bus(interface="virtual", channel=channel)
        address = f"ws://{HOST}:{server.server_address[1]}/"
    else:
        bus = RemoteServerBus(HOST, 0)
        address = f"ws://{bus.address[0]}:{bus.address[1]}/"
    arrivals: list[tuple[int, int]] = []

    def drive() -> None:  # the emulator's loop: every DRIVE_PERIOD, take what the bus holds
        while not stop.is_set():
            while (msg := bus.recv(0.0)) is not None:
                arrivals.append((STAMP.unpack(bytes(msg.data))[0], time.perf_counter_ns()))
            time.sleep(DRIVE_PERIOD)

    threads = [threading.Thread(target=drive, name="drive", daemon=True)]
    threads += [threading.Thread(target=_spin, args=(stop,), name=f"busy{k}", daemon=True) for k in range(busy)]
    for thread in threads:
        thread.start()
    print(json.dumps({"address": address}), flush=True)
    sys.stdin.read()  # the client closes stdin after its last frame and LINGER_S
    stop.set()
    for thread in threads:
        thread.join(2.0)
    print(json.dumps({"arrivals": arrivals}), flush=True)
    if server is not None:
        server.shutdown()
    bus.shutdown()


def run_bridge(kind: str, busy: int, frames: int, rate: float = 1000.0) -> BridgeRun:
    """Send ``frames`` frames at ``rate`` through a ``kind`` server with ``busy`` threads beside it (see above)."""
    import can

    if kind not in KINDS:
        raise ValueError(f"kind is one of {KINDS}, not {kind!r}")
    command = [sys.executable, "-m", "hild.bench.rigs.bridge_stall", kind, "--busy", str(busy)]
    server = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert server.stdin is not None and server.stdout is not None
    try:
        line = server.stdout.readline()
        if not line:
            raise RuntimeError(f"the {kind} bridge server did not start (exit {server.wait(START_TIMEOUT)})")
        address = json.loads(line)["address"]
        client = can.Bus(interface="remote", channel=address, receive_own_messages=False)
        sent: list[int] = []
        try:
            period = round(1e9 / rate)
            due = time.perf_counter_ns()
            for _ in range(frames):
                due += period
                while time.perf_counter_ns() < due:
                    time.sleep(0.0001)
                stamp = time.perf_counter_ns()
                client.send(can.Message(arbitration_id=FRAME_ID, data=STAMP.pack(stamp), is_extended_id=False))
                sent.append(stamp)
            time.sleep(LINGER_S)
        finally:
            client.shutdown()
        server.stdin.close()
        out = server.stdout.read()
        server.wait(START_TIMEOUT)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
    arrived = {s: a for s, a in json.loads(out.strip().splitlines()[-1])["arrivals"]}
    return BridgeRun(kind, busy, [arrived[s] - s if s in arrived else None for s in sent])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="A loopback CAN server for hild.bench.rigs.bridge_stall.")
    parser.add_argument("kind", choices=KINDS)
    parser.add_argument("--busy", type=int, default=0, help="CPU-bound Python threads beside the server")
    args = parser.parse_args(argv)
    _serve(args.kind, args.busy)
    return 0


if __name__ == "__main__":
    sys.exit(main())
