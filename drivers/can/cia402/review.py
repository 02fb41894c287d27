"""What ``hild check`` says about a ``cia402`` section, before anything is opened: errors, warnings, the bus budget.

``review`` needs only the params; ``review_files`` reads the drives' EDS/DCF (mappable objects, supported modes,
the scaling the wiring resolves); ``bus_usage`` is the layout's frames at the cycle rate. The constructor of the
driver refuses the same errors (``static_problems`` + the wiring's), so a config that passes ``check`` starts.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from drivers.can.bus import bits_per_second, frame_bits
from drivers.can.cia402 import pdo
from drivers.can.cia402.pdo import Layout, layout_for
from drivers.can.cia402.wiring import DriveWiring, load_dictionary, mode_of, wire_drives
from drivers.can.component import coverage_problems
from drivers.can.params import Cia402Params
from hild.hardware import BusUsage, Finding

__all__ = [
    "EMCY_BASE",
    "HEARTBEAT_BASE",
    "SDO_REQUEST_BASE",
    "SDO_RESPONSE_BASE",
    "bus_usage",
    "interpolation_period",
    "mappable",
    "review",
    "review_files",
    "static_problems",
]

HEARTBEAT_BASE = 0x700
EMCY_BASE = 0x80
SDO_RESPONSE_BASE = 0x580
SDO_REQUEST_BASE = 0x600

# Thresholds of the resolution warnings (at the actuator): a command step coarser than this is noticeable.
POSITION_STEP_LIMIT = 1e-4  # rad: one position unit above 0.1 mrad
VELOCITY_STEP_LIMIT = 1e-3  # rad/s: one velocity unit above 1 mrad/s
TORQUE_STEP_LIMIT = 0.05  # N·m: one per mille of rated torque above 50 mN·m (rated torque above 50 N·m)


def interpolation_period(period: float) -> tuple[int, int] | None:
    """0x60C2 (value, exponent) with value × 10^exponent = `period` s, value 1..255; None when none is exact."""
    for exponent in range(0, -7, -1):
        value = period / 10.0**exponent
        if 1 <= round(value) <= 255 and abs(value - round(value)) <= 1e-6 * value:
            return round(value), exponent
    return None


def mappable(w: DriveWiring) -> Callable[[int], bool]:
    """Index → the drive's EDS lets it be mapped into a PDO."""
    od = load_dictionary(w.eds, w.node_id)
    return lambda index: index in od and bool(getattr(od[index], "pdo_mappable", False))


def static_problems(params: Cia402Params, joints: Sequence[str]) -> list[str]:
    """The errors that need no file: joints and drives that do not match, node ids twice, an EMCY id on SYNC's,
    a heartbeat timeout not above its period."""
    problems = coverage_problems("drive", "drives", params.drives, joints)
    seen: dict[int, str] = {}
    for joint, drive in params.drives.items():
        if drive.node_id in seen:
            problems.append(f"{joint}: node id {drive.node_id} is also used by {seen[drive.node_id]}")
        seen.setdefault(drive.node_id, joint)
        if EMCY_BASE + drive.node_id == params.sync_id:
            problems.append(f"{joint}: node {drive.node_id}'s EMCY id {EMCY_BASE + drive.node_id:#x} is the SYNC id")
    if params.heartbeat_ms and params.heartbeat_timeout * 1000.0 <= params.heartbeat_ms:
        problems.append(
            f"heartbeat_timeout_ms {params.heartbeat_timeout * 1000.0:g} must exceed heartbeat_ms {params.heartbeat_ms}"
        )
    return problems


def review(params: Cia402Params, joints: Sequence[str], update_rate: float) -> list[Finding]:
    """What needs no file: the static errors; heartbeat, interpolation-period and layout notes."""
    findings = [Finding("error", p) for p in static_problems(params, joints)]
    if params.heartbeat_ms == 0:
        findings.append(Finding("warning", "heartbeat_ms 0: a silent drive is noticed only by its missing TPDOs"))
    elif params.heartbeat_timeout > 0.5:
        findings.append(
            Finding("warning", f"heartbeat timeout {params.heartbeat_timeout:g} s: a dead node is noticed late")
        )
    if interpolation_period(1.0 / update_rate) is None:
        findings.append(
            Finding(
                "warning",
                f"0x60C2 interpolation period cannot express the cycle period {1000.0 / update_rate:.6g} ms "
                "exactly (value 1..255 × 10^n s): the drives interpolate with a rounded period",
            )
        )
    if params.bus.fd and params.velocity_feedback == "derived":
        findings.append(Finding("info", "bus.fd: velocity (0x606C) and error code (0x603F) travel in the one FD TPDO"))
    if not params.bus.fd and params.velocity_feedback == "pdo":
        findings.append(Finding("info", "velocity_feedback: pdo on classic CAN: a second TPDO per drive and cycle"))
    return findings


