"""Which drive answers where and in which units: ``cia402``'s drives resolved from the config and their EDS.

Shared by the host driver and the emulator (``hild emulate`` builds each emulated drive from the same wiring), so
both ends of a bus agree on node ids, modes and scaling: position units per radian, velocity units per rad/s,
per-mille torque per N·m. A value the config leaves out comes from the drive's EDS/DCF (the object the CiA 402
profile defines for it); what neither gives is a problem ``hild check`` lists.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen.objectdictionary import ObjectDictionary

from drivers.can.component import coverage_problems
from drivers.can.params import Cia402DriveParams, Cia402Mode, Cia402Params

__all__ = ["DriveWiring", "dictionary_path", "load_dictionary", "mode_of", "wire_drives"]

TAU = 2.0 * math.pi
ENCODER_RESOLUTION = 0x608F  # sub 1 encoder increments, sub 2 motor revolutions
GEAR_RATIO = 0x6091  # sub 1 motor revolutions, sub 2 shaft revolutions
MOTOR_RATED_TORQUE = 0x6076  # mN·m
MODE_CODES: dict[str, int] = {"csp": 8, "csv": 9, "cst": 10}
"""0x6060 modes of operation (CiA 402: 8 cyclic synchronous position, 9 velocity, 10 torque)."""
SUPPORTED_MODE_BITS: dict[str, int] = {"csp": 1 << 7, "csv": 1 << 8, "cst": 1 << 9}
"""0x6502 supported drive modes: the bit of each cyclic synchronous mode."""
HOMING_BIT = 1 << 5


@dataclass(frozen=True, slots=True)
class DriveWiring:
    """One drive's node, mode, dictionary and unit scaling, resolved from the config and its EDS."""

    joint: str
    node_id: int
    mode: Cia402Mode
    eds: Path
    counts_per_rad: float
    """Position units (0x6064, 0x607A) per radian of the actuator shaft."""
    velocity_per_rad_s: float
    """Velocity units (0x606C, 0x60FF, 0x60B1) per rad/s."""
    rated_torque: float
    """N·m of 1000 ‰ (0x6071, 0x6077, 0x60B2 are per mille of it)."""
    params: Cia402DriveParams

    @property
    def permille_per_nm(self) -> float:
        return 1000.0 / self.rated_torque


def dictionary_path(params: Cia402Params, drive: Cia402DriveParams, config_dir: Path) -> Path:
    """The EDS/DCF of one drive: its own, else the component's; relative paths from the config's directory."""
    return config_dir / (drive.eds or params.eds)


@functools.lru_cache(maxsize=32)
def _parsed(path: Path, node_id: int) -> ObjectDictionary:
    return canopen.import_od(str(path), node_id)


def load_dictionary(path: Path, node_id: int) -> ObjectDictionary:
    """The object dictionary of `path` for `node_id` (``$NODEID`` resolved), parsed once per file and node.

    Shared between callers: treat it as read-only (a ``LocalNode`` keeps its values in its own data store)."""
    return _parsed(path.resolve(), node_id)


def _default(od: ObjectDictionary, index: int, subindex: int | None = None) -> float | None:
    """An object's default value from the EDS, or None when the dictionary has none."""
    if index not in od:
        return None
    obj = od[index]
    if subindex is not None:
        if subindex not in obj:  # type: ignore[operator]
            return None
        obj = obj[subindex]  # type: ignore[index]
    value = getattr(obj, "default", None)
    return float(value) if isinstance(value, int | float) else None


def counts_per_rev_from(od: ObjectDictionary) -> float | None:
    """0x608F increments per motor revolution × 0x6091 motor revolutions per shaft revolution (gear 1 if absent)."""
    increments, motor_revs = _default(od, ENCODER_RESOLUTION, 1), _default(od, ENCODER_RESOLUTION, 2)
    if not increments or not motor_revs:
        return None
    gear_motor, gear_shaft = _default(od, GEAR_RATIO, 1), _default(od, GEAR_RATIO, 2)
    gear = gear_motor / gear_shaft if gear_motor and gear_shaft else 1.0
    return increments / motor_revs * gear


def mode_of(params: Cia402Params, joint: str) -> Cia402Mode:
    """A joint's cyclic synchronous mode: its drive's own, else the component's."""
    drive = params.drives.get(joint)
    return (drive.mode if drive is not None else None) or params.mode


def wire_drives(params: Cia402Params, joints: Sequence[str], config_dir: Path) -> tuple[list[DriveWiring], list[str]]:
    """Resolve every joint's drive; also return every reason the params cannot work (empty when they can)."""
    problems = coverage_problems("drive", "drives", params.drives, joints)
    wiring: list[DriveWiring] = []
    seen: dict[int, str] = {}
    for joint in joints:
        drive = params.drives.get(joint)
        if drive is None:
            continue
        if drive.node_id in seen:
            problems.append(f"{joint}: node id {drive.node_id} is also used by {seen[drive.node_id]}")
            continue
        seen[drive.node_id] = joint
        path = dictionary_path(params, drive, config_dir)
        try:
            od = load_dictionary(path, drive.node_id)
        except (OSError, ValueError, KeyError) as exc:
            problems.append(f"{joint}: cannot read the EDS/DCF {path}: {exc}")
            continue
        mode = mode_of(params, joint)
        supported = _default(od, 0x6502)
        if supported is not None and not int(supported) & SUPPORTED_MODE_BITS[mode]:
            problems.append(f"{joint}: the drive's EDS ({path.name}) does not list {mode} in 0x6502 supported modes")
        if drive.homing is not None and supported is not None and not int(supported) & HOMING_BIT:
            problems.append(f"{joint}: homing is configured but the drive's EDS ({path.name}) lists no homing mode")
        counts = drive.counts_per_rev or counts_per_rev_from(od)
        if counts is None:
            problems.append(f"{joint}: give counts_per_rev (the EDS {path.name} has no 0x608F encoder resolution)")
            continue
        rated = drive.rated_torque
        if rated is None:
            milli = _default(od, MOTOR_RATED_TORQUE)
            rated = milli / 1000.0 if milli else None
        if rated is None:
            problems.append(f"{joint}: give rated_torque (the EDS {path.name} has no 0x6076 motor rated torque)")
            continue
        counts_per_rad = counts / TAU
        wiring.append(
            DriveWiring(
                joint=joint,
                node_id=drive.node_id,
                mode=mode,
                eds=path,
                counts_per_rad=counts_per_rad,
                velocity_per_rad_s=counts_per_rad * drive.velocity_factor,
                rated_torque=rated,
                params=drive,
            )
        )
    return wiring, problems
