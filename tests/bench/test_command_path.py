"""The [teleop] issue's 195 ms command → frame finding, reproduced in isolation (hild.bench.rigs.bridge_stall).

The stock python-can-remote server moves each frame with four blocking socket calls in a thread of its own; beside
CPU-bound Python threads in its process every call waits for the GIL (up to the 5 ms switch interval), so at the
cycle's 1 kHz most frames reach the drive far too late. The emulator's own loop serving the bus in a process of
its own (the bench rig's fix) delivers them all within a few ms. Counts within one switch interval, not tight
timings: the stock server beside busy threads pays up to a switch interval per blocking call, four per frame, so
most frames miss it (measured: 1 to 9 % within); the loop's frames take a fraction of a millisecond (p50 0.2 ms),
so a loaded machine does not fail the bound either. On a loaded 2-core machine a released GIL is often retaken by
the thread that released it before a busy waiter is scheduled, which softens the stall; on an idle many-core
machine every waiter runs at once and it is worse.
"""

from __future__ import annotations

from hild.bench.rigs.bridge_stall import run_bridge

FRAMES = 1000  # at 1 kHz: 1 s of a cycle's commands
DEADLINE_S = 0.005  # sys.getswitchinterval(): five periods of the cycle
BUSY = 3  # CPU-bound Python threads: the client domain's and the emulated drives' share of the GIL, and more


def test_stock_server_beside_busy_threads_queues_the_cycles_frames() -> None:
    run = run_bridge("stock", busy=BUSY, frames=FRAMES)
    assert run.within(DEADLINE_S) < FRAMES // 2, (run.within(DEADLINE_S), run.delivered)


def test_stock_server_alone_delivers_them_so_the_threads_are_the_cause() -> None:
    run = run_bridge("stock", busy=0, frames=FRAMES)
    assert run.within(DEADLINE_S) >= FRAMES * 9 // 10, (run.within(DEADLINE_S), run.delivered)


def test_the_emulators_own_loop_in_a_process_of_its_own_delivers_every_frame_in_time() -> None:
    run = run_bridge("loop", busy=0, frames=FRAMES)
    assert run.delivered == FRAMES
    assert run.within(DEADLINE_S) >= FRAMES * 98 // 100, run.within(DEADLINE_S)
