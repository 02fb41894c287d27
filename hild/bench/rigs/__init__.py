"""Rigs: what a bench scenario adds to the daemon's process so a robot's hardware is there without a robot.

``mit_can`` (:mod:`hild.bench.rigs.mit_can`) emulates Damiao drives on python-can virtual channels in the
daemon's process, ``cia402`` (:mod:`hild.bench.rigs.cia402`) CANopen CiA 402 drives the same way; with the cycle in
a process of its own :mod:`hild.bench.rigs.can_process` runs them in a process of theirs instead, each bus served
over loopback by their own loop (``--stock-can-bridge``: as before [teleop], in the daemon's process behind
python-can-remote's stock server, :mod:`hild.bench.rigs.can_bridge`).
:mod:`hild.bench.rigs.bridge_stall` measures those two servers alone. The measuring room may
import python-can, like the tests (docs/architecture.md, "Rooms"), so a rig is found by name here, not through an
entry-point group.
"""

from __future__ import annotations

from typing import Any, Protocol


class BenchRig(Protocol):
    """What a rig offers the bench, called in this order: ``robot_config`` (the bench) → ``start`` → ``attach``
    → ``listen``/``counters`` … → ``stop`` (the scenario's process)."""

    trajectory_scale: float

    @staticmethod
    def robot_config(joints: int, rate: float) -> dict[str, Any]: ...

    def start(self, loaded: Any) -> None: ...

    def attach(self, engine: Any) -> None: ...

    def threads(self) -> dict[str, int]: ...

    def counters(self) -> dict[str, int]: ...

    def listen(self, on: bool) -> dict[str, Any]: ...

    def stop(self) -> None: ...


RIGS = ("mit_can", "cia402")


def rig_class(name: str) -> type[BenchRig]:
    """The rig called ``name``, imported only when asked for (python-can loads with it)."""
    if name == "mit_can":
        from hild.bench.rigs.mit_can import CanBenchRig

        return CanBenchRig
    if name == "cia402":
        from hild.bench.rigs.cia402 import Cia402BenchRig

        return Cia402BenchRig
    raise LookupError(f"no bench rig {name!r} (known: {', '.join(RIGS)})")