def review_files(params: Cia402Params, joints: Sequence[str], config_dir: Path) -> list[Finding]:
    """What needs the EDS: wiring problems, objects the drive cannot map, and scales coarser than a joint needs."""
    wiring, problems = wire_drives(params, joints, config_dir)
    reviewed = set(static_problems(params, joints))  # `review` reports those already
    findings = [Finding("error", p) for p in problems if p not in reviewed]
    for w in wiring:
        findings += _layout_findings(w, layout_for(w.mode, params.velocity_feedback, params.bus.fd))
        findings += _resolution_findings(w)
    return findings


def _layout_findings(w: DriveWiring, full: Layout) -> list[Finding]:
    can_map = mappable(w)
    findings = []
    for entry in full.entries():
        if can_map(entry.index):
            continue
        if entry in pdo.OPTIONAL:
            what = "effort (the torque offset) is not applied" if entry == pdo.TORQUE_OFFSET else "not read"
            findings.append(Finding("warning", f"{w.joint}: the EDS does not let {entry.index:#06x} be mapped: {what}"))
        else:
            findings.append(
                Finding("error", f"{w.joint}: the EDS does not let {entry.index:#06x} be mapped into a PDO")
            )
    return findings


def _resolution_findings(w: DriveWiring) -> list[Finding]:
    findings = []
    step = 1.0 / w.counts_per_rad
    if w.mode == "csp" and step > POSITION_STEP_LIMIT:
        findings.append(
            Finding(
                "warning",
                f"{w.joint}: one position unit is {step * 1000:.3g} mrad at the actuator (coarser than "
                f"{POSITION_STEP_LIMIT * 1000:g} mrad): raise counts_per_rev if the drive has the resolution",
            )
        )
    vstep = 1.0 / w.velocity_per_rad_s
    if w.mode == "csv" and vstep > VELOCITY_STEP_LIMIT:
        findings.append(
            Finding(
                "warning",
                f"{w.joint}: one velocity unit is {vstep * 1000:.3g} mrad/s (coarser than "
                f"{VELOCITY_STEP_LIMIT * 1000:g} mrad/s): lower velocity_factor's unit if the drive allows",
            )
        )
    tstep = w.rated_torque / 1000.0
    if tstep > TORQUE_STEP_LIMIT:
        findings.append(
            Finding(
                "warning",
                f"{w.joint}: one per mille of rated torque is {tstep * 1000:.3g} mN·m (coarser than "
                f"{TORQUE_STEP_LIMIT * 1000:g} mN·m): torque commands move in steps of that size",
            )
        )
    return findings


def bus_usage(params: Cia402Params, update_rate: float) -> list[BusUsage]:
    """Every PDO of the layout at the cycle rate, SYNC (produced or not, it is on the bus), heartbeats; and every id
    the component uses (PDOs, SYNC, EMCY, heartbeat, SDO), so overlaps with other components are refused."""
    frames: list[tuple[int, float]] = []
    ids: set[int] = set()
    for joint, drive in params.drives.items():
        layout = layout_for(mode_of(params, joint), params.velocity_feedback, params.bus.fd)
        node = drive.node_id
        frames.extend((size, update_rate) for size in layout.frame_sizes())
        ids.add(pdo.rpdo_cob_id(layout.rpdo.number, node))
        ids.update(pdo.tpdo_cob_id(p.number, node) for p in layout.tpdos)
        ids.update({EMCY_BASE + node, HEARTBEAT_BASE + node, SDO_REQUEST_BASE + node, SDO_RESPONSE_BASE + node})
    bps = bits_per_second(params.bus, frames)
    bps += update_rate * frame_bits(0)  # SYNC: a classic frame without counter, also on an FD bus
    if params.heartbeat_ms:  # classic 1-byte frames
        bps += len(params.drives) * 1000.0 / params.heartbeat_ms * frame_bits(1)
    ids.add(params.sync_id)
    return [BusUsage(params.bus.name, bps, float(params.bus.bitrate), frozenset(ids))]
