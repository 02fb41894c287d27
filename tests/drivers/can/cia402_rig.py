"""An emulated CiA 402 drive behind `canopen`'s own master, on a private in-process virtual channel.

The master (`canopen.Network`, a `BaseNode402` from the same EDS) blocks on SDO replies, so a server thread
services the emulator at a frozen sim time: it answers every frame at once, but no plant time passes and no
timer runs on its own. Time advances only when a test calls `advance`, in fixed steps, so physics, heartbeats and
watchdogs are deterministic. Waits poll with a deadline, never sleep for luck.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import can
import canopen
from canopen.profiles.p402 import BaseNode402

from drivers.can.cia402.wiring import DriveWiring, wire_drives
from drivers.can.emulator import Cia402Firmware, Emulator, MotorPlant
from drivers.can.emulator.canopen_node import NmtState
from drivers.can.params import Cia402Params
from tests.conftest import CONFIGS

EDS = CONFIGS / "cia402_generic.eds"
T = TypeVar("T")


def wiring(node_ids: Sequence[int] = (3,), **drive: Any) -> list[DriveWiring]:
    drives = {f"j{k}": {"node_id": node_id, **drive} for k, node_id in enumerate(node_ids)}
    params = Cia402Params.model_validate(
        {"bus": {"interface": "virtual", "channel": "unused"}, "eds": str(EDS), "drives": drives}
    )
    wired, problems = wire_drives(params, list(drives), CONFIGS)
    assert not problems, problems
    return wired


def wait_until(condition: Callable[[], T], what: str, timeout: float = 5.0) -> T:
    deadline = time.monotonic() + timeout
    while not (result := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.001)
    return result


class Cia402Rig:
    """Drives on node ids `node_ids`, one `MotorPlant` joint each; `node` is the first drive's master-side node."""

    def __init__(self, node_ids: Sequence[int] = (3,), *, inertia: float = 0.05, **firmware: Any) -> None:
        self.channel = f"cia402-{uuid.uuid4().hex[:10]}"
        self.firmwares = [Cia402Firmware(w, seed=k, **firmware) for k, w in enumerate(wiring(node_ids))]
        self.firmware = self.firmwares[0]
        self.plant = MotorPlant(len(node_ids), inertia=inertia, damping=0.05)
        self.bus = can.Bus(interface="virtual", channel=self.channel)
        self.sniffer = can.Bus(interface="virtual", channel=self.channel)
        self.emulator = Emulator(self.bus, self.firmwares, self.plant)
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05  # how long closing waits for the notifier thread
        self.network.connect(interface="virtual", channel=self.channel)
        self.nodes = [self.network.add_node(BaseNode402(n, str(EDS))) for n in node_ids]
        self.node: BaseNode402 = self.nodes[0]
        self.boot_ups = [0] * len(self.nodes)
        """Boot-up frames canopen's NMT master heard from each node (from before the drive's first one)."""
        for k, node in enumerate(self.nodes):
            node.sdo.RESPONSE_TIMEOUT = 2.0  # canopen's waits are wall-clock: room for a loaded machine
            node.TIMEOUT_SWITCH_STATE_FINAL = 5.0
            node.TIMEOUT_SWITCH_STATE_SINGLE = 2.0
            node.TIMEOUT_SWITCH_OP_MODE = 2.0
            node.TIMEOUT_CHECK_TPDO = 1.0
            node.nmt.add_heartbeat_callback(lambda state, k=k: self._heard(k, state))
        self.now = 0.0
        self.error: BaseException | None = None
        """What ended the server thread, if anything did."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="cia402-emulator", daemon=True)
        self._thread.start()
        wait_until(lambda: all(self.boot_ups), "every drive's boot-up")

    def _heard(self, k: int, state: int) -> None:
        if state == 0:
            self.boot_ups[k] += 1

    def booted_again(self, k: int = 0) -> Callable[[], bool]:
        """A condition: node k's boot-up has been heard once more than now."""
        count = self.boot_ups[k]
        return lambda: self.boot_ups[k] > count

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                with self._lock:
                    self.emulator.service(self.now)
                self._stop.wait(0.0005)
        except BaseException as exc:  # surfaced by `close`: a waiting test would only see its deadline pass
            self.error = exc
            raise

    def advance(self, seconds: float, step: float = 0.001, each: Callable[[], None] | None = None) -> None:
        """Let `seconds` of sim time pass in `step`s; `each` runs (on the master side) before every step."""
        for _ in range(round(seconds / step)):
            if each is not None:
                each()
            with self._lock:
                self.now += step
                self.emulator.service(self.now)

    def on_drive(self, action: Callable[[], T]) -> T:
        """Run `action` between two services (as the emulator's control channel does)."""
        with self._lock:
            return action()

    def sniffed(self) -> list[can.Message]:
        """Every frame on the bus since the last call (both directions, except the sniffer's own)."""
        frames = []
        while (msg := self.sniffer.recv(timeout=0)) is not None:
            frames.append(msg)
        return frames

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.network.disconnect()
        self.bus.shutdown()
        self.sniffer.shutdown()
        if self.error is not None:
            raise AssertionError("the emulator's server thread failed") from self.error


def operational(rig: Cia402Rig) -> None:
    """canopen's NMT master starts the node; wait until the emulated drive is operational."""
    rig.node.nmt.state = "OPERATIONAL"
    wait_until(lambda: rig.firmware.nmt_state == NmtState.OPERATIONAL, "NMT operational")
