"""The engine's state that changes only with ``change_seq``, as one immutable value.

The cycle writes a new one whenever something changes (a mode, a fault, a controller, a hardware state) and never
per cycle; the client domain renders the status and list replies from it (``hild.crossing.status``) together with the
numbers that do move every cycle (the clock, the loop statistics, each joint's longest silence), which it reads
from their own cells. Plain tuples and dicts: it pickles to cross into the other process.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Snapshot:
    change_seq: int
    mode: str  # hold, active, fault or estop
    joints: tuple[dict[str, Any], ...]  # name, mode, owner, fault, limits
    controllers: tuple[dict[str, Any], ...]  # list_controllers' entries
    hardware: tuple[dict[str, Any], ...]  # list_hardware's entries
    interfaces: tuple[dict[str, Any], ...]  # list_interfaces' entries
    realtime: dict[str, str] = field(default_factory=dict)
    tuning: Any = None  # the daemon's own parameters as they are now (hild.config.tuning.ManagerParams)
    # name, type, frame_id, hardware, state_interfaces, fault (None: healthy), available
    sensors: tuple[dict[str, Any], ...] = ()
    walls: dict[str, Any] | None = None  # safety.walls on: the tool frame and the walls engaged now
    # every owner code the engine ever gave → its controller's name (the cycle log's owner column; never reused)
    controller_codes: dict[int, str] = field(default_factory=dict)
    # per joint homed since start (hild/cycle/homing.py): joint, state, attempt, detail, position
    homing: tuple[dict[str, Any], ...] = ()
