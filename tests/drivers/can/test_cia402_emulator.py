"""The emulated CiA 402 drive's CANopen side, driven by `canopen`'s own master: SDO, NMT, heartbeat, PDOs.

See tests/drivers/can/cia402_rig.py for how time passes (only in `advance`, in sim time).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

import can
import canopen
import pytest
from canopen.nmt import NmtError
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.can.emulator.canopen_node import NmtState
from tests.drivers.can.cia402_rig import Cia402Rig, operational, wait_until

NODE = 3


@pytest.fixture
def rig() -> Iterator[Cia402Rig]:
    made = Cia402Rig((NODE,))
    yield made
    made.close()


# ---- SDO ------------------------------------------------------------------------------------------------------------


def test_sdo_upload_and_download_of_dictionary_objects(rig: Cia402Rig) -> None:
    sdo = rig.node.sdo
    assert sdo[0x1008].raw == "hild generic CiA 402 drive"  # segmented upload (more than 4 bytes)
    assert sdo[0x1000].raw == 0x20192
    assert sdo[0x6076].raw == 10000  # rated torque from the EDS
    assert sdo[0x6041].raw & 0x4F == 0x40  # Switch On Disabled after boot
    sdo[0x6065].raw = 4321
    assert sdo[0x6065].raw == 4321
    assert rig.firmware.following_window == 4321  # the drive runs on what was written
    sdo[0x6072].raw = 500
    assert rig.firmware.max_torque == pytest.approx(5.0)  # ‰ of the 10 N·m rated torque


def test_sdo_aborts_with_the_standard_codes(rig: Cia402Rig) -> None:
    sdo = rig.node.sdo
    with pytest.raises(SdoAbortedError) as missing:
        sdo.upload(0x2000, 0)
    assert missing.value.code == 0x06020000  # object does not exist
    with pytest.raises(SdoAbortedError) as missing_sub:
        sdo.upload(0x1018, 7)
    assert missing_sub.value.code == 0x06090011  # sub-index does not exist
    with pytest.raises(SdoAbortedError) as read_only:
        sdo.download(0x6041, 0, b"\x00\x00")
    assert read_only.value.code == 0x06010002  # write to a read-only object
    with pytest.raises(SdoAbortedError) as unsupported:
        sdo[0x6060].raw = 1  # profile position: not in 0x6502
    assert unsupported.value.code == 0x06090030
    assert sdo[0x6061].raw == 0  # the display stayed
    sdo[0x6060].raw = 10
    assert sdo[0x6061].raw == 10  # a supported mode is displayed at once
    with pytest.raises(SdoAbortedError) as valid:
        sdo[0x1A01][1].raw = 0x60640020  # TPDO2 is valid: its mapping is locked
    assert valid.value.code == 0x08000022
    sdo[0x1801][1].raw = (0x280 + NODE) | 1 << 31
    with pytest.raises(SdoAbortedError) as unmappable:
        sdo[0x1A01][1].raw = 0x60760020  # rated torque is not PDO-mappable
    assert unmappable.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as length:
        sdo[0x1A01][1].raw = 0x60640010  # 16 bits of a 32-bit object
    assert length.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as moved:
        sdo[0x1800][1].raw = 0x1F0  # a valid PDO's COB-ID changes only through invalid
    assert moved.value.code == 0x06090030


# ---- NMT and heartbeat ----------------------------------------------------------------------------------------------


def test_nmt_boot_up_state_changes_and_heartbeat(rig: Cia402Rig) -> None:
    booted = rig.booted_again()
    rig.on_drive(rig.firmware.reboot)
    wait_until(booted, "the boot-up frame")  # (0x700 + n, [0x00])
    assert rig.node.nmt.state == "PRE-OPERATIONAL"

    rig.node.sdo[0x1017].raw = 50
    rig.sniffed()
    rig.advance(1.0)
    beats = [m for m in rig.sniffed() if m.arbitration_id == 0x700 + NODE]
    assert 19 <= len(beats) <= 21  # every 50 ms of sim time
    assert {bytes(m.data) for m in beats} == {bytes([NmtState.PRE_OPERATIONAL])}

    operational(rig)
    rig.advance(0.1)
    wait_until(lambda: rig.node.nmt.state == "OPERATIONAL", "the heartbeat to carry OPERATIONAL")

    rig.node.nmt.state = "STOPPED"
    rig.advance(0.1)
    wait_until(lambda: rig.node.nmt.state == "STOPPED", "the heartbeat to carry STOPPED")
    rig.node.sdo.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(SdoCommunicationError):  # nothing but NMT in stopped
        rig.node.sdo.upload(0x1000, 0)

    rig.node.nmt.state = "PRE-OPERATIONAL"
    wait_until(lambda: rig.firmware.nmt_state == NmtState.PRE_OPERATIONAL, "pre-operational")
    rig.node.sdo.RESPONSE_TIMEOUT = 2.0
    assert rig.node.sdo[0x1000].raw == 0x20192


def test_reset_node_restores_the_eds_defaults_and_reset_communication_only_the_communication_area(
    rig: Cia402Rig,
) -> None:
    sdo = rig.node.sdo
    sdo[0x1017].raw = 20
    sdo[0x6065].raw = 777
    booted = rig.booted_again()
    rig.node.nmt.send_command(0x82)  # reset communication
    wait_until(booted, "boot-up after reset communication")
    assert sdo[0x1017].raw == 0  # communication area back to the EDS
    assert sdo[0x6065].raw == 777  # the application area kept
    booted = rig.booted_again()
    rig.node.nmt.send_command(0x81)  # reset node
    wait_until(booted, "boot-up after reset node")
    assert sdo[0x6065].raw == 0xFFFFFFFF


def test_no_heartbeat_when_the_producer_time_is_zero(rig: Cia402Rig) -> None:
    rig.node.sdo[0x1017].raw = 0
    rig.sniffed()
    rig.advance(0.5)
    assert not [m for m in rig.sniffed() if m.arbitration_id == 0x700 + NODE]
    with pytest.raises(NmtError):
        rig.node.nmt.wait_for_heartbeat(timeout=0.2)


# ---- PDOs -----------------------------------------------------------------------------------------------------------


def configure_pdo(maps: canopen.pdo.PdoBase, variables: tuple[int, ...], transmission: int) -> canopen.pdo.PdoMap:
    """The first PDO of ``maps`` (a node's TPDOs or RPDOs) mapped to ``variables``, on every `transmission`th SYNC."""
    maps.read()
    pdo = maps[1]
    pdo.clear()
    for index in variables:
        pdo.add_variable(index)
    pdo.trans_type = transmission
    pdo.enabled = True
    pdo.save()
    return pdo


def configure_feedback(rig: Cia402Rig, transmission: int = 1) -> canopen.pdo.PdoMap:
    """TPDO1: statusword, position actual, torque actual (8 bytes)."""
    return configure_pdo(rig.node.tpdo, (0x6041, 0x6064, 0x6077), transmission)


def configure_command(rig: Cia402Rig, transmission: int = 1) -> canopen.pdo.PdoMap:
    """RPDO1: controlword and target position (6 bytes)."""
    return configure_pdo(rig.node.rpdo, (0x6040, 0x607A), transmission)


class Received:
    """Counts a PDO's receptions (canopen's wait_for_reception can miss a frame that came before it waited)."""

    def __init__(self, pdo: canopen.pdo.PdoMap) -> None:
        self.count = 0
        pdo.add_callback(self._on)

    def _on(self, pdo: canopen.pdo.PdoMap) -> None:
        self.count += 1


def test_tpdo_configured_by_sdo_sends_values_sampled_at_sync(rig: Cia402Rig) -> None:
    tpdo = configure_feedback(rig)
    received = Received(tpdo)
    operational(rig)
    cpr = rig.firmware.wiring.counts_per_rad

    rig.on_drive(lambda: rig.plant.positions.__setitem__(0, 0.5))
    rig.advance(0.001)
    rig.network.sync.transmit()
    wait_until(lambda: received.count == 1, "the TPDO after SYNC")
    assert tpdo["Position actual value"].raw == pytest.approx(0.5 * cpr, abs=2)
    assert tpdo["Statusword"].raw & 0x4F == 0x40

    rig.on_drive(lambda: rig.plant.positions.__setitem__(0, -0.25))
    rig.advance(0.05)
    assert received.count == 1  # no SYNC, no TPDO
    assert tpdo["Position actual value"].raw == pytest.approx(0.5 * cpr, abs=2)
    rig.network.sync.transmit()
    wait_until(lambda: received.count == 2, "the second TPDO")
    assert tpdo["Position actual value"].raw == pytest.approx(-0.25 * cpr, abs=2)


def test_tpdo_of_type_n_goes_out_on_every_nth_sync_and_not_before_operational(rig: Cia402Rig) -> None:
    tpdo = configure_feedback(rig, transmission=3)
    received = Received(tpdo)
    rig.sniffed()
    rig.network.sync.transmit()
    rig.network.sync.transmit()
    rig.network.sync.transmit()
    wait_until(lambda: rig.firmware.counters["sync"] >= 3, "three SYNCs at the drive")
    assert received.count == 0  # pre-operational: no PDOs
    operational(rig)
    for k in range(9):
        rig.network.sync.transmit()
        wait_until(lambda k=k: rig.firmware.counters["sync"] >= 4 + k, "the SYNC at the drive")
    wait_until(lambda: received.count == 3, "3 TPDOs for 9 SYNCs")
    rig.advance(0.01)
    assert received.count == 3


def test_rpdo_of_a_synchronous_type_is_applied_at_the_next_sync_and_255_on_reception(rig: Cia402Rig) -> None:
    rpdo = configure_command(rig, transmission=1)
    operational(rig)
    rpdo["Controlword"].raw = 0x06
    rpdo["Target position"].raw = 12345
    handled = rig.firmware.counters["handled"]
    rpdo.transmit()
    wait_until(lambda: rig.firmware.counters["handled"] > handled, "the RPDO at the drive")
    assert rig.firmware.target_position == 0
    assert rig.firmware.state == "SWITCH ON DISABLED"
    rig.network.sync.transmit()
    wait_until(lambda: rig.firmware.target_position == 12345, "the RPDO applied at SYNC")
    assert rig.firmware.state == "READY TO SWITCH ON"

    rig.node.nmt.state = "PRE-OPERATIONAL"
    wait_until(lambda: rig.firmware.nmt_state == NmtState.PRE_OPERATIONAL, "pre-operational")
    rpdo.trans_type = 255
    rpdo.save()
    operational(rig)
    rpdo["Target position"].raw = -500
    rpdo.transmit()
    wait_until(lambda: rig.firmware.target_position == -500, "the type-255 RPDO applied on reception")


def test_wrong_length_rpdo_is_ignored_and_counted(rig: Cia402Rig) -> None:
    configure_command(rig, transmission=255)
    operational(rig)
    rig.network.send_message(0x200 + NODE, struct.pack("<Hi", 0x06, 99) + b"\x00")  # 7 bytes for a 6-byte map
    wait_until(lambda: rig.firmware.counters["wrong_length"] == 1, "the wrong-length count")
    assert rig.firmware.target_position == 0
    assert rig.firmware.state == "SWITCH ON DISABLED"


def test_invalid_pdo_cob_id_switches_the_pdo_off(rig: Cia402Rig) -> None:
    tpdo = configure_feedback(rig)
    received = Received(tpdo)
    rig.node.sdo[0x1800][1].raw = (0x180 + NODE) | 1 << 31
    operational(rig)
    rig.network.sync.transmit()
    wait_until(lambda: rig.firmware.counters["sync"] == 1, "the SYNC at the drive")
    rig.advance(0.01)
    assert received.count == 0


def test_a_mapping_over_8_bytes_goes_out_as_a_can_fd_frame(rig: Cia402Rig) -> None:
    rig.node.tpdo.read()
    tpdo = rig.node.tpdo[2]
    tpdo.clear()
    for index in (0x6041, 0x6064, 0x606C, 0x6077, 0x6061):
        tpdo.add_variable(index)
    tpdo.trans_type = 1
    tpdo.enabled = True
    tpdo.save()
    operational(rig)
    rig.sniffed()
    rig.network.sync.transmit()

    seen: list[can.Message] = []

    def fd_frame() -> can.Message | None:
        seen.extend(rig.sniffed())
        return next((m for m in seen if m.arbitration_id == 0x280 + NODE), None)

    frame = wait_until(fd_frame, "the TPDO2 frame")
    assert frame.is_fd and len(frame.data) == 16  # 2 + 4 + 4 + 2 + 1 = 13 bytes, padded to a valid FD length
    wait_until(lambda: tpdo.is_received, "canopen's decoding of TPDO2")
    assert tpdo["Modes of operation display"].raw == 0
    assert tpdo["Statusword"].raw & 0x4F == 0x40


def test_an_fd_rpdo_padded_to_a_valid_length_is_applied(rig: Cia402Rig) -> None:
    rig.node.rpdo.read()
    rpdo = rig.node.rpdo[2]
    rpdo.clear()
    for index in (0x6040, 0x607A, 0x60B1, 0x60B2, 0x6060):  # 13 bytes
        rpdo.add_variable(index)
    rpdo.trans_type = 255
    rpdo.enabled = True
    rpdo.save()
    operational(rig)
    data = struct.pack("<HiihB", 0x06, 4242, 7, -3, 10).ljust(16, b"\x00")
    rig.network.bus.send(can.Message(arbitration_id=0x300 + NODE, data=data, is_extended_id=False, is_fd=True))
    wait_until(lambda: rig.firmware.target_position == 4242, "the FD RPDO applied")
    assert (rig.firmware.velocity_offset, rig.firmware.torque_offset, rig.firmware.mode_display) == (7, -3, 10)
    assert rig.firmware.state == "READY TO SWITCH ON"
    rig.network.bus.send(can.Message(arbitration_id=0x300 + NODE, data=data[:14], is_extended_id=False, is_fd=True))
    wait_until(lambda: rig.firmware.counters["wrong_length"] == 1, "a 14-byte frame counted as the wrong length")


def test_nmt_and_sync_broadcasts_reach_every_drive_on_the_bus() -> None:
    rig = Cia402Rig((5, 6))
    try:
        received = []
        for node in rig.nodes:
            node.tpdo.read()
            tpdo = node.tpdo[1]
            tpdo.clear()
            tpdo.add_variable(0x6064)
            tpdo.trans_type = 1
            tpdo.enabled = True
            tpdo.save()
            received.append(Received(tpdo))
        rig.network.nmt.send_command(0x01)  # start, node 0: every node
        wait_until(lambda: all(fw.nmt_state == NmtState.OPERATIONAL for fw in rig.firmwares), "both operational")
        rig.network.sync.transmit()
        wait_until(lambda: [r.count for r in received] == [1, 1], "a TPDO from each drive")
    finally:
        rig.close()


def test_a_silent_drive_sends_no_heartbeat_and_answers_nothing(rig: Cia402Rig) -> None:
    rig.node.sdo[0x1017].raw = 20
    rig.on_drive(lambda: setattr(rig.firmware, "silent", True))
    rig.sniffed()
    rig.advance(0.2)
    assert not [m for m in rig.sniffed() if m.arbitration_id == 0x700 + NODE]
    rig.node.sdo.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(SdoCommunicationError):
        rig.node.sdo.upload(0x1000, 0)
    rig.on_drive(lambda: setattr(rig.firmware, "silent", False))
    rig.advance(0.1)
    assert len([m for m in rig.sniffed() if m.arbitration_id == 0x700 + NODE]) >= 4


def test_a_glitch_corrupts_the_reported_position_not_the_law(rig: Cia402Rig) -> None:
    tpdo = configure_feedback(rig)
    received = Received(tpdo)
    operational(rig)
    cpr = rig.firmware.wiring.counts_per_rad
    rig.on_drive(lambda: rig.firmware.glitch.set(0, offset=0.2))
    rig.network.sync.transmit()
    wait_until(lambda: received.count == 1, "the TPDO")
    assert tpdo["Position actual value"].raw == pytest.approx(0.2 * cpr, abs=2)
    assert rig.plant.positions[0] == 0.0
    assert rig.node.sdo[0x60F4].raw == 0  # the drive's own following error sees the truth


def test_event_driven_tpdo_goes_out_on_its_event_timer(rig: Cia402Rig) -> None:
    rig.node.tpdo.read()
    tpdo = rig.node.tpdo[3]
    tpdo.clear()
    tpdo.add_variable(0x6041)
    tpdo.trans_type = 254
    tpdo.event_timer = 10
    tpdo.enabled = True
    tpdo.save()
    operational(rig)
    rig.sniffed()
    rig.advance(0.1)
    frames = [m for m in rig.sniffed() if m.arbitration_id == 0x380 + NODE]
    assert 9 <= len(frames) <= 11  # every 10 ms of sim time, no SYNC needed
    assert {struct.unpack("<H", m.data)[0] & 0x4F for m in frames} == {0x40}


def test_acyclic_synchronous_tpdo_goes_out_at_a_sync_only_when_its_data_changed(rig: Cia402Rig) -> None:
    tpdo = configure_feedback(rig, transmission=0)
    received = Received(tpdo)
    operational(rig)

    def tpdos_after_sync(count: int) -> int:
        """TPDO1 frames on the bus once the drive has fully served SYNC number `count`."""
        rig.network.sync.transmit()
        wait_until(lambda: rig.firmware.counters["sync"] == count, f"SYNC {count} at the drive")
        rig.on_drive(lambda: None)  # that service is over: its frames are on the bus
        return len([m for m in rig.sniffed() if m.arbitration_id == 0x180 + NODE])

    rig.sniffed()
    assert tpdos_after_sync(1) == 1
    assert tpdos_after_sync(2) == 0
    assert tpdos_after_sync(3) == 0
    rig.node.sdo[0x6040].raw = 0x06  # Ready To Switch On: the statusword changes
    assert tpdos_after_sync(4) == 1
    wait_until(lambda: received.count == 2, "canopen's decoding of both")
    assert tpdo["Statusword"].raw & 0x6F == 0x21
