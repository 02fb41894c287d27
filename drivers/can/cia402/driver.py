"""``cia402``: CANopen drives with the CiA 402 profile in a cyclic synchronous mode (CSP, CSV, CST).

Lifecycle (may block briefly; everything by ``canopen``'s SDO client through this component's bus link, see
``sdo.py``): ``on_configure`` opens the bus, resets communication and waits for every node's boot-up or heartbeat,
then configures each drive by SDO (0x6060 mode, the PDO layout of ``pdo.py``, 0x60C2 interpolation period, 0x1006
when hild produces SYNC, 0x6065/0x6066/0x6072/0x605A when configured, homing objects, 0x1017 heartbeat), reads the
statusword and position so the first ``read`` is real, and starts the nodes (NMT operational). ``on_activate``
walks every drive to Operation Enabled aimed at its actual position, confirmed from the statusword.

Cycle: ``write`` packs one preallocated RPDO per drive in place (controlword + the mode's target + torque offset)
and sends SYNC after them (``sync: produce``); ``read`` takes the TPDOs the SYNC triggered, with precompiled
structs. A drive whose TPDO did not come for this cycle's SYNC, or whose heartbeat stopped, is not fresh. Faults:
the statusword's FAULT state, a drive that left Operation Enabled while it should be in it, CSP following error,
a node that left NMT operational (rebooted), and EMCY/0x603F error codes by their standard names
(``errors.py``). FAULT and QUICK STOP ACTIVE are never left automatically: ``clear_faults`` sends the fault-reset
edge and waits for the statusword; only ``enable`` (an operator command) walks a drive back to Operation Enabled.

In CSP and CSV the drive runs its own loops (its joints' ``gains_applied`` are False) and ``COMMAND_FIELDS`` says
what the mode applies (CSP: position + effort as 0x60B2 torque offset; CSV: velocity + effort). In CST this driver
applies the whole servo command on the torque path: kp·(p − q) + kd·(v − q̇) + effort from the latest SYNC sample,
at the cycle rate.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import can
import canopen
from canopen.nmt import NMT_STATES
from canopen.sdo.constants import EXPEDITED, REQUEST_DOWNLOAD, RESPONSE_ABORTED, RESPONSE_DOWNLOAD, SIZE_SPECIFIED

from drivers.can.cia402 import pdo, review, state
from drivers.can.cia402.errors import describe_error_code, emcy_code
from drivers.can.cia402.pdo import Layout, layout_for
from drivers.can.cia402.review import EMCY_BASE, HEARTBEAT_BASE, SDO_REQUEST_BASE, SDO_RESPONSE_BASE
from drivers.can.cia402.sdo import LinkNetwork, run_transfers
from drivers.can.cia402.wiring import MODE_CODES, DriveWiring, load_dictionary, mode_of, wire_drives
from drivers.can.component import CanComponent
from drivers.can.params import Cia402Params
from hild.arrays import JointState, ServoCommand
from hild.config.params import Params
from hild.hardware import BusUsage, Finding, HardwareContext, HardwareError, Homing

__all__ = [
    "FAULT_FOLLOWING_ERROR",
    "FAULT_NMT",
    "FAULT_NOT_ENABLED",
    "FAULT_STATE",
    "MODE_FIELDS",
    "Cia402Driver",
]

# ---- per-joint fault codes -------------------------------------------------------------------------------------
_ERROR_CODE_MASK = 0xFFFF  # bits 0–15: the drive's error code (EMCY or 0x603F)
FAULT_STATE = 1 << 16
"""The statusword shows FAULT or FAULT REACTION ACTIVE."""
FAULT_NOT_ENABLED = 1 << 17
"""The drive is not in Operation Enabled although it should be; bits 24–27 carry the state it shows."""
FAULT_FOLLOWING_ERROR = 1 << 18
"""CSP: statusword bit 13, the drive's own following-error window exceeded."""
FAULT_NMT = 1 << 19
"""The heartbeat says the node left NMT operational (rebooted, stopped, pre-operational); bits 32–39: its state."""
_STATE_SHIFT = 24
_NMT_SHIFT = 32

MODE_FIELDS: dict[str, frozenset[str]] = {
    "csp": frozenset({"position", "effort"}),
    "csv": frozenset({"velocity", "effort"}),
    "cst": frozenset({"position", "velocity", "effort", "kp", "kd"}),
}
"""The servo-command fields each cyclic synchronous mode applies (effort: 0x60B2 torque offset). CST applies the
whole servo law, hild-side at the cycle rate: the target torque is kp·(p − q) + kd·(v − q̇) + effort on the
drive's latest SYNC sample, so hold and position controllers work on a torque-mode drive (one cycle late, so
with a cycle-rate bandwidth: docs/drivers.md, "cia402")."""

SW_TARGET_REACHED = 1 << 10
SW_HOMING_ATTAINED = 1 << 12
SW_FOLLOWING_ERROR = 1 << 13  # CSP; in homing mode: homing error
SW_HOMING_ERROR = 1 << 13
NMT_OPERATIONAL = 0x05
NMT_BOOT_UP = 0x00
NMT_RESET_COMMUNICATION = 0x82
NMT_START = 0x01
HOMING_MODE = 6
RESET_EDGE_TIME = 0.002  # s each controlword level of the fault-reset edge is held (a 1 ms drive loop sees both)
RESET_CONFIRM_TIME = 0.4  # s the statusword has to leave FAULT after the edge (within the engine's 0.5 s)
MIN_LIFECYCLE_WAIT = 0.05  # s: a walk through the state machine needs several SYNC exchanges
INT32 = (-(2**31), 2**31 - 1)
INT16 = (-32768, 32767)
_SDO_6060 = struct.Struct("<BHBb3x")
_SDO_REPLY = struct.Struct("<BHB")
_SDO_DOWNLOAD_1 = REQUEST_DOWNLOAD | EXPEDITED | SIZE_SPECIFIED | (3 << 2)  # 0x2F: expedited, 1 byte
_SDO_ABORT_CODE = struct.Struct("<I")
_VELOCITY_UNPACK = pdo.Pdo(2, (pdo.VELOCITY_ACTUAL,)).layout.unpack_from

