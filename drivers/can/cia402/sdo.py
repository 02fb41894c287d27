"""canopen's SDO client on hild's own bus link, for lifecycle hooks only.

``canopen``'s blocking SDO client waits on a queue that ``Network.notify`` fills. ``Network.connect`` would start
a ``can.Notifier`` thread reading the bus, competing with the cycle's drain, so it is never called: a
``LinkNetwork`` sends through the component's ``CanLink`` and is fed the SDO answers by the component. A transfer
runs in a short-lived worker thread while the lifecycle thread keeps draining the bus (and serving in-process
emulators through ``CanLink.collect``); the worker has ended before ``run_transfers`` returns.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

import can
import canopen

from drivers.can.bus import CanLink
from hild.hardware import HardwareError

__all__ = ["LinkNetwork", "run_transfers"]

T = TypeVar("T")
_JOIN_GRACE = 1.0  # s: after the collect bound, how long to wait for a worker still inside an SDO timeout


class LinkNetwork(canopen.Network):
    """A canopen ``Network`` without a Notifier: sends through `link`, receives what the component feeds it."""

    def __init__(self, link: CanLink) -> None:
        super().__init__(None)
        self.link = link

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        msg = can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False, is_remote_frame=remote)
        try:
            self.link.send_wait(msg)
        except HardwareError as exc:  # canopen's SDO client retries on CanError
            raise can.CanError(str(exc)) from exc

    def feed(self, msg: can.Message) -> None:
        """Hand one received frame to canopen's subscribers (the SDO clients' answer queues)."""
        self.notify(msg.arbitration_id, msg.data, msg.timestamp)


def run_transfers(
    link: CanLink, handle: Callable[[can.Message], None], transfers: Callable[[], T], timeout: float
) -> T:
    """Run `transfers` (blocking canopen SDO calls) in a worker while this thread feeds received frames to
    `handle`; return its result or re-raise its exception. Each SDO call is bounded by its client's
    ``RESPONSE_TIMEOUT``, so `timeout` only guards against a bus that never lets the worker finish."""
    outcome: dict[str, object] = {}

    def work() -> None:
        try:
            outcome["value"] = transfers()
        except BaseException as exc:  # re-raised on the lifecycle thread
            outcome["error"] = exc

    worker = threading.Thread(target=work, name="cia402-sdo", daemon=True)
    worker.start()
    try:
        link.collect(handle, lambda: not worker.is_alive(), timeout)
    finally:
        worker.join(_JOIN_GRACE)
    if worker.is_alive():
        raise HardwareError(f"CANopen SDO transfers on {link.spec.name} did not finish within {timeout:g} s")
    error = outcome.get("error")
    if isinstance(error, BaseException):
        raise error
    return outcome["value"]  # type: ignore[return-value]
