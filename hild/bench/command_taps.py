"""Bench-only taps on the command path's hops, for tools/command_hops.py: nothing in the product calls them.

Why: the command → frame figure is one number across four processes (the bench, the daemon's client domain, the
cycle process, the emulated drives); to say where its time goes each hop is stamped on ``perf_counter_ns``
(CLOCK_MONOTONIC, one clock for the machine):

* ``accept`` — ``forward_command``'s input callback in the client domain took the command (first value);
* ``adopt`` — the cycle's ``LatestNumbers.take`` returned it (the crossing, ``hild.crossing.mailboxes``);
* ``send`` — ``CanLink.send`` in the cycle's driver was handed the first motor's command frame (its 8 bytes).

``install()`` wraps those three methods in the process it runs in, when ``HILD_COMMAND_HOPS_DIR`` names a
directory: the tool puts a ``sitecustomize`` on ``PYTHONPATH`` that calls it, so every process the bench starts
(the daemon, its cycle process) is tapped without a line of hild changed. Stamps go to a list and a thread of the
tap appends them to ``<dir>/<pid>.jsonl`` every ``FLUSH_S`` — in the cycle process too, one more Python thread
that sleeps almost always (so the cycle's own figures under the tap are not the product's; the hops are).
"""

from __future__ import annotations

import atexit
import json
import os
import threading
import time
from pathlib import Path
from typing import Any

ENV = "HILD_COMMAND_HOPS_DIR"
WATCHED_ID = 0x01  # the first motor's command id: the one the bench's probes move
FLUSH_S = 0.25

_stamps: list[tuple[str, int, Any]] = []
_lock = threading.Lock()


def _note(kind: str, value: Any) -> None:
    _stamps.append((kind, time.perf_counter_ns(), value))  # list.append is atomic under the GIL


class _TakeTap:
    """A ``LatestNumbers`` whose ``take`` notes what it adopted (the first value)."""

    def __init__(self, slot: Any) -> None:
        self._slot = slot

    def take(self) -> Any:
        fresh = self._slot.take()
        if fresh is not None:
            _note("adopt", float(fresh[0]))
        return fresh

    def __getattr__(self, name: str) -> Any:
        return getattr(self._slot, name)


def _flush(path: Path) -> None:
    with _lock:
        taken = len(_stamps)
        if not taken:
            return
        lines = "".join(json.dumps(s) + "\n" for s in _stamps[:taken])
        del _stamps[:taken]
        with path.open("a") as f:
            f.write(lines)


def _flusher(path: Path) -> None:
    while True:
        time.sleep(FLUSH_S)
        _flush(path)


def install() -> bool:
    """Tap this process's command path when ``HILD_COMMAND_HOPS_DIR`` is set; whether it did."""
    where = os.environ.get(ENV)
    if not where:
        return False
    from drivers.can.bus import CanLink
    from hild.controllers.forward_command import ForwardCommandController

    accept, init, send = ForwardCommandController.accept, ForwardCommandController.__init__, CanLink.send

    def tapped_accept(self: Any, payload: Any) -> None:
        values = payload.get("values") if isinstance(payload, dict) else None
        if isinstance(values, list) and values:
            _note("accept", float(values[0]))
        accept(self, payload)

    def tapped_init(self: Any, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        self._slot = _TakeTap(self._slot)

    def tapped_send(self: Any, msg: Any) -> bool:
        if msg.arbitration_id == WATCHED_ID and len(msg.data) == 8:
            _note("send", bytes(msg.data).hex())
        return bool(send(self, msg))

    ForwardCommandController.accept = tapped_accept  # type: ignore[method-assign]
    ForwardCommandController.__init__ = tapped_init  # type: ignore[method-assign]
    CanLink.send = tapped_send  # type: ignore[method-assign]
    path = Path(where) / f"{os.getpid()}.jsonl"
    threading.Thread(target=_flusher, args=(path,), name="bench-command-taps", daemon=True).start()
    atexit.register(_flush, path)
    return True


def read_stamps(where: Path) -> dict[str, list[tuple[int, Any]]]:
    """Every process's stamps in ``where``, by kind, in time order."""
    out: dict[str, list[tuple[int, Any]]] = {"accept": [], "adopt": [], "send": []}
    for path in sorted(where.glob("*.jsonl")):
        for line in path.read_text().splitlines():
            kind, stamp, value = json.loads(line)
            out.setdefault(kind, []).append((int(stamp), value))
    for stamps in out.values():
        stamps.sort(key=lambda s: s[0])
    return out


SITECUSTOMIZE = f"""# written by tools/command_hops.py: tap the command path's hops in every process hild bench starts
import os

if os.environ.get({ENV!r}):
    from hild.bench.command_taps import install

    install()
"""