_OPERATE = state.HOLD_CW[state.OPERATION_ENABLED]
# Homing phases of one drive.
_IDLE, _MODE_REQUESTED, _RUNNING, _RETURNING = range(4)


class _IntegerRange:
    """A command value checked against its object's integer range before packing: clamped, never wrapped.

    Reported once when an episode of clamping starts and once when it ends (events on change only)."""

    def __init__(self, emit: Callable[[str, str], None], joints: Sequence[str], field: str, limits: tuple[int, int]):
        self.emit = emit
        self.joints = list(joints)
        self.field = field
        self.lo, self.hi = limits
        self.clamped = [0] * len(joints)
        self._active = [False] * len(joints)

    def __call__(self, k: int, value: float, fallback: int) -> int:
        lo, hi = self.lo, self.hi
        if lo <= value <= hi:  # NaN fails
            if self._active[k]:
                self._active[k] = False
                self.emit("info", f"{self.joints[k]}: {self.field} back inside its range")
            return round(value)
        clamped = hi if value > hi else lo if value < lo else fallback
        self.clamped[k] += 1
        if not self._active[k]:
            self._active[k] = True
            self.emit("warning", f"{self.joints[k]}: {self.field} {value:.6g} outside [{lo}, {hi}]: sent as {clamped}")
        return clamped


def _problems(params: Cia402Params, joints: Sequence[str], config_dir: Path) -> tuple[list[DriveWiring], list[str]]:
    """Every reason the params cannot work (what ``hild check`` reports as errors), with the wiring."""
    wiring, problems = wire_drives(params, joints, config_dir)
    return wiring, problems + [p for p in review.static_problems(params, joints) if p not in problems]


