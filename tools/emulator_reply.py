#!/usr/bin/env python3
"""A drive's reply time across ``hild emulate --serve-remote``'s bus: woken by the frame, or polled on the grid.

    python tools/emulator_reply.py                       # the default rate beside a 500 Hz daemon (1 kHz), both ways
    python tools/emulator_reply.py --rate 5000 --frames 2000

One emulated Damiao drive behind a ``RemoteServerBus`` on 127.0.0.1, served by ``serve_on_grid`` at ``--rate`` on
the wall clock, as ``hild emulate`` serves it; a python-can ``remote`` client (as the daemon's driver) sends an
enable and waits for the reply, ``--frames`` times with a few milliseconds between them (a command lands anywhere
in the grid's period). ``woken``: the frame wakes the loop (``frame_wakeup``); ``polled``: the loop only serves on
its grid, as before. Round trip = the client's send → its recv of the reply (µs). Wall time: a loaded machine moves
the figures.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time

import can

from drivers.can.emulator import DamiaoFirmware, Emulator, MotorPlant
from drivers.can.emulator.core import frame_wakeup, loop_stats, serve_on_grid
from drivers.can.emulator.remote_host import RemoteServerBus
from drivers.can.protocol.flavours import DAMIAO
from drivers.can.protocol.models import MODELS


def round_trips(rate: float, frames: int, woken: bool) -> tuple[list[float], dict[str, float]]:
    server = RemoteServerBus("127.0.0.1", 0)
    emulator = Emulator(server, [DamiaoFirmware(1, 0x11, MODELS["damiao"]["DM4310"])], MotorPlant(1))
    stop, stats = threading.Event(), loop_stats()
    wake = frame_wakeup([server]) if woken else None
    loop = threading.Thread(
        target=serve_on_grid, args=(emulator.service, 1.0 / rate, stop), kwargs={"wake": wake, "stats": stats}
    )
    loop.start()
    host = can.Bus(interface="remote", channel=f"ws://127.0.0.1:{server.address[1]}/")
    enable = DAMIAO.special(1, "enable")
    micros: list[float] = []
    try:
        host.send(enable)
        host.recv(timeout=5.0)
        for i in range(frames):
            start = time.perf_counter_ns()
            host.send(enable)
            if host.recv(timeout=5.0) is None:
                raise RuntimeError("no reply within 5 s")
            micros.append((time.perf_counter_ns() - start) / 1000.0)
            time.sleep(0.002 + 0.001 * (i % 7) / 7)  # land anywhere in the grid's period
    finally:
        host.shutdown()  # answered by the loop, which still runs
        stop.set()
        loop.join()
        server.shutdown()
    return micros, stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=1000.0, help="the loop's grid, Hz (hild emulate --rate)")
    parser.add_argument("--frames", type=int, default=1000)
    args = parser.parse_args()
    print(f"round trip across the remote bus, grid {args.rate:g} Hz, {args.frames} frames (µs)")
    print(f"{'loop':<8}{'p50':>8}{'p99':>8}{'max':>8}  services (woken)")
    for woken in (True, False):
        micros, stats = round_trips(args.rate, args.frames, woken)
        micros.sort()
        p99 = micros[min(len(micros) - 1, round(0.99 * (len(micros) - 1)))]
        print(
            f"{'woken' if woken else 'polled':<8}{statistics.median(micros):>8.0f}{p99:>8.0f}{micros[-1]:>8.0f}"
            f"  {stats['services']:.0f} ({stats['woken']:.0f})"
        )


if __name__ == "__main__":
    main()
