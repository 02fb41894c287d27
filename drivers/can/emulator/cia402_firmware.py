"""Emulated CiA 402 servo drive on CANopen (CiA 301), built from the same EDS and wiring as the host driver.

The object dictionary and the SDO server are `canopen`'s `LocalNode` (so uploads, downloads, segmented transfers
and abort codes are the library's); live objects (statusword, actual values, targets, controlword, error state)
are read from and written into this drive's state through the node's callbacks. Everything `LocalNode` does not
do the way a drive does is here: the NMT slave, the heartbeat producer, SYNC-driven PDOs honouring their SDO
configuration, EMCY, and the CiA 402 state machine with its modes.

Behaviour:

* NMT: boot-up (0x700+n, [0]) on power-up, reboot and reset; start / stop / pre-operational / reset node (the
  OD back to EDS defaults) / reset communication (0x1000–0x1FFF back to defaults); heartbeat every 0x1017 ms.
  SDO and SYNC in pre-operational and operational, PDOs only in operational, nothing but NMT in stopped.
* PDOs as configured by SDO (0x1400–0x1403/0x1600–0x1603, 0x1800–0x1803/0x1A00–0x1A03; COB-ID valid bit 31,
  transmission type, mapped objects with their bit lengths; byte-aligned standard types). RPDOs of type 0–240
  are latched and applied at the next SYNC, 254/255 on reception; an RPDO of the wrong length is ignored and
  counted (``wrong_length``). TPDOs of type 1–240 go out on every Nth SYNC with values sampled at that SYNC,
  type 0 at a SYNC when their data changed, 254/255 on their event timer (0x18xx:5). A mapping longer than 8
  bytes goes out as a CAN FD frame, padded to the next valid FD length (an RPDO may come padded the same way).
  Configuration is compiled once per change, never per SYNC.
* Watchdog (the analogue of a Damiao CAN timeout), armed only in Operation Enabled and fed only while NMT
  operational: no SYNC and no RPDO for more than `sync_timeout_periods` × 0x1006 (when 0x1006 ≠ 0), or the
  heartbeat of the node in 0x1016:1 missing for longer than its time (once a first one was heard) → FAULT with
  EMCY 0x8130.
* CiA 402 state machine: transitions 0–16 from the controlword, fault reset on the rising edge of bit 7 only,
  quick stop per 0x605A (0: disable at once; 1–3: brake, then Switch On Disabled; 5–7: brake and stay in Quick
  Stop Active), the fault reaction is immediate (torque off). Statusword bits 0–6, 9 (remote), 10 (target
  reached), 11 (internal limit: torque clamped), 12/13 (mode specific). 0x6061 follows 0x6060; a mode missing
  from 0x6502 is refused (SDO abort 0x06090030; from an RPDO it is ignored and counted) and the display stays.
* Modes: CSP (PD in actuator space on 0x607A with the internal gains, + 0x60B1 velocity and 0x60B2 torque
  offsets), CSV (velocity loop on 0x60FF + 0x60B1, + 0x60B2), CST (0x6071 + 0x60B2), all limited by 0x6072;
  homing (6) with methods 35/37 (the current position becomes 0x607C) and 33/34 (move at 0x6099:2 to the next
  index pulse below/above, emulated at `index_position` + k·2π of the shaft, which becomes 0x607C).
* CSP following error: |demand − actual| > 0x6065 for longer than 0x6066 ms → FAULT, EMCY 0x8611.

Faults latch 0x603F, set 0x1001 (bit 0 plus the class bit of the code), push 0x1003 and send an EMCY (unless
NMT stopped or 0x1014 is invalid); a fault reset that clears them sends EMCY 0x0000.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable

import can
import canopen
from canopen.objectdictionary import ODVariable, datatypes
from canopen.profiles.p402 import State402
from canopen.sdo import SdoAbortedError

from drivers.can.cia402.wiring import DriveWiring, load_dictionary
from drivers.can.emulator.base import MotorFirmware, ThermalModel
from drivers.can.protocol.errors import FrameError

__all__ = ["Cia402Firmware", "NmtState"]

_TAU = 2.0 * math.pi
_TIME_TOLERANCE = 1e-9


class NmtState:
    """NMT states as the heartbeat carries them (CiA 301)."""

    INITIALISING = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


# NMT command specifiers (byte 0 of COB-ID 0x000)
_NMT_START, _NMT_STOP, _NMT_PRE_OP, _NMT_RESET_NODE, _NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82

# CiA 402 states, named as canopen's State402 names them
NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP = "QUICK STOP ACTIVE"
FAULT_REACTION = "FAULT REACTION ACTIVE"
FAULT = "FAULT"
_STATE_BITS = {name: value for name, (_mask, value) in State402.SW_MASK.items()}
_VOLTAGE_ENABLED = 0x0010
_QUICK_STOP_OFF = 0x0020  # statusword bit 5: 1 = quick stop NOT active
_REMOTE = 0x0200
_TARGET_REACHED = 0x0400
_INTERNAL_LIMIT = 0x0800
_BIT12 = 0x1000
_BIT13 = 0x2000

_CW_FAULT_RESET = 0x0080
_CW_HOMING_START = 0x0010
_CW_HALT = 0x0100

# modes of operation (0x6060)
HOMING, CSP, CSV, CST = 6, 8, 9, 10
_MODE_BIT = {HOMING: 1 << 5, CSP: 1 << 7, CSV: 1 << 8, CST: 1 << 9}

# EMCY error codes (CiA 301 / 402)
EMCY_RESET = 0x0000
EMCY_HEARTBEAT = 0x8130
EMCY_FOLLOWING_ERROR = 0x8611
EMCY_OVER_TEMPERATURE = 0x4310

# SDO abort codes
_ABORT_VALUE_RANGE = 0x06090030
_ABORT_NOT_MAPPABLE = 0x06040041
_ABORT_PDO_LENGTH = 0x06040042
_ABORT_WRONG_STATE = 0x08000022

_PDO_NOT_VALID = 1 << 31
_NO_WINDOW = 0xFFFFFFFF
_STANDSTILL = 0.01  # rad/s: a braking drive counts as stopped below this
_STRUCT_CODES = {
    datatypes.BOOLEAN: "?",
    datatypes.INTEGER8: "b",
    datatypes.INTEGER16: "h",
    datatypes.INTEGER32: "i",
    datatypes.INTEGER64: "q",
    datatypes.UNSIGNED8: "B",
    datatypes.UNSIGNED16: "H",
    datatypes.UNSIGNED32: "I",
    datatypes.UNSIGNED64: "Q",
    datatypes.REAL32: "f",
    datatypes.REAL64: "d",
}
_LIMITS = {
    "b": (-(1 << 7), (1 << 7) - 1),
    "h": (-(1 << 15), (1 << 15) - 1),
    "i": (-(1 << 31), (1 << 31) - 1),
    "q": (-(1 << 63), (1 << 63) - 1),
    "B": (0, (1 << 8) - 1),
    "H": (0, (1 << 16) - 1),
    "I": (0, (1 << 32) - 1),
    "Q": (0, (1 << 64) - 1),
}


def _i32(value: float) -> int:
    """A value as a drive's INTEGER32 register holds it (wraps like the counter does)."""
    return ((round(value) + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


_FD_LENGTHS = (12, 16, 20, 24, 32, 48, 64)


def fd_length(size: int) -> int:
    """The CAN FD frame length that carries `size` bytes (the controller pads up to the next valid DLC)."""
    return size if size <= 8 else next(n for n in _FD_LENGTHS if n >= size)


def _saturate(value: float, code: str) -> int:
    low, high = _LIMITS[code]
    return low if value < low else high if value > high else int(value)


class _Outbox:
    """The `network` a `LocalNode` sends through: frames are collected for the firmware to return, never sent."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []

    def send_message(self, can_id: int, data: bytes | bytearray | list[int], remote: bool = False) -> None:
        payload = bytes(data)
        if len(payload) > 8:
            payload = payload.ljust(fd_length(len(payload)), b"\x00")  # what a CAN FD controller puts on the bus
        self.frames.append(
            can.Message(
                arbitration_id=can_id,
                data=payload,
                is_extended_id=can_id > 0x7FF,
                is_remote_frame=remote,
                is_fd=len(payload) > 8,
            )
        )

    def subscribe(self, can_id: int, callback: Callable[..., None]) -> None:
        """Routing is the emulator's (`accepts`), not a notifier's."""

    def unsubscribe(self, can_id: int, callback: Callable[..., None] | None = None) -> None:
        """See `subscribe`."""

    def send_periodic(self, can_id: int, data: bytes, period: float, remote: bool = False) -> _NoTask:
        """canopen's NmtSlave would start a thread for the heartbeat; this drive produces it from `tick`."""
        return _NoTask()

    def take(self) -> list[can.Message]:
        frames, self.frames = self.frames, []
        return frames


class _NoTask:
    def stop(self) -> None:
        pass

    def update(self, data: bytes) -> None:
        pass


class _Pdo:
    """One PDO compiled from its communication and mapping records: what the SYNC path runs."""

    __slots__ = ("cob_id", "codec", "counter", "getters", "last", "next_event", "period", "setters", "size", "type")

    def __init__(
        self,
        cob_id: int,
        transmission: int,
        codec: struct.Struct,
        getters: tuple[Callable[[], int | float], ...],
        setters: tuple[Callable[[int | float], None], ...],
        period: float,
    ) -> None:
        self.cob_id = cob_id
        self.type = transmission
        self.codec = codec
        self.size = codec.size
        self.getters = getters
        self.setters = setters
        self.period = period
        self.counter = 0
        self.last: bytes | None = None
        self.next_event: float | None = None


class Cia402Firmware(MotorFirmware):
    """One CiA 402 drive (one CANopen node) for the joint `wiring` describes.

    `position_gain` (N·m/rad) and `velocity_gain` (N·m·s/rad) are the drive's own loop gains in actuator space
    (default 30 × and 1 × the rated torque per rad); `sync_timeout_periods` scales 0x1006 into the watchdog
    (default 50: the stale bound the loopback rig allows its two processes);
    `index_position` (rad, shaft) is where the emulated index pulse sits in every revolution.
    """

    def __init__(
        self,
        wiring: DriveWiring,
        *,
        seed: int = 0,
        thermal: ThermalModel | None = None,
        position_gain: float | None = None,
        velocity_gain: float | None = None,
        sync_timeout_periods: float = 50.0,
        index_position: float = 0.0,
    ) -> None:
        super().__init__(rated_torque=wiring.rated_torque, seed=seed, thermal=thermal)
        self.wiring = wiring
        self.node_id = wiring.node_id
        self.position_gain = 30.0 * wiring.rated_torque if position_gain is None else position_gain
        self.velocity_gain = 1.0 * wiring.rated_torque if velocity_gain is None else velocity_gain
        self.sync_timeout_periods = sync_timeout_periods
        self.index_position = index_position
        self._counts_per_rad = wiring.counts_per_rad
        self._velocity_per_rad_s = wiring.velocity_per_rad_s
        self._permille_per_nm = wiring.permille_per_nm
        self.counters["wrong_length"] = 0
        self.counters["sync"] = 0
        self._outbox = _Outbox()
        od = load_dictionary(wiring.eds, wiring.node_id)
        self.node = canopen.LocalNode(wiring.node_id, od)
        self.node.associate_network(self._outbox)  # type: ignore[arg-type]
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self._live_read: dict[tuple[int, int], Callable[[], int | float]] = {}
        self._live_write: dict[tuple[int, int], Callable[[int | float], None]] = {}
        self._register_live_objects()
        self.origin = 0.0
        """Shaft position (rad) where the position actual value reads 0 (moved by homing; lost on reboot)."""
        self._power_up()

    # -- power, NMT ----------------------------------------------------------------------------------------------

    def _power_up(self) -> None:
        """State after power-on or reset node: EDS defaults, INITIALISING until the next timer run sends boot-up."""
        self.node.data_store.clear()
        self.origin = 0.0
        self.state = NOT_READY
        self.controlword = 0
        self.mode = 0
        self.mode_display = 0
        self.target_position = 0
        self.target_velocity = 0
        self.target_torque = 0
        self.velocity_offset = 0
        self.torque_offset = 0
        self.error_code = 0
        self.error_register = 0
        self.error_history: list[int] = []
        self.applied_torque = 0.0
        self.limited = False
        self._stopped = False
        self.homing_state = "idle"  # idle, moving, attained, interrupted, error
        self._homing_goal = 0.0
        self._homing_speed = 0.0
        self._hold = 0.0
        self._following_since: float | None = None
        self._reset_communication()
        self.state = SWITCH_ON_DISABLED  # transition 1: self-test passed

    def _reset_communication(self) -> None:
        for index in [i for i in self.node.data_store if 0x1000 <= i < 0x2000]:
            del self.node.data_store[index]
        self.nmt_state = NmtState.INITIALISING
        self._latched: dict[int, bytes] = {}
        self._last_feed: float | None = None
        self._consumer_seen: float | None = None
        self._next_heartbeat: float | None = None
        self._reload()

    def _boot_if_due(self, now: float) -> None:
        if self.nmt_state == NmtState.INITIALISING:
            self._outbox.send_message(0x700 + self.node_id, b"\x00")
            self.nmt_state = NmtState.PRE_OPERATIONAL
            self._next_heartbeat = now + self.heartbeat_ms / 1000.0 if self.heartbeat_ms else None

    def _nmt(self, data: bytes) -> None:
        if len(data) < 2:
            raise FrameError(f"NMT command of {len(data)} bytes")
        command, target = data[0], data[1]
        if target not in (0, self.node_id):
            return
        if command == _NMT_START:
            self.nmt_state = NmtState.OPERATIONAL
        elif command == _NMT_STOP:
            self.nmt_state = NmtState.STOPPED
        elif command == _NMT_PRE_OP:
            self.nmt_state = NmtState.PRE_OPERATIONAL
        elif command == _NMT_RESET_NODE:
            self._power_up()
        elif command == _NMT_RESET_COMM:
            self._reset_communication()
        else:
            self.counters["ignored"] += 1

    # -- MotorFirmware -----------------------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        return self.state in (OPERATION_ENABLED, QUICK_STOP)

    @property
    def fault(self) -> int:
        return self.error_code if self.state in (FAULT, FAULT_REACTION) else 0

    def accepts(self, msg: can.Message) -> bool:
        return not msg.is_extended_id and not msg.is_error_frame and msg.arbitration_id in self._listening

    def torque(self, position: float, velocity: float) -> float:
        state = self.state
        if state == OPERATION_ENABLED:
            tau = self._law(position, velocity)
        elif state == QUICK_STOP:  # the velocity loop brakes to standstill, then the position loop holds
            tau = self.position_gain * (self._hold - position) if self._stopped else 0.0
            tau -= self.velocity_gain * velocity
        else:
            self.applied_torque = 0.0
            self.limited = False
            return 0.0
        limit = self.max_torque
        self.limited = not -limit <= tau <= limit
        self.applied_torque = limit if tau > limit else -limit if tau < -limit else tau
        return self.applied_torque

    def _law(self, position: float, velocity: float) -> float:
        mode = self.mode_display
        if mode == CSP:
            demand = self.origin + self.target_position / self._counts_per_rad
            velocity_ff = self.velocity_offset / self._velocity_per_rad_s
            return (
                self.position_gain * (demand - position)
                + self.velocity_gain * (velocity_ff - velocity)
                + self.torque_offset / self._permille_per_nm
            )
        if mode == CSV:
            demand = (self.target_velocity + self.velocity_offset) / self._velocity_per_rad_s
            return self.velocity_gain * (demand - velocity) + self.torque_offset / self._permille_per_nm
        if mode == CST:
            return (self.target_torque + self.torque_offset) / self._permille_per_nm
        if mode == HOMING:
            if self.homing_state == "moving":
                return self.velocity_gain * (self._homing_speed - velocity)
            return self.position_gain * (self._hold - position) - self.velocity_gain * velocity
        return 0.0

    def inject_fault(self, code: int) -> None:
        """Latch the fault an EMCY error code names (e.g. 0x2310 overcurrent, 0x3210 overvoltage, 0x4310 hot)."""
        if not 0 < code <= 0xFFFF:
            raise ValueError(f"a CiA 402 fault is an EMCY error code 0x0001..0xFFFF, got {code:#x}")
        self._fault(code)

    def clear_fault(self) -> None:
        """The cause is gone and the fault acknowledged at the drive (as a fault reset would): Switch On Disabled."""
        if self.state in (FAULT, FAULT_REACTION):
            self._reset_fault()

    def reboot(self) -> None:
        self._pending.clear()
        self._outbox.take()
        self._power_up()

    def _over_temperature_fault(self, rotor: bool) -> int:
        return EMCY_OVER_TEMPERATURE

    def _expire(self, now: float) -> None:
        self._boot_if_due(now)
        state = self.state
        if state == QUICK_STOP:
            self._brake()
        if self.state != OPERATION_ENABLED:
            self._following_since = None
            return
        if self._watchdog_expired(now):
            self._fault(EMCY_HEARTBEAT)
            return
        mode = self.mode_display
        if mode == CSP:
            self._check_following_error(now)
        elif mode == HOMING and self.homing_state == "moving":
            self._home_step()

    def _periodic(self, now: float) -> list[can.Message]:
        if self.heartbeat_ms and self._next_heartbeat is not None and now >= self._next_heartbeat - _TIME_TOLERANCE:
            period = self.heartbeat_ms / 1000.0
            self._next_heartbeat += period
            if self._next_heartbeat <= now:
                self._next_heartbeat = now + period
            self._outbox.send_message(0x700 + self.node_id, bytes((self.nmt_state,)))
        if self.nmt_state == NmtState.OPERATIONAL:
            for pdo in self._event_tpdos:
                if pdo.next_event is None or now >= pdo.next_event - _TIME_TOLERANCE:
                    pdo.next_event = now + pdo.period
                    self._transmit(pdo)
        return self._outbox.take()

    # -- receiving ----------------------------------------------------------------------------------------------

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        if msg.is_remote_frame:
            return self._ignore()
        cob_id = msg.arbitration_id
        data = bytes(msg.data)
        if cob_id == 0:
            self._nmt(data)
            self._boot_if_due(now)
            return self._outbox.take()
        nmt = self.nmt_state
        if nmt == NmtState.STOPPED or nmt == NmtState.INITIALISING:
            return self._ignore()
        if cob_id == self._sdo_rx:
            if len(data) != 8:
                raise FrameError(f"SDO request of {len(data)} bytes")
            self.node.sdo.on_request(cob_id, data, now)
            if self._dirty:
                self._reload()
            return self._outbox.take()
        if cob_id == self._sync_id:
            self._sync(now)
            return self._outbox.take()
        if cob_id == self._consumer_id:
            self._consumer_seen = now
            return []
        rpdo = self._rpdos.get(cob_id)
        if rpdo is None or nmt != NmtState.OPERATIONAL:
            return self._ignore()
        if len(data) != rpdo.size and not (msg.is_fd and rpdo.size > 8 and len(data) == fd_length(rpdo.size)):
            self.counters["wrong_length"] += 1
            return []
        self._last_feed = now
        if rpdo.type <= 240:
            self._latched[cob_id] = data
        else:
            self._apply(rpdo, data)
            if self._dirty:
                self._reload()
        return self._outbox.take()

    def _sync(self, now: float) -> None:
        self.counters["sync"] += 1
        if self.nmt_state != NmtState.OPERATIONAL:
            return
        self._last_feed = now
        if self._latched:
            for cob_id, data in self._latched.items():
                rpdo = self._rpdos.get(cob_id)
                if rpdo is not None:
                    self._apply(rpdo, data)
            self._latched.clear()
            if self._dirty:
                self._reload()
        for pdo in self._sync_tpdos:
            if pdo.type == 0:
                data = self._sample(pdo)
                if data != pdo.last:
                    pdo.last = data
                    self._outbox.send_message(pdo.cob_id, data)
                continue
            pdo.counter += 1
            if pdo.counter >= pdo.type:
                pdo.counter = 0
                self._transmit(pdo)

    def _apply(self, rpdo: _Pdo, data: bytes) -> None:
        for setter, value in zip(rpdo.setters, rpdo.codec.unpack_from(data), strict=True):
            setter(value)

    def _sample(self, pdo: _Pdo) -> bytes:
        return pdo.codec.pack(*[getter() for getter in pdo.getters])

    def _transmit(self, pdo: _Pdo) -> None:
        self._outbox.send_message(pdo.cob_id, self._sample(pdo))

    # -- object dictionary ----------------------------------------------------------------------------------------

    def _register_live_objects(self) -> None:
        read, write = self._live_read, self._live_write
        read[(0x6040, 0)] = lambda: self.controlword
        write[(0x6040, 0)] = self._set_controlword
        read[(0x6041, 0)] = self.statusword
        read[(0x6060, 0)] = lambda: self.mode
        write[(0x6060, 0)] = self._set_mode_from_pdo
        read[(0x6061, 0)] = lambda: self.mode_display
        read[(0x6062, 0)] = self._position_demand
        read[(0x6064, 0)] = self._position_reported
        read[(0x606C, 0)] = lambda: _i32(self.velocity * self._velocity_per_rad_s)
        read[(0x6077, 0)] = lambda: _saturate(round(self.applied_torque * self._permille_per_nm), "h")
        read[(0x60F4, 0)] = lambda: _i32(self._position_demand() - self._position_actual())
        read[(0x603F, 0)] = lambda: self.error_code
        read[(0x1001, 0)] = lambda: self.error_register
        read[(0x1003, 0)] = lambda: len(self.error_history)
        write[(0x1003, 0)] = self._clear_error_history
        for sub in range(1, 9):
            read[(0x1003, sub)] = lambda sub=sub: self.error_history[sub - 1] if sub <= len(self.error_history) else 0
        for index, name in (
            (0x607A, "target_position"),
            (0x60FF, "target_velocity"),
            (0x6071, "target_torque"),
            (0x60B1, "velocity_offset"),
            (0x60B2, "torque_offset"),
        ):
            read[(index, 0)] = lambda name=name: getattr(self, name)
            write[(index, 0)] = lambda value, name=name: setattr(self, name, int(value))

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | float | None:
        getter = self._live_read.get((index, subindex))
        return None if getter is None else getter()

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        value = od.decode_raw(data)
        if index == 0x6060:
            self._set_mode(int(value), refuse=True)
            return
        setter = self._live_write.get((index, subindex))
        if setter is not None:
            setter(value)
            return
        if 0x1600 <= index <= 0x1603 or 0x1A00 <= index <= 0x1A03:
            self._check_mapping(index, subindex, int(value))
        elif (0x1400 <= index <= 0x1403 or 0x1800 <= index <= 0x1803) and subindex == 1:
            self._check_cob_id(index, int(value))
        self._dirty = True  # a parameter: stored by the node, cached by `_reload` once the request is done

    def _check_cob_id(self, index: int, value: int) -> None:
        """CiA 301: a valid PDO's COB-ID changes only by way of invalid (bit 31) first."""
        current = self._value(index, 1)
        if not current & _PDO_NOT_VALID and not value & _PDO_NOT_VALID and (current ^ value) & 0x1FFFFFFF:
            raise SdoAbortedError(_ABORT_VALUE_RANGE)

    def _check_mapping(self, index: int, subindex: int, value: int) -> None:
        """CiA 301: a mapping changes only while its PDO is invalid and, for the entries, while sub 0 is 0."""
        if not self._value(index - 0x200, 1) & _PDO_NOT_VALID:
            raise SdoAbortedError(_ABORT_WRONG_STATE)
        if subindex != 0 and self._value(index, 0) != 0:
            raise SdoAbortedError(_ABORT_WRONG_STATE)
        if subindex == 0:
            entries = [self._mapped(index, sub) for sub in range(1, value + 1)]
            if sum(bits for _, _, bits in entries) > 64 * 8:
                raise SdoAbortedError(_ABORT_PDO_LENGTH)
            return
        if value == 0:
            return
        target, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        variable = self._variable(target, sub)
        if variable is None or not variable.pdo_mappable or variable.data_type not in _STRUCT_CODES:
            raise SdoAbortedError(_ABORT_NOT_MAPPABLE)
        if bits != len(variable):
            raise SdoAbortedError(_ABORT_NOT_MAPPABLE)
        receive = index < 0x1A00
        if receive and not variable.writable:
            raise SdoAbortedError(_ABORT_NOT_MAPPABLE)

    def _variable(self, index: int, subindex: int) -> ODVariable | None:
        od = self.node.object_dictionary
        if index not in od:
            return None
        obj = od[index]
        if isinstance(obj, ODVariable):
            return obj if subindex == 0 else None
        return obj.get(subindex)  # type: ignore[union-attr,return-value]

    def _value(self, index: int, subindex: int = 0) -> int:
        """A parameter's current value (RAM, else the EDS default)."""
        variable = self._variable(index, subindex)
        assert variable is not None, f"{index:#06x}:{subindex} is not in the EDS"
        return int(variable.decode_raw(self.node.get_data(index, subindex)))

    def _mapped(self, index: int, subindex: int) -> tuple[int, int, int]:
        entry = self._value(index, subindex)
        return entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF

    def _clear_error_history(self, value: int | float) -> None:
        if value != 0:
            raise SdoAbortedError(_ABORT_VALUE_RANGE)
        self.error_history.clear()

    def _reload(self) -> None:
        """Cache the parameters the drive runs on and compile the PDOs (after a configuration change, not per SYNC)."""
        self._dirty = False
        value = self._value
        self.heartbeat_ms = value(0x1017)
        self._sync_id = value(0x1005) & 0x7FF
        self._sync_period = value(0x1006) / 1e6
        emcy = value(0x1014)
        self._emcy_id = None if emcy & _PDO_NOT_VALID else emcy & 0x7FF
        consumer = value(0x1016, 1) if 0x1016 in self.node.object_dictionary else 0
        consumer_node, consumer_ms = (consumer >> 16) & 0x7F, consumer & 0xFFFF
        self._consumer_id = 0x700 + consumer_node if consumer_node and consumer_ms else None
        self._consumer_timeout = consumer_ms / 1000.0
        self._sdo_rx = 0x600 + self.node_id
        self.quick_stop_option = value(0x605A)
        self.max_torque = value(0x6072) / self._permille_per_nm
        self.following_window = value(0x6065)
        self.following_timeout = value(0x6066) / 1000.0
        self.home_offset = value(0x607C)
        self.homing_method = value(0x6098)
        self.homing_speed_zero = value(0x6099, 2) / self._velocity_per_rad_s
        self.supported_modes = value(0x6502)
        if self._next_heartbeat is None and self.heartbeat_ms and self.nmt_state != NmtState.INITIALISING:
            self._next_heartbeat = -math.inf  # switched on: the first heartbeat goes out at the next tick
        elif not self.heartbeat_ms:
            self._next_heartbeat = None
        self._rpdos: dict[int, _Pdo] = {}
        self._sync_tpdos: list[_Pdo] = []
        self._event_tpdos: list[_Pdo] = []
        for k in range(4):
            rpdo = self._compile(0x1400 + k, 0x1600 + k, receive=True)
            if rpdo is not None:
                self._rpdos[rpdo.cob_id] = rpdo
            tpdo = self._compile(0x1800 + k, 0x1A00 + k, receive=False)
            if tpdo is None:
                continue
            if tpdo.type <= 240:
                self._sync_tpdos.append(tpdo)
            elif tpdo.period > 0.0:
                self._event_tpdos.append(tpdo)
        self._listening = {0, self._sync_id, self._sdo_rx, *self._rpdos}
        if self._consumer_id is not None:
            self._listening.add(self._consumer_id)

    def _compile(self, comm: int, mapping: int, *, receive: bool) -> _Pdo | None:
        od = self.node.object_dictionary
        if comm not in od or mapping not in od:
            return None
        cob = self._value(comm, 1)
        if cob & _PDO_NOT_VALID:
            return None
        transmission = self._value(comm, 2)
        if 241 <= transmission <= 253:
            return None  # reserved / RTR-only: not emulated
        entries = self._value(mapping, 0)
        if entries == 0:
            return None  # nothing mapped: nothing to send or receive
        codes, getters, setters = ["<"], [], []
        for sub in range(1, entries + 1):
            index, subindex, _bits = self._mapped(mapping, sub)
            variable = self._variable(index, subindex)
            if variable is None:
                return None
            codes.append(_STRUCT_CODES[variable.data_type])
            getters.append(self._getter(index, subindex, variable))
            setters.append(self._setter(index, subindex, variable))
        period = 0.0
        if not receive and 5 in od[comm]:  # type: ignore[operator]
            period = self._value(comm, 5) / 1000.0
        return _Pdo(cob & 0x7FF, transmission, struct.Struct("".join(codes)), tuple(getters), tuple(setters), period)

    def _getter(self, index: int, subindex: int, variable: ODVariable) -> Callable[[], int | float]:
        live = self._live_read.get((index, subindex))
        if live is not None:
            return live
        return lambda: variable.decode_raw(self.node.get_data(index, subindex))

    def _setter(self, index: int, subindex: int, variable: ODVariable) -> Callable[[int | float], None]:
        live = self._live_write.get((index, subindex))
        if live is not None:
            return live

        def store(value: int | float) -> None:
            self.node.data_store.setdefault(index, {})[subindex] = variable.encode_raw(value)
            self._dirty = True  # a parameter mapped into an RPDO: re-cached once the frame is done

        return store

    # -- CiA 402 ----------------------------------------------------------------------------------------------

    def statusword(self) -> int:
        state = self.state
        word = _STATE_BITS[state] | _REMOTE
        if state in (READY, SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP):
            word |= _VOLTAGE_ENABLED
        if state in (READY, SWITCHED_ON, OPERATION_ENABLED):
            word |= _QUICK_STOP_OFF
        if state == QUICK_STOP and self._stopped:
            word |= _TARGET_REACHED
        if state == OPERATION_ENABLED:
            if self.limited:
                word |= _INTERNAL_LIMIT
            mode = self.mode_display
            if mode in (CSP, CSV, CST):
                word |= _BIT12  # the drive follows the command value
                if mode == CSP and self._following_error():
                    word |= _BIT13
            elif mode == HOMING:
                word |= self._homing_bits()
        return word

    def _homing_bits(self) -> int:
        homing = self.homing_state
        if homing == "moving":
            return 0
        if homing == "attained":
            return _BIT12 | _TARGET_REACHED
        if homing == "error":
            return _BIT13 | (_TARGET_REACHED if abs(self.velocity) < _STANDSTILL else 0)
        return _TARGET_REACHED  # interrupted or not started

    def _set_controlword(self, value: int | float) -> None:
        word = int(value)
        previous, self.controlword = self.controlword, word
        state = self.state
        if state in (FAULT, FAULT_REACTION):
            if word & _CW_FAULT_RESET and not previous & _CW_FAULT_RESET:
                self._reset_fault()
            return
        command = word & 0x0F
        if not command & 0x02:  # disable voltage: 7, 9, 10, 12
            if state != SWITCH_ON_DISABLED:
                self._enter(SWITCH_ON_DISABLED)
        elif not command & 0x04:  # quick stop: 7, 10, 11
            if state == OPERATION_ENABLED:
                self._enter(QUICK_STOP)
            elif state in (READY, SWITCHED_ON):
                self._enter(SWITCH_ON_DISABLED)
        elif not command & 0x01:  # shutdown: 2, 6, 8
            if state in (SWITCH_ON_DISABLED, SWITCHED_ON, OPERATION_ENABLED):
                self._enter(READY)
        elif not command & 0x08:  # switch on / disable operation: 3, 5
            if state in (READY, OPERATION_ENABLED):
                self._enter(SWITCHED_ON)
        else:  # enable operation: 3 + 4, 4, 16
            if state == READY:
                self._enter(SWITCHED_ON)
                state = SWITCHED_ON
            if state == SWITCHED_ON or (state == QUICK_STOP and self.quick_stop_option >= 5):
                self._enter(OPERATION_ENABLED)
        if self.state == OPERATION_ENABLED and self.mode_display == HOMING:
            self._homing_control(previous, word)

    def _enter(self, state: str) -> None:
        leaving = self.state
        self.state = state
        if state == OPERATION_ENABLED and leaving != OPERATION_ENABLED:
            self._last_feed = None  # the watchdog counts from the next feed or tick
            self._following_since = None
            self._hold = self.position
            if self.mode_display == HOMING:
                self.homing_state = "idle"
        elif state == QUICK_STOP:
            self._stopped = False
            if self.quick_stop_option == 0:
                self.state = SWITCH_ON_DISABLED
        if state != OPERATION_ENABLED and self.homing_state == "moving":
            self.homing_state = "interrupted"

    def _brake(self) -> None:
        """Quick Stop Active: brake to standstill, then hold (options 5–7) or switch off (1–3)."""
        if not self._stopped and abs(self.velocity) < _STANDSTILL:
            self._stopped = True
            self._hold = self.position
            if self.quick_stop_option < 5:
                self.state = SWITCH_ON_DISABLED

    def _set_mode_from_pdo(self, value: int | float) -> None:
        if not self._set_mode(int(value), refuse=False):
            self.counters["ignored"] += 1

    def _set_mode(self, mode: int, *, refuse: bool) -> bool:
        """0x6060: a supported mode is displayed at once; another is refused (SDO abort) and the display stays."""
        if mode != 0 and not self.supported_modes & _MODE_BIT.get(mode, 0):
            if refuse:
                raise SdoAbortedError(_ABORT_VALUE_RANGE)
            return False
        self.mode = mode
        if mode != self.mode_display:
            self.mode_display = mode
            self._hold = self.position
            if self.homing_state == "moving":
                self.homing_state = "interrupted"
            if mode == HOMING:
                self.homing_state = "idle"
        return True

    # -- homing -------------------------------------------------------------------------------------------------

    def _homing_control(self, previous: int, word: int) -> None:
        start = word & _CW_HOMING_START
        if word & _CW_HALT or not start:
            if self.homing_state == "moving":
                self.homing_state = "interrupted"
                self._hold = self.position
            return
        if previous & _CW_HOMING_START and self.homing_state != "idle":
            return  # only a rising edge of bit 4 starts homing
        method = self.homing_method
        if method in (35, 37):
            self._set_home(self.position)
        elif method in (33, 34):
            turn = (self.position - self.index_position) / _TAU
            k = math.floor(turn - 1e-9) if method == 33 else math.ceil(turn + 1e-9)
            self._homing_goal = self.index_position + k * _TAU
            self._homing_speed = self.homing_speed_zero * (1.0 if method == 34 else -1.0)
            self.homing_state = "moving"
        else:
            self.homing_state = "error"

    def _home_step(self) -> None:
        if (self._homing_speed > 0.0) == (self.position >= self._homing_goal):
            self._set_home(self._homing_goal)

    def _set_home(self, position: float) -> None:
        """The shaft at `position` now reads 0x607C."""
        self.origin = position - self.home_offset / self._counts_per_rad
        self._hold = position
        self.homing_state = "attained"

    # -- positions and faults --------------------------------------------------------------------------------------

    def _position_actual(self) -> int:
        return _i32((self.position - self.origin) * self._counts_per_rad)

    def _position_reported(self) -> int:
        if not self.glitch.active:
            return self._position_actual()
        return _i32((self.glitch.corrupt(0, self.position) - self.origin) * self._counts_per_rad)

    def _position_demand(self) -> int:
        if self.state == OPERATION_ENABLED and self.mode_display == CSP:
            return self.target_position
        return self._position_actual()

    def _following_error(self) -> bool:
        window = self.following_window
        return window != _NO_WINDOW and abs(self.target_position - self._position_actual()) > window

    def _check_following_error(self, now: float) -> None:
        if not self._following_error():
            self._following_since = None
            return
        if self._following_since is None:
            self._following_since = now
        if now - self._following_since >= self.following_timeout - _TIME_TOLERANCE and (
            now > self._following_since or self.following_timeout == 0.0
        ):
            self._fault(EMCY_FOLLOWING_ERROR)

    def _watchdog_expired(self, now: float) -> bool:
        """Counts in every NMT state (a drive left outside operational starves), fed only while operational."""
        if self._sync_period > 0.0:
            if self._last_feed is None:
                self._last_feed = now
            elif now - self._last_feed > self.sync_timeout_periods * self._sync_period:
                return True
        seen = self._consumer_seen
        return self._consumer_id is not None and seen is not None and now - seen > self._consumer_timeout

    def _fault(self, code: int) -> None:
        self.state = FAULT  # the fault reaction (0x605E) is immediate: torque off
        self.applied_torque = 0.0
        if self.homing_state == "moving":
            self.homing_state = "error"
        self.error_code = code
        self.error_register |= 0x01 | _error_class(code)
        self.error_history.insert(0, code)
        del self.error_history[8:]
        self._consumer_seen = None
        self._emcy(code)

    def _reset_fault(self) -> None:
        if self.temperature_rotor > self.over_temperature or self.temperature_mos > self.over_temperature:
            return  # the cause persists
        self.state = SWITCH_ON_DISABLED
        self.error_code = 0
        self.error_register = 0
        self._emcy(EMCY_RESET)

    def _emcy(self, code: int) -> None:
        if self._emcy_id is None or self.nmt_state in (NmtState.STOPPED, NmtState.INITIALISING):
            return
        self._outbox.send_message(self._emcy_id, struct.pack("<HB5x", code, self.error_register))


def _error_class(code: int) -> int:
    """The 0x1001 error register bit of an EMCY code's class (CiA 301)."""
    high = code >> 12
    if high == 0x2:
        return 0x02  # current
    if high == 0x3:
        return 0x04  # voltage
    if high == 0x4:
        return 0x08  # temperature
    if code >> 8 in (0x81, 0x82):
        return 0x10  # communication
    if high in (0x6, 0x7, 0x8):
        return 0x20  # device profile specific
    return 0x80  # manufacturer specific