class Cia402Driver(CanComponent):
    """CiA 402 drives on one CANopen bus, in CSP, CSV or CST; the drive applies its own gains."""

    Params = Cia402Params
    COMMAND_FIELDS = frozenset({"position", "velocity", "effort"})  # the union; each drive applies its mode's
    APPLIES_GAINS = False  # CSP/CSV run the drive's own loops: hild's kp/kd never reach it (CST: gains_applied)

    # ---- config review (class level: drivers/can/cia402/review.py) ---------------------------------------------
    @classmethod
    def command_fields(cls, params: Params, joints: Sequence[str]) -> dict[str, frozenset[str]]:
        assert isinstance(params, Cia402Params)
        return {j: MODE_FIELDS[mode_of(params, j)] for j in joints}

    @classmethod
    def holds_at_stop(cls, params: Params) -> bool:
        """Drives left holding (``on_deactivate: hold``), or motors whose brakes the drives apply on disable."""
        assert isinstance(params, Cia402Params)
        return params.on_deactivate == "hold" or params.brakes

    @classmethod
    def files(cls, params: Params) -> dict[str, str]:
        assert isinstance(params, Cia402Params)
        named = {"eds": params.eds}
        named.update({f"drives.{j}.eds": d.eds for j, d in params.drives.items() if d.eds})
        return named

    @classmethod
    def review(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[Finding]:
        assert isinstance(params, Cia402Params)
        return review.review(params, joints, update_rate)

    @classmethod
    def review_files(cls, params: Params, joints: Sequence[str], update_rate: float, config_dir: Path) -> list[Finding]:
        assert isinstance(params, Cia402Params)
        return review.review_files(params, joints, config_dir)

    @classmethod
    def bus_usage(cls, params: Params, joints: Sequence[str], update_rate: float) -> list[BusUsage]:
        assert isinstance(params, Cia402Params)
        return review.bus_usage(params, update_rate)

    # ---- construction --------------------------------------------------------------------------------------
    def __init__(self, context: HardwareContext, params: Cia402Params) -> None:
        wiring, problems = _problems(params, context.joints, context.config_dir)
        if problems:
            raise HardwareError(f"{context.name}: " + "; ".join(problems))
        super().__init__(context, params, len(context.joints))
        self.params: Cia402Params = params
        self.wiring = wiring
        self.nodes = [w.node_id for w in wiring]
        n = len(wiring)
        self.modes = [w.mode for w in wiring]
        self.layouts = [layout_for(w.mode, params.velocity_feedback, params.bus.fd, review.mappable(w)) for w in wiring]
        fields: frozenset[str] = frozenset().union(
            *(
                MODE_FIELDS[m] if m == "cst" or layout.has_torque_offset else MODE_FIELDS[m] - {"effort"}
                for m, layout in zip(self.modes, self.layouts, strict=True)
            )
        )
        self.COMMAND_FIELDS = fields  # type: ignore[misc]  # what this instance's drives apply
        self._produce_sync = params.sync == "produce"
        self._period = context.period
        self._heartbeat_timeout = params.heartbeat_timeout
        # Feedback, per drive, as plain lists (cheap single-element updates; read copies them once per cycle).
        self.statusword = [0] * n
        self.position_counts = [0] * n
        self.torque_permille = [0] * n
        self.velocity_units = [0] * n
        self.error_code = [0] * n  # 0x603F when mapped
        self.emcy = [0] * n  # latched last EMCY error code (0: none or reset by the drive)
        self.nmt_state = [-1] * n  # from the heartbeat; -1 unknown
        self.tpdos = [0] * n  # TPDO1 count
        self.heartbeats = [0] * n
        self.boot_ups = [0] * n
        self.position = [0.0] * n
        self.velocity = [0.0] * n
        self.effort = [0.0] * n
        self._heartbeat_age = [0.0] * n
        self._new = [False] * n  # TPDO1 since the last read
        self._new_velocity = [False] * n  # TPDO2 since the last read (velocity_feedback: pdo)
        self._needs_velocity_pdo = [len(layout.tpdos) > 1 for layout in self.layouts]
        self._prev_counts = [0] * n
        self._have_prev = [False] * n
        self._sync_mark = [0] * n  # SYNCs sent when the previous TPDO arrived
        self._since_tpdo = [0.0] * n  # seconds since the previous TPDO (external SYNC)
        self._fresh = [False] * n
        self._fault = [0] * n
        self.syncs = 0
        # What the drives are told.
        self.expect_enabled = [False] * n
        self.expect_operational = [False] * n
        self._walking = [False] * n  # activate / enable: step toward Operation Enabled
        self._walk_elapsed = [0.0] * n  # enable (in the cycle): given up after the lifecycle wait
        self._disabling = [False] * n  # deactivate: disable voltage
        self._reset_cycles = [-1] * n  # fault reset: cycles since it began (-1: none)
        self._reset_code = [0] * n
        self._persistent: dict[int, str] = {}
        self._edge_cycles = max(1, math.ceil(RESET_EDGE_TIME / context.period - 1e-9))
        self._reset_limit = self._edge_cycles * 2 + max(1, math.ceil(RESET_CONFIRM_TIME / context.period))
        # Homing.
        self._homing_phase = [_IDLE] * n
        self._homing_cycles = [0] * n
        self._homing_elapsed = [0.0] * n
        self._homing_result: list[tuple[Homing, str] | None] = [None] * n  # the end, reported once
        self._homing_outcome: list[tuple[Homing, str] | None] = [None] * n  # the end, until cyclic again
        self._sdo_requests = [self._sdo_request(node, HOMING_MODE) for node in self.nodes]
        self._sdo_returns = [
            self._sdo_request(node, MODE_CODES[m]) for node, m in zip(self.nodes, self.modes, strict=True)
        ]
        # Frames, packed in place by write.
        self._rpdo = [
            self.link.make_message(pdo.rpdo_cob_id(layout.rpdo.number, node), bytes(layout.frame_sizes()[0]))
            for node, layout in zip(self.nodes, self.layouts, strict=True)
        ]
        self._pack = [layout.rpdo.layout.pack_into for layout in self.layouts]
        self._has_offset = [layout.has_torque_offset for layout in self.layouts]
        self._sync = can.Message(arbitration_id=params.sync_id, data=b"", is_extended_id=False)  # classic
        self._counts_per_rad = [w.counts_per_rad for w in wiring]
        self._velocity_per_rad_s = [w.velocity_per_rad_s for w in wiring]
        self._permille_per_nm = [w.permille_per_nm for w in wiring]
        joints = list(context.joints)
        emit = context.emit_event
        self._target_range = [
            _IntegerRange(emit, joints, f"{pdo.TARGETS[m].index:#06x} target", INT16 if m == "cst" else INT32)
            for m in self.modes
        ]
        self._offset_range = _IntegerRange(emit, joints, "0x60B2 torque offset", INT16)
        # Receive routing: COB-ID → (kind, drive).
        self._tpdo1 = {pdo.tpdo_cob_id(1, node): k for k, node in enumerate(self.nodes)}
        self._tpdo1_unpack = [layout.tpdos[0].layout.unpack_from for layout in self.layouts]
        self._tpdo1_size = [layout.tpdos[0].size for layout in self.layouts]
        self._tpdo2 = {
            pdo.tpdo_cob_id(2, node): k
            for k, node, layout in zip(range(n), self.nodes, self.layouts, strict=True)
            if len(layout.tpdos) > 1
        }
        self._fd_feedback = params.bus.fd
        self._heartbeat_ids = {HEARTBEAT_BASE + node: k for k, node in enumerate(self.nodes)}
        self._emcy_ids = {EMCY_BASE + node: k for k, node in enumerate(self.nodes)}
        self._sdo_ids = {SDO_RESPONSE_BASE + node: k for k, node in enumerate(self.nodes)}
        self._rpdo_ids = frozenset(msg.arbitration_id for msg in self._rpdo)
        self.network: LinkNetwork | None = None

    def _sdo_request(self, node: int, mode: int) -> can.Message:
        """A non-blocking expedited SDO download of 0x6060 (mode of operation), sent from the cycle."""
        data = bytearray(8)
        _SDO_6060.pack_into(data, 0, _SDO_DOWNLOAD_1, 0x6060, 0, mode)
        return can.Message(arbitration_id=SDO_REQUEST_BASE + node, data=data, is_extended_id=False)

    @property
    def _wait(self) -> float:
        """A lifecycle wait spans a reply timeout and at least one heartbeat period and a few SYNC exchanges."""
        return max(self.params.reply_timeout_ms / 1000.0, self.params.heartbeat_ms / 1000.0 * 1.5, MIN_LIFECYCLE_WAIT)

    # ---- lifecycle -------------------------------------------------------------------------------------------
    def on_configure(self) -> None:
        """Open the bus, boot every node, configure it by SDO, read where it is, start it (nothing enabled)."""
        self.link.open()
        try:
            self.link.drain()
            self._boot()
            network = LinkNetwork(self.link)
            self.network = network
            for w in self.wiring:
                node = canopen.RemoteNode(w.node_id, load_dictionary(w.eds, w.node_id))
                node.sdo.RESPONSE_TIMEOUT = self.params.reply_timeout_ms / 1000.0
                node.sdo.MAX_RETRIES = 2
                network.add_node(node)
            transfers = len(self.wiring) * 60
            timeout = transfers * 2.0 * self.params.reply_timeout_ms / 1000.0 + 1.0
            readings = run_transfers(self.link, self._accept_configuring, self._configure_all, timeout)
            for k, (sw, counts) in enumerate(readings):
                self.statusword[k] = sw
                self.position_counts[k] = counts
                self.position[k] = counts / self._counts_per_rad[k]
                self._prev_counts[k] = counts
                self._have_prev[k] = True
            for node in self.nodes:
                self.link.send_wait(self.link.make_message(0x000, bytes((NMT_START, node))))
            n = len(self.nodes)
            self.expect_operational[:] = [True] * n
            self.nmt_state[:] = [-1] * n  # the boot-up seen above is not news: the next heartbeat says operational
            self._heartbeat_age[:] = [0.0] * n
            self._new[:] = [True] * n  # the SDO readings are real feedback: the first read is fresh
            for k, joint in enumerate(self.joints):
                if state.state_of(self.statusword[k]) in state.FAULTED:
                    self.context.emit_event(
                        "error", f"{joint}: drive in FAULT at start-up{self._words(k)}: reset, then enable it"
                    )
        except BaseException:
            self.network = None
            self.link.close()
            raise

    def _boot(self) -> None:
        """NMT reset communication to every node; wait for each boot-up (or a heartbeat); name the silent ones."""
        before_boot, before_hb = list(self.boot_ups), list(self.heartbeats)
        for node in self.nodes:
            self.link.send_wait(self.link.make_message(0x000, bytes((NMT_RESET_COMMUNICATION, node))))

        def heard(k: int) -> bool:
            return self.boot_ups[k] > before_boot[k] or self.heartbeats[k] > before_hb[k]

        ok = self.link.collect(self._accept, lambda: all(heard(k) for k in range(len(self.nodes))), self._wait)
        if not ok:
            silent = [f"{self.joints[k]} (node {self.nodes[k]})" for k in range(len(self.nodes)) if not heard(k)]
            raise HardwareError(
                f"CANopen nodes sent no boot-up or heartbeat on {self.params.bus.name}: {', '.join(silent)}"
            )

    def _accept_configuring(self, msg: can.Message) -> None:
        if msg.arbitration_id in self._sdo_ids and self.network is not None:
            self.network.feed(msg)
        else:
            self._accept(msg)

    def _configure_all(self) -> list[tuple[int, int]]:
        """Worker thread: every drive's SDO configuration; returns (statusword, position actual) per drive."""
        assert self.network is not None
        readings = []
        for w, layout in zip(self.wiring, self.layouts, strict=True):
            node = self.network[w.node_id]
            try:
                readings.append(self._configure_drive(node, w, layout))
            except (canopen.SdoAbortedError, canopen.SdoCommunicationError, KeyError) as exc:
                raise HardwareError(f"{w.joint} (node {w.node_id}): SDO configuration failed: {exc}") from exc
        return readings

    def _configure_drive(self, node: canopen.RemoteNode, w: DriveWiring, layout: Layout) -> tuple[int, int]:
        sdo, od = node.sdo, node.object_dictionary
        p = w.params
        sdo[0x6060].raw = MODE_CODES[w.mode]
        self._map_pdos(node.rpdo, layout, w.node_id, receive=True)
        self._map_pdos(node.tpdo, layout, w.node_id, receive=False)
        ipp = review.interpolation_period(self._period)
        if ipp is not None and 0x60C2 in od:
            sdo[0x60C2][1].raw, sdo[0x60C2][2].raw = ipp
        if self._produce_sync and 0x1006 in od:
            sdo[0x1006].raw = round(self._period * 1e6)
        if p.following_error_window is not None:
            sdo[0x6065].raw = min(round(p.following_error_window * w.counts_per_rad), 0xFFFFFFFE)
        if p.following_error_timeout_ms is not None:
            sdo[0x6066].raw = p.following_error_timeout_ms
        if p.max_torque is not None:
            sdo[0x6072].raw = min(round(p.max_torque * w.permille_per_nm), 0xFFFF)
        if self.params.quick_stop_option is not None:
            sdo[0x605A].raw = self.params.quick_stop_option
        if p.homing is not None:
            h = p.homing
            sdo[0x6098].raw = h.method
            sdo[0x607C].raw = round(h.offset * w.counts_per_rad)
            if h.speed_switch is not None:
                sdo[0x6099][1].raw = round(h.speed_switch * w.velocity_per_rad_s)
            if h.speed_zero is not None:
                sdo[0x6099][2].raw = round(h.speed_zero * w.velocity_per_rad_s)
            if h.acceleration is not None and 0x609A in od:
                sdo[0x609A].raw = round(h.acceleration * w.velocity_per_rad_s)
        sdo[0x1017].raw = self.params.heartbeat_ms
        mode = sdo[0x6061].raw if 0x6061 in od else MODE_CODES[w.mode]
        if mode != MODE_CODES[w.mode]:
            raise HardwareError(f"{w.joint}: the drive shows mode {mode} in 0x6061 after 0x6060 = {MODE_CODES[w.mode]}")
        return int(sdo[0x6041].raw), int(sdo[0x6064].raw)

    @staticmethod
    def _map_pdos(maps: object, layout: Layout, node_id: int, *, receive: bool) -> None:
        """canopen's PdoMap.save: disable (COB-ID bit 31), write the mapping, transmission type 1, re-enable.
        Every PDO of the drive the layout does not use is disabled."""
        wanted = {p.number: p for p in ((layout.rpdo,) if receive else layout.tpdos)}
        for number in range(1, pdo.PDO_COUNT + 1):
            pdo_map = maps[number]  # type: ignore[index]
            pdo_map.clear()
            pdo_map.cob_id = (pdo.rpdo_cob_id if receive else pdo.tpdo_cob_id)(number, node_id)
            chosen = wanted.get(number)
            if chosen is None:
                pdo_map.enabled = False
            else:
                for entry in chosen.entries:
                    pdo_map.add_variable(entry.index, entry.subindex)
                pdo_map.trans_type = pdo.TRANSMISSION_SYNC
                pdo_map.enabled = True
            pdo_map.save()

    def on_activate(self) -> None:
        """Walk every drive to Operation Enabled aimed at its actual position, confirmed from the statusword."""
        n = len(self.nodes)
        targets = []
        for k, joint in enumerate(self.joints):
            s = state.state_of(self.statusword[k])
            if s in state.FAULTED or s == state.QUICK_STOP:
                self.context.emit_event(
                    "error",
                    f"{joint}: not enabled, drive in {state.STATE_NAMES[s]}{self._words(k)}: reset clears it, then "
                    "enable it explicitly",
                )
                self.expect_enabled[k] = True  # its fault shows until the operator enables it
                continue
            targets.append(k)
        self._disabling[:] = [False] * n
        for k in targets:
            self._walking[k] = True
        self._pump(lambda: not any(self._walking[k] for k in targets), self._wait)
        failed = [k for k in targets if self._walking[k]]
        for k in failed:
            self._walking[k] = False
        for k in range(n):
            self.expect_enabled[k] = True
        if failed:
            names = ", ".join(
                f"{self.joints[k]} (node {self.nodes[k]}: {state.STATE_NAMES[state.state_of(self.statusword[k])]}, "
                f"statusword {self.statusword[k]:#06x}{self._words(k)})"
                for k in failed
            )
            raise HardwareError(f"CiA 402 drives did not reach OPERATION ENABLED: {names}")

    def on_deactivate(self) -> None:
        for k in range(len(self.nodes)):
            if self._homing_phase[k] != _IDLE:
                self.stop_homing(self.joints[k])
        if not self._stopping_limp("drives left in OPERATION ENABLED at their last target"):
            return
        n = len(self.nodes)
        self.expect_enabled[:] = [False] * n
        self._walking[:] = [False] * n
        self._disabling[:] = [True] * n

        def disabled(k: int) -> bool:
            return state.state_of(self.statusword[k]) == state.SWITCH_ON_DISABLED

        try:
            self._pump(lambda: all(disabled(k) for k in range(n)), self._wait)
        except HardwareError as exc:  # the bus failed under us: say so, and which drives are not confirmed
            self.context.emit_event("error", f"disable voltage not sent to every drive: {exc}")
        failed = [k for k in range(n) if not disabled(k)]
        for k in failed:
            self.context.emit_event(
                "error",
                f"{self.joints[k]}: not confirmed SWITCH ON DISABLED after disable voltage, the drive shows "
                f"{state.STATE_NAMES[state.state_of(self.statusword[k])]} (statusword {self.statusword[k]:#06x})",
            )

    def on_cleanup(self) -> None:
        self.network = None
        super().on_cleanup()

    def _pump(self, done: Callable[[], bool], timeout: float) -> None:
        """Lifecycle exchange: the cycle's frames (held at the actual position) each period until `done()`."""
        deadline = time.monotonic() + timeout
        period = self._period
        while not done() and time.monotonic() < deadline:
            before = list(self.tpdos)
            self._send_held()
            self.link.collect(
                self._accept,
                lambda before=before: all(now > then for now, then in zip(self.tpdos, before, strict=True)),
                min(period, max(0.0, deadline - time.monotonic())),
            )
            self._update_flags()

    def _send_held(self) -> None:
        """RPDOs aimed at the actual position (CSV/CST: zero), then SYNC; outside the cycle."""
        for k in range(len(self.nodes)):
            self._pack_held(k, self._controlword(k))
            self.link.send_wait(self._rpdo[k])
        if self._produce_sync:
            self.link.send_wait(self._sync)
            self.syncs += 1

    def _pack_held(self, k: int, cw: int) -> None:
        target = self.position_counts[k] if self.modes[k] == "csp" else 0
        if self._has_offset[k]:
            self._pack[k](self._rpdo[k].data, 0, cw, target, 0)
        else:
            self._pack[k](self._rpdo[k].data, 0, cw, target)

    # ---- the state machine -------------------------------------------------------------------------------------
    def _controlword(self, k: int) -> int:
        s = state.state_of(self.statusword[k])
        if self._reset_cycles[k] >= 0:
            return state.CW_FAULT_RESET if self._reset_cycles[k] >= self._edge_cycles else state.DISABLED_CW
        if self._disabling[k]:
            return state.DISABLED_CW
        if self._walking[k]:
            return state.WALK_CW[s]
        cw = state.HOLD_CW[s]
        phase = self._homing_phase[k]
        if phase == _RUNNING and self._homing_cycles[k] > 0:
            cw |= state.CW_HOMING_START  # low for the first cycle in homing mode, then high: the rising edge
        elif phase == _RETURNING:
            cw |= state.CW_HALT
        return cw

    def _update_flags(self) -> None:
        """After new statuswords: walks that arrived, resets confirmed or given up, homing's progress."""
        for k in range(len(self.nodes)):
            s = state.state_of(self.statusword[k])
            if self._walking[k] and s == state.OPERATION_ENABLED:
                self._walking[k] = False
                self.expect_enabled[k] = True
            if self._reset_cycles[k] >= 0:
                self._reset_step(k, s)

    def _reset_step(self, k: int, s: int) -> None:
        cycles = self._reset_cycles[k] = self._reset_cycles[k] + 1
        if cycles > 2 * self._edge_cycles and s not in state.FAULTED:
            self._reset_cycles[k] = -1
            self.emcy[k] = 0
            self._persistent.pop(k, None)
        elif cycles >= self._reset_limit:
            self._reset_cycles[k] = -1
            self.emcy[k] = self.emcy[k] or self._reset_code[k]  # the fault keeps its name
            words = f"still in {state.STATE_NAMES[s]} after fault reset{self._words(k)}"
            self._persistent[k] = words
            self.context.emit_event("error", f"{self.joints[k]}: {words}")

    # ---- cycle -------------------------------------------------------------------------------------------------
    def read(self, t: float, dt: float, state_out: JointState) -> None:
        hb_age, since = self._heartbeat_age, self._since_tpdo
        for k in range(len(hb_age)):
            hb_age[k] += dt
            since[k] += dt
        self.drain(self._accept)
        produce, period, syncs = self._produce_sync, self._period, self.syncs
        new, new_velocity, needs_velocity = self._new, self._new_velocity, self._needs_velocity_pdo
        fresh, fault = self._fresh, self._fault
        hb_limit = self._heartbeat_timeout or math.inf
        position, velocity = self.position, self.velocity
        derived = not self._fd_feedback
        for k, counts in enumerate(self.position_counts):
            if new[k]:
                if self._homing_phase[k] != _IDLE and self.statusword[k] & SW_HOMING_ATTAINED:
                    velocity[k] = 0.0  # the drive set its home: the position jumped without moving
                    self._prev_counts[k] = counts
                elif derived and not needs_velocity[k]:
                    elapsed = (syncs - self._sync_mark[k]) * period if produce else since[k]
                    if self._have_prev[k] and elapsed > 0.0:
                        velocity[k] = (counts - self._prev_counts[k]) / self._counts_per_rad[k] / elapsed
                    self._prev_counts[k] = counts
                    self._have_prev[k] = True
                self._sync_mark[k] = syncs
                since[k] = 0.0
            fresh[k] = new[k] and (new_velocity[k] or not needs_velocity[k]) and hb_age[k] <= hb_limit
            fault[k] = self._fault_code(k)
            new[k] = new_velocity[k] = False
        self._update_flags()
        self._walk_step(dt)
        self._homing_step(dt)
        state_out.position[:] = position
        state_out.velocity[:] = velocity
        state_out.effort[:] = self.effort
        state_out.fresh[:] = fresh
        state_out.fault[:] = fault
        self.bad_frames.report(t)

    def _fault_code(self, k: int) -> int:
        sw = self.statusword[k]
        s = state.state_of(sw)
        code = self.error_code[k] or self.emcy[k]
        if s in state.FAULTED:
            code |= FAULT_STATE
        elif self.expect_enabled[k] and not self._walking[k] and s != state.OPERATION_ENABLED:
            code |= FAULT_NOT_ENABLED | s << _STATE_SHIFT
        if (
            self.modes[k] == "csp"
            and s == state.OPERATION_ENABLED
            and sw & SW_FOLLOWING_ERROR
            and self._homing_phase[k] == _IDLE
        ):
            code |= FAULT_FOLLOWING_ERROR
        nmt = self.nmt_state[k]
        if self.expect_operational[k] and nmt >= 0 and nmt != NMT_OPERATIONAL:
            code |= FAULT_NMT | nmt << _NMT_SHIFT
        return code

    def gains_applied(self) -> list[bool]:
        """CST joints get kp/kd applied (by this driver, on the torque path); CSP/CSV joints run the drive's own."""
        return [mode == "cst" for mode in self.modes]

    def write(self, t: float, dt: float, command: ServoCommand) -> None:
        send, rpdo, pack, has_offset = self.link.send, self._rpdo, self._pack, self._has_offset
        counts_per_rad, velocity_per_rad_s, permille = (
            self._counts_per_rad,
            self._velocity_per_rad_s,
            self._permille_per_nm,
        )
        ranges, offsets = self._target_range, self._offset_range
        position, velocity = self.position, self.velocity
        for k, (p, v, ff, kp, kd) in enumerate(
            zip(
                command.position.tolist(),
                command.velocity.tolist(),
                command.effort.tolist(),
                command.kp.tolist(),
                command.kd.tolist(),
                strict=True,
            )
        ):
            cw = self._controlword(k)
            mode = self.modes[k]
            actual = self.position_counts[k]
            if cw != _OPERATE or self._walking[k] or self._homing_phase[k] != _IDLE:  # not on hild's command
                self._pack_held(k, cw)
            else:
                if mode == "csp":
                    target = ranges[k](k, p * counts_per_rad[k], actual)
                elif mode == "csv":
                    target = ranges[k](k, v * velocity_per_rad_s[k], 0)
                else:  # CST: the servo law on the latest sample (a NaN anywhere gives no torque)
                    tau = ff + kp * (p - position[k]) + kd * (v - velocity[k])
                    target = ranges[k](k, tau * permille[k], 0)
                if has_offset[k]:
                    pack[k](rpdo[k].data, 0, cw, target, offsets(k, ff * permille[k], 0))
                else:
                    pack[k](rpdo[k].data, 0, cw, target)
            send(rpdo[k])
        if self._produce_sync:
            send(self._sync)
            self.syncs += 1
        self.link.end_cycle()

    def _accept(self, msg: can.Message) -> None:
        """A TPDO straight into the feedback lists; every other frame through `_accept_other`."""
        ident = msg.arbitration_id
        k = self._tpdo1.get(ident)
        data = msg.data
        if k is None or msg.is_extended_id or msg.is_remote_frame or len(data) < self._tpdo1_size[k]:
            self._accept_other(msg)
            return
        values = self._tpdo1_unpack[k](data)
        self.statusword[k] = values[0]
        self.position_counts[k] = values[1]
        self.position[k] = values[1] / self._counts_per_rad[k]
        self.torque_permille[k] = values[2]
        self.effort[k] = values[2] / self._permille_per_nm[k]
        if self._fd_feedback:
            self.velocity_units[k] = values[3]
            self.velocity[k] = values[3] / self._velocity_per_rad_s[k]
            self.error_code[k] = values[4]
        self.tpdos[k] += 1
        self._new[k] = True

    def _accept_other(self, msg: can.Message) -> None:
        ident, data = msg.arbitration_id, msg.data
        if msg.is_extended_id or msg.is_remote_frame:
            self.bad_frames.note("unexpected frame type", ident)
            return
        k = self._heartbeat_ids.get(ident)
        if k is not None:
            if len(data) != 1:
                self.bad_frames.note("wrong length", ident)
                return
            nmt = data[0] & 0x7F
            if nmt == NMT_BOOT_UP:
                self.boot_ups[k] += 1
            else:
                self.heartbeats[k] += 1
            self.nmt_state[k] = nmt
            self._heartbeat_age[k] = 0.0
            return
        k = self._emcy_ids.get(ident)
        if k is not None:
            try:
                code, _register = emcy_code(data)
            except struct.error:
                self.bad_frames.note("wrong length", ident)
                return
            if code == 0 or self.emcy[k] == 0:  # 0: the drive's error reset; otherwise the first code names it
                self.emcy[k] = code
            return
        k = self._tpdo2.get(ident)
        if k is not None:
            if len(data) < 4:
                self.bad_frames.note("wrong length", ident)
                return
            (units,) = _VELOCITY_UNPACK(data)
            self.velocity_units[k] = units
            self.velocity[k] = units / self._velocity_per_rad_s[k]
            self._new_velocity[k] = True
            return
        k = self._sdo_ids.get(ident)
        if k is not None:
            self._sdo_reply(k, data)
            return
        if ident in self._tpdo1:
            self.bad_frames.note("wrong length", ident)
        elif ident == self.params.sync_id or ident in self._rpdo_ids or ident == 0 or ident & 0x780 == 0x600:
            return  # SYNC, NMT, RPDOs and SDO requests of another master
        else:
            self.bad_frames.note("unknown id", ident)

    def _walk_step(self, dt: float) -> None:
        """An ``enable`` walk that did not arrive within the lifecycle wait ends: the fault then says where it is."""
        for k, walking in enumerate(self._walking):
            if walking:
                self._walk_elapsed[k] += dt
                if self._walk_elapsed[k] > self._wait:
                    self._walking[k] = False
                    self.context.emit_event(
                        "error",
                        f"{self.joints[k]}: enable not confirmed, the drive shows "
                        f"{state.STATE_NAMES[state.state_of(self.statusword[k])]}{self._words(k)}",
                    )

    # ---- homing ----------------------------------------------------------------------------------------------------
    def _sdo_reply(self, k: int, data: bytearray) -> None:
        """An answer to the cycle's 0x6060 download (homing); others (a second master's) are not ours."""
        phase = self._homing_phase[k]
        if phase not in (_MODE_REQUESTED, _RETURNING) or len(data) < 8:
            return
        command, index, subindex = _SDO_REPLY.unpack_from(data)
        if index != 0x6060 or subindex != 0:
            return
        if command == RESPONSE_DOWNLOAD:
            if phase == _MODE_REQUESTED:
                self._homing_phase[k] = _RUNNING
                self._homing_cycles[k] = 0
            else:
                self._homing_ended(k, self._homing_outcome[k])
        elif command == RESPONSE_ABORTED:
            (abort,) = _SDO_ABORT_CODE.unpack_from(data, 4)
            if phase == _MODE_REQUESTED:
                self._finish_homing(k, Homing.FAILED, f"the drive refused homing mode (SDO abort {abort:#010x})")
            else:
                words = f"the drive refused its cyclic mode again (SDO abort {abort:#010x}): disable and reconfigure"
                self._homing_ended(k, (Homing.FAILED, words))

    def _homing_step(self, dt: float) -> None:
        for k, phase in enumerate(self._homing_phase):
            if phase == _IDLE:
                continue
            self._homing_elapsed[k] += dt
            homing = self.wiring[k].params.homing
            timeout = homing.timeout if homing is not None else 0.0
            if phase == _RUNNING:
                self._homing_cycles[k] += 1
                sw = self.statusword[k]
                if state.state_of(sw) != state.OPERATION_ENABLED:
                    self._finish_homing(k, Homing.FAILED, f"the drive left OPERATION ENABLED{self._words(k)}")
                elif self._homing_cycles[k] > 2 and sw & SW_HOMING_ERROR:
                    self._finish_homing(k, Homing.FAILED, "the drive reports a homing error (statusword bit 13)")
                elif self._homing_cycles[k] > 2 and sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED:
                    self._finish_homing(k, Homing.ATTAINED, "")
                elif self._homing_elapsed[k] > timeout:
                    self._finish_homing(k, Homing.FAILED, f"not attained within {timeout:g} s")
            elif phase == _MODE_REQUESTED and self._homing_elapsed[k] > self._wait:
                self._finish_homing(k, Homing.FAILED, "the drive did not answer the homing-mode request")
            elif phase == _RETURNING and self._homing_elapsed[k] > self._wait:
                _outcome, detail = self._homing_outcome[k] or (Homing.FAILED, "")
                words = f"the drive did not confirm its cyclic mode (0x6060) after homing{': ' if detail else ''}"
                self._homing_ended(k, (Homing.FAILED, words + detail))

    def _finish_homing(self, k: int, outcome: Homing, detail: str) -> None:
        """Back to the cyclic mode (0x6060 by SDO), halted and held at the actual position; the outcome is
        reported once the drive acknowledges the mode (the contract: cyclic again before the end is reported)."""
        self._homing_outcome[k] = (outcome, detail)
        self._homing_phase[k] = _RETURNING
        self._homing_elapsed[k] = 0.0
        self.link.send(self._sdo_returns[k])

    def _homing_ended(self, k: int, result: tuple[Homing, str] | None) -> None:
        self._homing_phase[k] = _IDLE
        self._homing_outcome[k] = None
        self._homing_result[k] = result or (Homing.FAILED, "")

    def start_homing(self, joint: str) -> None:
        (k,) = self._joint_indices(joint)
        if self.wiring[k].params.homing is None:
            raise HardwareError(f"{joint}: no homing configured (drives.{joint}.homing)")
        if self._homing_phase[k] != _IDLE:
            raise HardwareError(f"{joint}: homing already running")
        s = state.state_of(self.statusword[k])
        if s != state.OPERATION_ENABLED:
            raise HardwareError(f"{joint}: the drive is in {state.STATE_NAMES[s]}, not OPERATION ENABLED")
        self._homing_result[k] = None
        self._homing_elapsed[k] = 0.0
        self._homing_phase[k] = _MODE_REQUESTED
        if not self.link.send(self._sdo_requests[k]):
            self._homing_phase[k] = _IDLE
            raise HardwareError(f"{joint}: homing-mode request not sent ({self.link.problem or 'send queue full'})")

    def stop_homing(self, joint: str) -> None:
        (k,) = self._joint_indices(joint)
        if self._homing_phase[k] in (_MODE_REQUESTED, _RUNNING):
            # Halt (bit 8) goes with the held frame of the next write; the mode returns to cyclic.
            self._finish_homing(k, Homing.FAILED, "stopped")

    def homing(self, joint: str) -> tuple[Homing, str]:
        k = self.joints.index(joint)
        result = self._homing_result[k]
        if result is not None:
            self._homing_result[k] = None
            return result
        if self._homing_phase[k] != _IDLE:
            return Homing.RUNNING, ""
        return Homing.IDLE, ""

    # ---- reporting and operator commands ------------------------------------------------------------------------
    def _words(self, k: int) -> str:
        code = self.error_code[k] or self.emcy[k]
        return f", {describe_error_code(code)}" if code else ""

    def describe_fault(self, code: int) -> str:
        parts = []
        error = code & _ERROR_CODE_MASK
        if error:
            parts.append(describe_error_code(error))
        if code & FAULT_STATE:
            parts.append("drive in FAULT (reset sends fault reset; enable it explicitly afterwards)")
        if code & FAULT_NOT_ENABLED:
            s = (code >> _STATE_SHIFT) & 0xF
            name = state.STATE_NAMES[s] if s < len(state.STATE_NAMES) else f"state {s}"
            parts.append(f"drive in {name}, not OPERATION ENABLED; it is not re-enabled automatically: enable it")
        if code & FAULT_FOLLOWING_ERROR:
            parts.append("following error (statusword bit 13: the drive's 0x6065 window exceeded)")
        if code & FAULT_NMT:
            nmt = (code >> _NMT_SHIFT) & 0xFF
            parts.append(f"node left NMT OPERATIONAL: {NMT_STATES.get(nmt, f'state {nmt:#x}')} (rebooted?)")
        return "; ".join(parts) or "no fault"

    def clear_faults(self) -> None:
        """Operator reset: recover the bus; the fault-reset edge (0 then 0x80, each held ≥ 2 ms) to every drive in
        FAULT, confirmed from its statusword (``confirming``); latched EMCY codes cleared. Never re-enables."""
        self.recover_bus(self._accept)
        for k in range(len(self.nodes)):
            code, self.emcy[k] = self.emcy[k], 0
            if state.state_of(self.statusword[k]) in state.FAULTED:
                self._reset_code[k] = code
                self._reset_cycles[k] = 0
            else:
                self._persistent.pop(k, None)

    def confirming(self) -> bool:
        return any(c >= 0 for c in self._reset_cycles)

    def persistent_errors(self) -> dict[str, str]:
        return {self.joints[k]: words for k, words in self._persistent.items()}

    def enable(self, joint: str | None = None) -> list[str]:
        """Operator command: walk one drive (or all) to OPERATION ENABLED, holding where it is; the cycle's
        statuswords confirm it. A drive still in FAULT needs a reset first."""
        targets = self._joint_indices(joint)
        faulted = [self.joints[k] for k in targets if state.state_of(self.statusword[k]) in state.FAULTED]
        if faulted:
            raise HardwareError(f"drives {faulted} are in FAULT: reset first (it sends fault reset)")
        for k in targets:
            self._disabling[k] = False
            self._walking[k] = True
            self._walk_elapsed[k] = 0.0
            self.expect_enabled[k] = True
        return [self.joints[k] for k in targets]

    @property
    def statistics(self) -> dict[str, int]:
        return {
            **super().statistics,
            "syncs": self.syncs,
            "clamped": sum(r.clamped[k] for k, r in enumerate(self._target_range)),
        }
