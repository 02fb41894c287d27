"""The cyclic PDO layout of one ``cia402`` drive: which objects travel in which PDO, and how they are packed.

One RPDO and one TPDO per drive and cycle on classic CAN (8 bytes each way):

* RPDO1 = 0x6040 controlword + the mode's target (CSP 0x607A, CSV 0x60FF, CST 0x6071) + 0x60B2 torque offset
  (CSP and CSV; CST's target already is a torque);
* TPDO1 = 0x6041 statusword + 0x6064 position actual + 0x6077 torque actual; velocity is derived from consecutive
  SYNC-latched positions, unless ``velocity_feedback: pdo`` adds TPDO2 = 0x606C velocity actual;
* CAN FD: TPDO1 also carries 0x606C and 0x603F error code (14 bytes, sent as a 16-byte FD frame).

Every PDO is synchronous (transmission type 1: each SYNC). The structs here are compiled once; the driver packs
its preallocated RPDO frames in place and unpacks TPDOs with them, so the cycle calls no ``canopen`` code.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from drivers.can.params import Cia402Mode

__all__ = ["Entry", "Layout", "Pdo", "fd_length", "layout_for", "rpdo_cob_id", "tpdo_cob_id"]

TRANSMISSION_SYNC = 1
"""0x1400/0x1800 sub 2: act on (RPDO) / send at (TPDO) every SYNC."""
PDO_COUNT = 4
"""RPDOs and TPDOs a drive offers (0x1400–0x1403, 0x1800–0x1803); the unused ones are disabled at configure."""
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@dataclass(frozen=True, slots=True)
class Entry:
    """One mapped object: index, subindex, bit length and its struct character."""

    index: int
    bits: int
    code: str
    subindex: int = 0

    @property
    def mapping(self) -> int:
        """The 0x1600/0x1A00 mapping entry: index << 16 | subindex << 8 | bits."""
        return self.index << 16 | self.subindex << 8 | self.bits


CONTROLWORD = Entry(0x6040, 16, "H")
STATUSWORD = Entry(0x6041, 16, "H")
POSITION_ACTUAL = Entry(0x6064, 32, "i")
VELOCITY_ACTUAL = Entry(0x606C, 32, "i")
TORQUE_ACTUAL = Entry(0x6077, 16, "h")
ERROR_CODE = Entry(0x603F, 16, "H")
TARGET_POSITION = Entry(0x607A, 32, "i")
TARGET_VELOCITY = Entry(0x60FF, 32, "i")
TARGET_TORQUE = Entry(0x6071, 16, "h")
TORQUE_OFFSET = Entry(0x60B2, 16, "h")

TARGETS: dict[str, Entry] = {"csp": TARGET_POSITION, "csv": TARGET_VELOCITY, "cst": TARGET_TORQUE}
OPTIONAL = frozenset({TORQUE_OFFSET, ERROR_CODE})
"""Left out of the layout when the drive cannot map them (the effort offset, the FD error code)."""


@dataclass(frozen=True, slots=True)
class Pdo:
    """One PDO (number 1..4) and its compiled little-endian struct."""

    number: int
    entries: tuple[Entry, ...]

    @property
    def size(self) -> int:
        return sum(e.bits for e in self.entries) // 8

    @property
    def layout(self) -> struct.Struct:
        return struct.Struct("<" + "".join(e.code for e in self.entries))


@dataclass(frozen=True, slots=True)
class Layout:
    """The PDOs of one drive in one mode."""

    rpdo: Pdo
    tpdos: tuple[Pdo, ...]
    fd: bool

    @property
    def has_torque_offset(self) -> bool:
        return TORQUE_OFFSET in self.rpdo.entries

    @property
    def has_velocity(self) -> bool:
        return any(VELOCITY_ACTUAL in p.entries for p in self.tpdos)

    @property
    def has_error_code(self) -> bool:
        return any(ERROR_CODE in p.entries for p in self.tpdos)

    def entries(self) -> tuple[Entry, ...]:
        return self.rpdo.entries + tuple(e for p in self.tpdos for e in p.entries)

    def frame_sizes(self) -> list[int]:
        """Payload bytes of every PDO one cycle carries (RPDO first), as sent (FD lengths rounded up)."""
        sizes = [self.rpdo.size, *(p.size for p in self.tpdos)]
        return [fd_length(s) for s in sizes] if self.fd else sizes


def layout_for(
    mode: Cia402Mode, velocity_feedback: str, fd: bool, mappable: Callable[[int], bool] | None = None
) -> Layout:
    """The layout of one drive: see the module docstring. `mappable` (index → the drive can map it) drops the
    optional entries a drive lacks; without it every entry is assumed mappable (the larger, worst-case layout)."""
    target = TARGETS[mode]
    rpdo = (CONTROLWORD, target) if mode == "cst" else (CONTROLWORD, target, TORQUE_OFFSET)
    if mappable is not None:
        rpdo = tuple(e for e in rpdo if e not in OPTIONAL or mappable(e.index))
    if fd:
        tpdo = (STATUSWORD, POSITION_ACTUAL, TORQUE_ACTUAL, VELOCITY_ACTUAL, ERROR_CODE)
        if mappable is not None:
            tpdo = tuple(e for e in tpdo if e not in OPTIONAL or mappable(e.index))
        return Layout(Pdo(1, rpdo), (Pdo(1, tpdo),), fd=True)
    tpdos = [Pdo(1, (STATUSWORD, POSITION_ACTUAL, TORQUE_ACTUAL))]
    if velocity_feedback == "pdo":
        tpdos.append(Pdo(2, (VELOCITY_ACTUAL,)))
    return Layout(Pdo(1, rpdo), tuple(tpdos), fd=False)


def fd_length(size: int) -> int:
    """The CAN FD frame length that carries `size` bytes (FD lengths above 8 go 12, 16, 20, 24, 32, 48, 64)."""
    return next(n for n in _FD_LENGTHS if n >= size)


def rpdo_cob_id(number: int, node_id: int) -> int:
    """Default COB-ID of RPDO `number` (CiA 301 predefined connection set: 0x200, 0x300, 0x400, 0x500 + node)."""
    return 0x100 + 0x100 * number + node_id


def tpdo_cob_id(number: int, node_id: int) -> int:
    """Default COB-ID of TPDO `number` (0x180, 0x280, 0x380, 0x480 + node)."""
    return 0x80 + 0x100 * number + node_id
