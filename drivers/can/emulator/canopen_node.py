"""What every emulated CANopen drive shares (CiA 301): NMT, heartbeat, SDO, SYNC-driven PDOs, EMCY, error history.

The object dictionary and the SDO server are `canopen`'s `LocalNode` from the drive's EDS, so uploads, downloads,
segmented transfers and abort codes are the library's. Its `network` is an outbox the firmware drains (no
notifier, no thread, no clock): `LocalNode` neither ties PDOs to the dictionary nor sends them on SYNC, and its NMT
slave runs the heartbeat in a thread, so those are here. A device profile (`Cia402Firmware`) registers its live
objects — read from and written into its state, never stored — and caches its parameters in `_load_parameters`.

* NMT: boot-up (0x700+n, [0]) on power-up, reboot and reset; start / stop / pre-operational / reset node (the
  application's `_reset_application`) / reset communication (0x1000–0x1FFF back to the EDS); heartbeat every
  0x1017 ms. SDO and SYNC in pre-operational and operational, PDOs only in operational, nothing but NMT in stopped.
* PDOs as configured by SDO (0x1400–0x1403/0x1600–0x1603, 0x1800–0x1803/0x1A00–0x1A03; COB-ID valid bit 31,
  transmission type, mapped objects with their bit lengths; byte-aligned standard types). A mapping changes only
  while its PDO is invalid and, entry by entry, while sub 0 is 0; a valid PDO's COB-ID only through invalid.
  RPDOs of type 0–240 are latched and applied at the next SYNC, 254/255 on reception; an RPDO of the wrong length
  is ignored and counted (``wrong_length``). TPDOs of type 1–240 go out on every Nth SYNC with values sampled at
  that SYNC, type 0 at a SYNC when their data changed, 254/255 on their event timer (0x18xx:5). A mapping longer
  than 8 bytes goes out as a CAN FD frame, padded to the next valid FD length (an RPDO may come padded the same
  way). Configuration is compiled once per change, never per SYNC.
* Watchdog inputs: the time of the latest SYNC or RPDO while operational, and the heartbeat of the node 0x1016:1
  names; `_watchdog_expired` applies them (the profile decides when it is armed).
* Errors: `_record_error` sets 0x1001 (bit 0 plus the code's class bit) and pushes 0x1003, `_emcy` sends on 0x1014
  (not in NMT stopped).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable, datatypes
from canopen.sdo import SdoAbortedError

from drivers.can.cia402.wiring import load_dictionary
from drivers.can.emulator.base import MotorFirmware, ThermalModel
from drivers.can.protocol.errors import FrameError

__all__ = ["CanopenFirmware", "NmtState", "fd_length"]

TIME_TOLERANCE = 1e-9
"""Due times accumulate in floating point: a tick within a nanosecond of one counts as on time."""


class NmtState:
    """NMT states as the heartbeat carries them (CiA 301)."""

    INITIALISING = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


# NMT command specifiers (byte 0 of COB-ID 0x000)
_NMT_START, _NMT_STOP, _NMT_PRE_OP, _NMT_RESET_NODE, _NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82

# SDO abort codes
ABORT_VALUE_RANGE = 0x06090030
_ABORT_NOT_MAPPABLE = 0x06040041
_ABORT_PDO_LENGTH = 0x06040042
_ABORT_WRONG_STATE = 0x08000022

_PDO_NOT_VALID = 1 << 31
_FD_LENGTHS = (12, 16, 20, 24, 32, 48, 64)
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

Getter = Callable[[], int | float]
Setter = Callable[[int | float], None]


def fd_length(size: int) -> int:
    """The CAN FD frame length that carries `size` bytes (the controller pads up to the next valid DLC)."""
    return size if size <= 8 else next(n for n in _FD_LENGTHS if n >= size)


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
        getters: tuple[Getter, ...],
        setters: tuple[Setter, ...],
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


class CanopenFirmware(MotorFirmware):
    """One CANopen node from its EDS; a device profile subclasses it (see the module docstring).

    Hooks: `_register_live_objects` (fill `_live_read`, `_live_write`, `_sdo_checks`), `_load_parameters` (cache
    the profile's parameters after any configuration change), `_reset_application` (NMT reset node).
    """

    def __init__(
        self,
        node_id: int,
        eds: Path,
        *,
        rated_torque: float,
        seed: int = 0,
        thermal: ThermalModel | None = None,
    ) -> None:
        super().__init__(rated_torque=rated_torque, seed=seed, thermal=thermal)
        self.node_id = node_id
        self.counters["wrong_length"] = 0
        self.counters["sync"] = 0
        self._outbox = _Outbox()
        self.node = canopen.LocalNode(node_id, load_dictionary(eds, node_id))
        self.node.associate_network(self._outbox)  # type: ignore[arg-type]
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self._live_read: dict[tuple[int, int], Getter] = {}
        self._live_write: dict[tuple[int, int], Setter] = {}
        self._sdo_checks: dict[tuple[int, int], Setter] = {}
        """Run before a live object's setter on an SDO download only; may abort (an RPDO cannot be refused)."""
        self.error_register = 0
        self.error_history: list[int] = []
        self._register_live_objects()

    # -- hooks ---------------------------------------------------------------------------------------------------

    def _register_live_objects(self) -> None:
        read = self._live_read
        read[(0x1001, 0)] = lambda: self.error_register
        read[(0x1003, 0)] = lambda: len(self.error_history)
        self._live_write[(0x1003, 0)] = self._clear_error_history
        for sub in range(1, 9):
            read[(0x1003, sub)] = lambda sub=sub: self.error_history[sub - 1] if sub <= len(self.error_history) else 0

    def _load_parameters(self) -> None:
        """Cache the profile's parameters (called after every configuration change)."""

    def _reset_application(self) -> None:
        """NMT reset node: the application's power-up (which resets communication too)."""
        self.node.data_store.clear()
        self.error_register = 0
        self.error_history = []
        self._reset_communication()

    # -- NMT -----------------------------------------------------------------------------------------------------

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
            self._reset_application()
        elif command == _NMT_RESET_COMM:
            self._reset_communication()
        else:
            self.counters["ignored"] += 1

    # -- MotorFirmware -----------------------------------------------------------------------------------------

    def accepts(self, msg: can.Message) -> bool:
        return not msg.is_extended_id and not msg.is_error_frame and msg.arbitration_id in self._listening

    def _periodic(self, now: float) -> list[can.Message]:
        if self.heartbeat_ms and self._next_heartbeat is not None and now >= self._next_heartbeat - TIME_TOLERANCE:
            period = self.heartbeat_ms / 1000.0
            self._next_heartbeat += period
            if self._next_heartbeat <= now:
                self._next_heartbeat = now + period
            self._outbox.send_message(0x700 + self.node_id, bytes((self.nmt_state,)))
        if self.nmt_state == NmtState.OPERATIONAL:
            for pdo in self._event_tpdos:
                if pdo.next_event is None or now >= pdo.next_event - TIME_TOLERANCE:
                    pdo.next_event = now + pdo.period
                    self._transmit(pdo)
        return self._outbox.take()

    def _receive(self, msg: can.Message, now: float) -> list[can.Message]:
        if msg.is_remote_frame:
            return self._ignore()
        cob_id = msg.arbitration_id
        data = bytes(msg.data)
        if cob_id == 0:
            self._nmt(data)
            self._boot_if_due(now)
            return self._outbox.take()
        if cob_id == self._consumer_id:  # NMT error control: heard in every state
            self._consumer_seen = now
            return []
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

    # -- PDOs ------------------------------------------------------------------------------------------------------

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

    def _watchdog_expired(self, now: float, periods: float) -> bool:
        """No SYNC/RPDO for `periods` × 0x1006 (when set), or the consumed heartbeat (0x1016:1) overdue.

        Counts in every NMT state (a drive left outside operational starves), fed only while operational; call it
        only while the watchdog is armed (the first call after arming starts the count)."""
        if self._sync_period > 0.0:
            if self._last_feed is None:
                self._last_feed = now
            elif now - self._last_feed > periods * self._sync_period:
                return True
        seen = self._consumer_seen
        return self._consumer_id is not None and seen is not None and now - seen > self._consumer_timeout

    def _rearm_watchdog(self) -> None:
        """Count from the next feed or call, and wait for a first heartbeat again."""
        self._last_feed = None
        self._consumer_seen = None

    # -- object dictionary ----------------------------------------------------------------------------------------

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | float | None:
        getter = self._live_read.get((index, subindex))
        return None if getter is None else getter()

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        value = od.decode_raw(data)
        key = (index, subindex)
        check = self._sdo_checks.get(key)
        if check is not None:
            check(value)
        setter = self._live_write.get(key)
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
            raise SdoAbortedError(ABORT_VALUE_RANGE)

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

    def _reload(self) -> None:
        """Cache the parameters the node runs on and compile the PDOs (after a configuration change, not per SYNC)."""
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
        self._load_parameters()

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

    def _getter(self, index: int, subindex: int, variable: ODVariable) -> Getter:
        live = self._live_read.get((index, subindex))
        if live is not None:
            return live
        return lambda: variable.decode_raw(self.node.get_data(index, subindex))

    def _setter(self, index: int, subindex: int, variable: ODVariable) -> Setter:
        live = self._live_write.get((index, subindex))
        if live is not None:
            return live

        def store(value: int | float) -> None:
            self.node.data_store.setdefault(index, {})[subindex] = variable.encode_raw(value)
            self._dirty = True  # a parameter mapped into an RPDO: re-cached once the frame is done

        return store

    # -- errors ----------------------------------------------------------------------------------------------------

    def _record_error(self, code: int) -> None:
        """0x1001 and 0x1003 for a new error (the profile decides what the error does)."""
        self.error_register |= 0x01 | _error_class(code)
        self.error_history.insert(0, code)
        del self.error_history[8:]

    def _clear_error_history(self, value: int | float) -> None:
        if value != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        self.error_history.clear()

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
