"""A scripted CiA 402 slave for the ``cia402`` driver's tests, built on ``canopen``'s own ``LocalNode``.

Everything the driver sends is decoded by canopen: its SDO configuration lands in the ``LocalNode``'s data store
(canopen's SDO server), its RPDOs are decoded by the PDO maps canopen reads back from that store, NMT commands go
to canopen's ``NmtSlave``, TPDOs are encoded by canopen's TPDO maps. On top sits a minimal CiA 402 state machine
(the standard transitions, a fault-reset edge, an ideal CSP follower) whose statusword a test can also script.
Time is the test's: ``service(now)`` handles the frames waiting and sends heartbeats due by `now`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can
import canopen
from canopen.emcy import EMCY_STRUCT

SOD, RTSO, SO, OE, QSA, FAULT = 0x0250, 0x0231, 0x0233, 0x0237, 0x0217, 0x0218  # remote bit 9 set


class _NoTask:
    def stop(self) -> None: ...

    def update(self, data: Any) -> None: ...


class SlaveNetwork(canopen.Network):
    """A canopen Network on the slaves' end of the virtual bus, fed by hand (no Notifier thread), no timers."""

    def send_periodic(self, *args: Any, **kwargs: Any) -> Any:  # heartbeats are sent on the test's clock
        return _NoTask()

    def service(self) -> None:
        assert self.bus is not None
        while (msg := self.bus.recv(timeout=0)) is not None:
            self.notify(msg.arbitration_id, msg.data, msg.timestamp)


class Cia402Slave:
    """One drive: a canopen LocalNode from `eds`, a CiA 402 state machine and an ideal CSP follower."""

    def __init__(self, network: SlaveNetwork, node_id: int, eds: Path) -> None:
        self.network = network
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        network.add_node(self.node)
        network.subscribe(0, self._on_nmt)
        network.subscribe(0x80, self._on_sync)
        self.node.add_read_callback(self._read)
        self.id = node_id
        self.statusword = SOD
        self.position = 0  # counts
        self.torque = 0  # per mille
        self.velocity = 0
        self.error_code = 0
        self.controlwords: list[int] = []  # every controlword applied at a SYNC
        self.targets: list[dict[int, int]] = []  # every RPDO's mapped values at a SYNC, by index
        self.silent = False  # no heartbeat, no TPDO, no SDO answer effect on heartbeats
        self.skip_tpdo = 0  # SYNCs to let pass without a TPDO
        self.frozen = False  # statusword scripted: the state machine leaves it alone
        self.reset_needs_cycles = 1  # SYNCs the fault-reset bit must be seen low before its rising edge counts
        self._low_cycles = 0
        self.next_heartbeat = 0.0
        self.operational = False

    # canopen hooks
    def _read(self, index: int, subindex: int, od: Any) -> int | None:
        if index == 0x6061:  # mode display follows the mode written
            return int.from_bytes(self.node.get_data(0x6060, 0), "little", signed=True)
        return {0x6041: self.statusword, 0x6064: self.position, 0x6077: self.torque, 0x606C: self.velocity,
                0x603F: self.error_code}.get(index)  # fmt: skip

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if data[1] not in (0, self.id):
            return
        if data[0] == 0x01:  # start: the PDO configuration the master wrote is in force from now on
            self.node.rpdo.read()
            self.node.tpdo.read()
            self.node.rpdo.subscribe()
            self.operational = True
        elif data[0] in (0x80, 0x81, 0x82, 0x02):
            self.operational = False
            if data[0] in (0x81, 0x82) and not self.silent:  # canopen's NmtSlave does not announce a reset
                self.network.send_message(0x700 + self.id, [0])

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if not self.operational or self.silent:
            return
        rpdo = self.node.rpdo[1]
        if rpdo.enabled and rpdo.is_received:
            values = {var.index: var.raw for var in rpdo.map}
            self.targets.append(values)
            self._apply(values)
        tpdo = self.node.tpdo[1]
        if self.skip_tpdo > 0:
            self.skip_tpdo -= 1
            return
        for number in (1, 2):
            pdo_map = self.node.tpdo[number]
            if not pdo_map.enabled:
                continue
            for var in pdo_map.map:
                var.raw = self._read(var.index, var.subindex, None)
            pdo_map.transmit()
        del tpdo

    def _apply(self, values: dict[int, int]) -> None:
        cw = values[0x6040]
        previous = self.controlwords[-1] if self.controlwords else 0
        self.controlwords.append(cw)
        if self.statusword == OE and 0x607A in values:
            self.position = values[0x607A]
        if 0x6071 in values and self.statusword == OE:
            self.torque = values[0x6071]
        if self.frozen:
            return
        if self.statusword == FAULT:
            if cw & 0x80 and not previous & 0x80 and self._low_cycles >= self.reset_needs_cycles:
                self.statusword = SOD
                self.error_code = 0
            self._low_cycles = 0 if cw & 0x80 else self._low_cycles + 1
            return
        if self.statusword == QSA:
            if cw & 0x02 == 0:
                self.statusword = SOD
            return
        if cw & 0x02 == 0:  # disable voltage
            self.statusword = SOD
        elif cw & 0x0F == 0x06:
            self.statusword = RTSO
        elif cw & 0x0F == 0x07 and self.statusword in (RTSO, SO, OE):
            self.statusword = SO
        elif cw & 0x0F == 0x0F and self.statusword in (SO, OE):
            self.statusword = OE

    # test controls
    def fault(self, code: int, register: int = 0x01) -> None:
        """Enter FAULT and say why in an EMCY frame (canopen's struct)."""
        self.statusword = FAULT
        self.error_code = code
        self._low_cycles = 0
        self.network.send_message(0x80 + self.id, EMCY_STRUCT.pack(code, register, b"\x00" * 5))

    def heartbeat(self, now: float) -> None:
        period = self.node.sdo[0x1017].raw / 1000.0
        if self.silent or period <= 0.0 or now < self.next_heartbeat:
            return
        self.next_heartbeat = now + period
        state = 0x05 if self.operational else 0x7F
        self.network.send_message(0x700 + self.id, [state])


class Slaves:
    """The slaves' end of one virtual channel."""

    def __init__(self, channel: str, nodes: list[int], eds: Path) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.network = SlaveNetwork(self.bus)
        self.drives = [Cia402Slave(self.network, node, eds) for node in nodes]

    def service(self, now: float) -> None:
        self.network.service()
        for drive in self.drives:
            drive.heartbeat(now)

    def close(self) -> None:
        self.bus.shutdown()
