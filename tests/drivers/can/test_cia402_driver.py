"""cia402 against scripted canopen LocalNode slaves on an in-process virtual bus, in lockstep.

What the driver writes is read back with canopen's own objects: its SDO configuration from the LocalNode's data
store, its PDO layout from the PDO maps canopen reads from that store, its RPDOs decoded by those maps.
"""

from __future__ import annotations

import math
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest

from drivers.can.cia402.driver import (
    FAULT_FOLLOWING_ERROR,
    FAULT_NMT,
    FAULT_NOT_ENABLED,
    FAULT_STATE,
    Cia402Driver,
)
from drivers.can.cia402.review import interpolation_period
from drivers.can.params import Cia402Params
from hild.arrays import JointState, ServoCommand
from hild.hardware import HardwareContext, HardwareError, Homing
from tests.drivers.can.cia402_slave import OE, QSA, SO, SOD, Slaves

RATE = 500.0
DT = 1.0 / RATE
CONFIGS = Path(__file__).resolve().parents[3] / "configs"
EDS = CONFIGS / "cia402_generic.eds"


class Rig:
    """One cia402 driver and its scripted slaves on a private virtual channel, stepped in lockstep."""

    def __init__(self, nodes: dict[str, int], *, eds: Path = EDS, **params: Any) -> None:
        self.channel = f"cia402-{uuid.uuid4().hex[:10]}"
        self.events: list[tuple[str, str]] = []
        self.joints = tuple(nodes)
        raw = {
            "bus": {"interface": "virtual", **params.pop("bus", {}), "channel": self.channel},
            "eds": str(eds),
            "drives": {joint: {"node_id": node} for joint, node in nodes.items()},
            "reply_timeout_ms": 300,  # SDO answers under load; lockstep otherwise
            **params,
        }
        self.params = Cia402Params.model_validate(raw)
        context = HardwareContext(
            "arm", self.joints, CONFIGS, RATE, "sim", lambda level, msg: self.events.append((level, msg))
        )
        self.slaves = Slaves(self.channel, list(nodes.values()), eds)
        self.driver = Cia402Driver(context, self.params)
        self.driver.serve_while_waiting = self.serve
        self.now = 0.0
        self.t = 0.0
        self.state = JointState.zeros(len(nodes))
        self.command = ServoCommand.zeros(len(nodes))

    @property
    def drives(self) -> list[Any]:
        return self.slaves.drives

    def serve(self) -> None:
        self.now += 2e-4
        self.slaves.service(self.now)

    def start(self) -> None:
        self.driver.on_configure()
        self.driver.read(0.0, DT, self.state)
        self.driver.on_activate()

    def hold(self) -> None:
        self.command.position[:] = self.state.position
        self.command.velocity[:] = 0.0
        self.command.effort[:] = 0.0

    def cycle(self, count: int = 1) -> None:
        for _ in range(count):
            self.driver.write(self.t, DT, self.command)
            self.now += DT
            self.t += DT
            self.slaves.service(self.now)
            self.driver.read(self.t, DT, self.state)

    def inject(self, msg: can.Message) -> None:
        self.slaves.bus.send(msg)


@pytest.fixture
def rigs() -> Iterator[Any]:
    made: list[Rig] = []

    def build(*args: Any, **kwargs: Any) -> Rig:
        made.append(Rig(*args, **kwargs))
        return made[-1]

    yield build
    for rig in made:
        rig.driver.on_cleanup()
        rig.slaves.close()


def _sdo(rig: Rig, k: int, index: int, subindex: int | None = None) -> Any:
    """A value the driver wrote, read from the slave's data store through canopen's SDO server."""
    obj = rig.drives[k].node.sdo[index]
    return (obj if subindex is None else obj[subindex]).raw


def test_configure_writes_the_mode_layout_and_timing_into_the_drive(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.drives[1].position = 12345
    rig.driver.on_configure()
    rig.slaves.service(rig.now)  # the slaves take the NMT start
    for k in range(2):
        assert _sdo(rig, k, 0x6060) == 8  # CSP
        assert (_sdo(rig, k, 0x60C2, 1), _sdo(rig, k, 0x60C2, 2)) == (2, -3)  # 2 × 10⁻³ s
        assert _sdo(rig, k, 0x1006) == 2000  # µs, hild produces SYNC
        assert _sdo(rig, k, 0x1017) == 100
        node = rig.drives[k].node
        rpdo, tpdo = node.rpdo[1], node.tpdo[1]  # read back from the data store by canopen at NMT start
        assert [(v.index, v.length) for v in rpdo.map] == [(0x6040, 16), (0x607A, 32), (0x60B2, 16)]
        assert [(v.index, v.length) for v in tpdo.map] == [(0x6041, 16), (0x6064, 32), (0x6077, 16)]
        assert rpdo.enabled and tpdo.enabled and rpdo.trans_type == 1 and tpdo.trans_type == 1
        assert rpdo.cob_id == 0x200 + rig.drives[k].id and tpdo.cob_id == 0x180 + rig.drives[k].id
        assert not any(node.tpdo[n].enabled for n in (2, 3, 4))  # COB-ID bit 31
        assert not any(node.rpdo[n].enabled for n in (2, 3, 4))
        assert rig.drives[k].operational  # NMT start
    assert not any(t.name == "cia402-sdo" for t in threading.enumerate())  # the SDO worker is gone
    rig.driver.read(0.0, DT, rig.state)
    counts_per_rad = rig.driver.wiring[1].counts_per_rad
    assert rig.state.position[1] == pytest.approx(12345 / counts_per_rad)  # the first read is real
    assert rig.state.fresh.all() and not rig.state.fault.any()


def test_configured_limits_are_converted_through_the_scaling(rigs: Any) -> None:
    rig = rigs(
        {"hip": 3},
        quick_stop_option=6,
        drives={
            "hip": {
                "node_id": 3,
                "max_torque": 4.0,
                "following_error_window": 0.01,
                "following_error_timeout_ms": 20,
                "homing": {"method": 35, "offset": 0.5, "speed_switch": 1.0},
            }
        },
    )
    rig.driver.on_configure()
    w = rig.driver.wiring[0]
    assert _sdo(rig, 0, 0x6072) == round(4.0 * 1000.0 / w.rated_torque)
    assert _sdo(rig, 0, 0x6065) == round(0.01 * w.counts_per_rad)
    assert _sdo(rig, 0, 0x6066) == 20
    assert _sdo(rig, 0, 0x605A) == 6
    assert _sdo(rig, 0, 0x6098) == 35
    assert _sdo(rig, 0, 0x607C) == round(0.5 * w.counts_per_rad)
    assert _sdo(rig, 0, 0x6099, 1) == round(1.0 * w.velocity_per_rad_s)


def test_silent_node_at_configure_is_named(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.slaves.network.unsubscribe(0, rig.drives[1].node.nmt.on_command)  # never boots
    rig.drives[1].silent = True
    with pytest.raises(HardwareError, match=r"no boot-up or heartbeat.*knee \(node 4\)"):
        rig.driver.on_configure()
    assert rig.driver.link.bus is None


def test_activate_walks_to_operation_enabled_holding_the_actual_position(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.drives[0].position = 1000
    rig.drives[1].position = -2000
    rig.start()
    assert [d.statusword for d in rig.drives] == [OE, OE]
    for d, actual in zip(rig.drives, (1000, -2000), strict=True):
        assert [cw & 0x8F for cw in d.controlwords][:3] == [0x06, 0x07, 0x0F]  # shutdown, switch on, enable
        assert {t[0x607A] for t in d.targets} == {actual}  # aimed at where it is all along: no jump
    rig.hold()
    rig.cycle(10)
    assert [d.position for d in rig.drives] == [1000, -2000]
    assert rig.state.fresh.all() and not rig.state.fault.any()


def test_activate_names_a_drive_that_does_not_enable(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.driver.on_configure()
    rig.drives[1].frozen = True  # stays in SWITCH ON DISABLED whatever it is told
    with pytest.raises(HardwareError, match=r"knee \(node 4: SWITCH ON DISABLED"):
        rig.driver.on_activate()
    assert rig.drives[0].statusword == OE


def test_csp_targets_and_torque_offset_in_drive_units(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    w = rig.driver.wiring[0]
    rig.command.position[:] = 0.25
    rig.command.effort[:] = 1.5
    rig.cycle()
    last = rig.drives[0].targets[-1]  # decoded by canopen's RPDO map
    assert last[0x6040] == 0x0F
    assert last[0x607A] == round(0.25 * w.counts_per_rad)
    assert last[0x60B2] == round(1.5 * 1000.0 / w.rated_torque)
    rig.cycle()
    assert rig.state.position[0] == pytest.approx(0.25, abs=1.0 / w.counts_per_rad)


def test_velocity_is_derived_from_sync_latched_positions(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.cycle(2)
    w = rig.driver.wiring[0]
    step = 100  # counts per SYNC
    for _ in range(5):
        rig.command.position[:] = (rig.drives[0].position + step) / w.counts_per_rad
        rig.cycle()
    # the drive's position moves `step` each SYNC, one SYNC per 2 ms
    assert rig.state.velocity[0] == pytest.approx(step / w.counts_per_rad / DT, rel=1e-6)


def test_cst_applies_the_servo_law_on_the_latest_sample(rigs: Any) -> None:
    """CST: target torque = kp·(p − q) + kd·(v − q̇) + effort, from the reading of the last SYNC (hold works)."""
    rig = rigs({"hip": 3}, mode="cst")
    rig.start()
    rig.cycle(2)
    w = rig.driver.wiring[0]
    q, dq = rig.state.position[0], rig.state.velocity[0]
    rig.command.position[:] = q + 0.01
    rig.command.velocity[:] = dq + 0.5
    rig.command.kp[:] = 200.0
    rig.command.kd[:] = 2.0
    rig.command.effort[:] = 0.5
    rig.cycle()
    expected = 200.0 * 0.01 + 2.0 * 0.5 + 0.5  # N·m
    assert rig.drives[0].targets[-1][0x6071] == round(expected * 1000.0 / w.rated_torque)
    rig.command.position[:] = math.nan  # a NaN anywhere: no torque, never a wrapped value
    rig.cycle()
    assert rig.drives[0].targets[-1][0x6071] == 0


def test_cst_sends_torque_and_its_range_is_clamped_not_wrapped(rigs: Any) -> None:
    rig = rigs({"hip": 3}, mode="cst")
    rig.start()
    w = rig.driver.wiring[0]
    assert sorted(rig.driver.COMMAND_FIELDS) == ["effort", "kd", "kp", "position", "velocity"]
    assert rig.driver.gains_applied() == [True]
    rig.command.kp[:] = rig.command.kd[:] = 0.0
    rig.command.effort[:] = 2.0
    rig.cycle()
    assert rig.drives[0].targets[-1][0x6071] == round(2.0 * 1000.0 / w.rated_torque)
    rig.command.effort[:] = 1e6  # far beyond int16 per mille
    rig.cycle(3)
    assert rig.drives[0].targets[-1][0x6071] == 32767
    assert sum("outside" in msg for _, msg in rig.events) == 1  # one event per episode


def test_emcy_becomes_a_named_fault_and_reset_confirms_from_the_statusword(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.start()
    rig.hold()
    rig.cycle(3)
    rig.drives[1].fault(0x3210)
    rig.cycle(2)
    code = int(rig.state.fault[1])
    assert rig.state.fault[0] == 0
    assert code & 0xFFFF == 0x3210 and code & FAULT_STATE
    assert "DC-link over-voltage (0x3210)" in rig.driver.describe_fault(code)
    rig.drives[1].reset_needs_cycles = 1
    n = len(rig.drives[1].controlwords)
    rig.driver.clear_faults()
    assert rig.driver.confirming()
    for _ in range(100):
        if not rig.driver.confirming():
            break
        rig.cycle()
    assert not rig.driver.confirming() and rig.driver.persistent_errors() == {}
    sent = [cw & 0x80 for cw in rig.drives[1].controlwords[n:]]
    assert sent[0] == 0 and 0x80 in sent  # the rising edge: bit 7 low, then high
    assert rig.drives[1].statusword == SOD  # out of FAULT, and not re-enabled
    rig.cycle(5)
    assert rig.drives[1].statusword == SOD
    assert int(rig.state.fault[1]) & FAULT_NOT_ENABLED  # it says so until the operator enables it
    assert rig.driver.enable("knee") == ["knee"]
    rig.cycle(5)
    assert rig.drives[1].statusword == OE and rig.state.fault[1] == 0


def test_a_fault_that_stays_is_persistent(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.drives[0].fault(0x7121)
    rig.drives[0].frozen = True
    rig.cycle(2)
    rig.driver.clear_faults()
    for _ in range(400):
        if not rig.driver.confirming():
            break
        rig.cycle()
    assert not rig.driver.confirming()
    assert "motor blocked (0x7121)" in rig.driver.persistent_errors()["hip"]


def test_leaving_operation_enabled_is_a_fault_and_quick_stop_is_never_left(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.hold()
    rig.drives[0].statusword = QSA
    rig.cycle(3)
    code = int(rig.state.fault[0])
    assert code & FAULT_NOT_ENABLED
    assert "QUICK STOP ACTIVE" in rig.driver.describe_fault(code)
    assert rig.drives[0].statusword == QSA  # no controlword took it out
    # the first cycle's controlword went out before the TPDO said QSA; from then on only "quick stop"
    assert {cw & 0x8F for cw in rig.drives[0].controlwords[-2:]} == {0x02}


def test_csp_following_error_bit_is_a_fault(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.hold()
    rig.drives[0].statusword = OE | 1 << 13
    rig.cycle(2)
    assert int(rig.state.fault[0]) & FAULT_FOLLOWING_ERROR
    assert "following error" in rig.driver.describe_fault(int(rig.state.fault[0]))


def test_missed_tpdo_is_not_fresh_that_cycle(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.start()
    rig.hold()
    rig.cycle(2)
    rig.drives[0].skip_tpdo = 1
    rig.cycle()
    assert list(rig.state.fresh) == [False, True]
    rig.cycle()
    assert rig.state.fresh.all()


def test_heartbeat_loss_is_stale_within_its_bound(rigs: Any) -> None:
    rig = rigs({"hip": 3}, heartbeat_ms=20)  # timeout: 3 periods = 60 ms
    rig.start()
    rig.hold()
    rig.cycle(10)
    assert rig.state.fresh.all()
    drive = rig.drives[0]
    drive.heartbeat = lambda now: None  # type: ignore[method-assign]  # TPDOs go on, the heartbeat stops
    stale_after = None
    for i in range(60):
        rig.cycle()
        if not rig.state.fresh[0]:
            stale_after = (i + 1) * DT
            break
    assert stale_after is not None and stale_after <= 0.06 + 0.02 + DT


def test_a_rebooted_node_is_a_fault(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.cycle(2)
    rig.inject(can.Message(arbitration_id=0x703, data=[0x00], is_extended_id=False))  # boot-up
    rig.cycle()
    code = int(rig.state.fault[0])
    assert code & FAULT_NMT and "left NMT OPERATIONAL" in rig.driver.describe_fault(code)


def test_bad_frames_are_counted(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.inject(can.Message(arbitration_id=0x183, data=[1, 2], is_extended_id=False))  # short TPDO
    rig.inject(can.Message(arbitration_id=0x123, data=[1], is_extended_id=False))
    rig.cycle()
    stats = rig.driver.statistics
    assert stats["ignored wrong length"] == 1 and stats["ignored unknown id"] == 1


def test_deactivate_confirms_switch_on_disabled(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.start()
    rig.cycle(2)
    rig.driver.on_deactivate()
    assert [d.statusword for d in rig.drives] == [SOD, SOD]
    assert not [e for e in rig.events if e[0] == "error"]


def test_deactivate_reports_a_drive_that_stays_enabled(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.start()
    rig.drives[0].frozen = True
    rig.driver.on_deactivate()
    assert rig.drives[1].statusword == SOD
    assert any("hip: not confirmed SWITCH ON DISABLED" in msg for level, msg in rig.events if level == "error")


def test_hold_on_deactivate_leaves_them_enabled(rigs: Any) -> None:
    rig = rigs({"hip": 3}, on_deactivate="hold")
    rig.start()
    rig.driver.on_deactivate()
    assert rig.drives[0].statusword == OE


def test_homing_switches_mode_by_sdo_and_starts_on_a_rising_edge(rigs: Any) -> None:
    rig = rigs({"hip": 3}, drives={"hip": {"node_id": 3, "homing": {"method": 37}}})
    rig.start()
    rig.hold()
    n = len(rig.drives[0].controlwords)
    rig.driver.start_homing("hip")
    rig.cycle(2)
    assert _sdo(rig, 0, 0x6060) == 6
    assert rig.driver.homing("hip") == (Homing.RUNNING, "")
    rig.cycle(3)
    bits = [cw & 0x10 for cw in rig.drives[0].controlwords[n:]]
    rise = bits.index(0x10)
    assert rise > 0 and bits[rise - 1] == 0 and bits[-1] == 0x10  # low in homing mode first, then high
    rig.drives[0].statusword = OE | 1 << 12 | 1 << 10  # attained, target reached
    outcome = Homing.RUNNING
    for _ in range(10):
        rig.cycle()
        outcome, _detail = rig.driver.homing("hip")
        if outcome is not Homing.RUNNING:
            break
        assert rig.drives[0].controlwords[-1] & 0x100 or _sdo(rig, 0, 0x6060) == 6  # halted while returning
    assert outcome is Homing.ATTAINED
    assert _sdo(rig, 0, 0x6060) == 8  # back in CSP before the end is reported
    assert rig.driver.homing("hip") == (Homing.IDLE, "")


def test_interpolation_period_encoding() -> None:
    assert interpolation_period(0.002) == (2, -3)
    assert interpolation_period(0.001) == (1, -3)
    assert interpolation_period(0.0005) == (5, -4)
    assert interpolation_period(1 / 300) is None


def test_bit_13_is_a_following_error_only_in_operation_enabled(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.drives[0].frozen = True
    rig.drives[0].statusword = SO | 1 << 13
    rig.cycle()
    code = int(rig.state.fault[0])
    assert not code & FAULT_FOLLOWING_ERROR
    assert code & FAULT_NOT_ENABLED and "SWITCHED ON" in rig.driver.describe_fault(code)


def test_velocity_pdo_is_read_and_both_tpdos_make_a_fresh_reading(rigs: Any) -> None:
    rig = rigs({"hip": 3}, velocity_feedback="pdo")
    rig.driver.on_configure()
    rig.slaves.service(rig.now)
    node = rig.drives[0].node
    assert [v.index for v in node.tpdo[2].map] == [0x606C] and node.tpdo[2].trans_type == 1
    rig.driver.read(0.0, DT, rig.state)
    rig.driver.on_activate()
    rig.hold()
    rig.drives[0].velocity = 5000
    rig.cycle(2)
    w = rig.driver.wiring[0]
    assert rig.state.velocity[0] == pytest.approx(5000 / w.velocity_per_rad_s)
    assert rig.state.fresh.all()


def test_fd_maps_velocity_and_error_code_into_the_one_tpdo(rigs: Any) -> None:
    rig = rigs({"hip": 3}, bus={"fd": True})
    rig.driver.on_configure()
    rig.slaves.service(rig.now)
    tpdo = rig.drives[0].node.tpdo[1]
    assert [v.index for v in tpdo.map] == [0x6041, 0x6064, 0x6077, 0x606C, 0x603F]
    rig.driver.read(0.0, DT, rig.state)
    rig.driver.on_activate()
    rig.hold()
    rig.drives[0].velocity = -3000
    rig.drives[0].error_code = 0x4310
    rig.cycle(2)
    w = rig.driver.wiring[0]
    assert rig.state.velocity[0] == pytest.approx(-3000 / w.velocity_per_rad_s)
    assert int(rig.state.fault[0]) & 0xFFFF == 0x4310
    assert "excess drive temperature (0x4310)" in rig.driver.describe_fault(int(rig.state.fault[0]))


def test_enable_takes_a_quick_stopped_drive_through_switch_on_disabled(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.hold()
    rig.drives[0].statusword = QSA
    rig.cycle(5)
    assert rig.drives[0].statusword == QSA  # never left by itself
    n = len(rig.drives[0].controlwords)
    rig.driver.enable("hip")
    rig.cycle(6)
    assert rig.drives[0].statusword == OE
    assert [cw & 0x8F for cw in rig.drives[0].controlwords[n : n + 4]] == [0x00, 0x06, 0x07, 0x0F]


def test_an_sdo_abort_at_configure_names_the_drive(rigs: Any) -> None:
    from canopen.sdo import SdoAbortedError

    rig = rigs({"hip": 3, "knee": 4})

    def refuse(index: int, subindex: int, od: Any, data: bytes) -> None:
        if index == 0x6060:
            raise SdoAbortedError(0x06090030)

    rig.drives[1].node.add_write_callback(refuse)
    with pytest.raises(HardwareError, match=r"knee \(node 4\): SDO configuration failed: .*0x06090030"):
        rig.driver.on_configure()
    assert rig.driver.link.bus is None
    assert not any(t.name == "cia402-sdo" for t in threading.enumerate())


def test_external_sync_sends_only_rpdos_and_reads_what_the_other_masters_sync_triggers(rigs: Any) -> None:
    rig = rigs({"hip": 3}, sync="external")
    rig.driver.on_configure()
    rig.slaves.service(rig.now)
    assert _sdo(rig, 0, 0x1006) == 0  # hild does not produce SYNC: the period object is the other master's
    rig.driver.read(0.0, DT, rig.state)
    drive = rig.drives[0]

    def other_master_sync() -> None:  # the other master's SYNC, as the slave hears it
        drive._on_sync(0x80, bytearray(), rig.now)

    rig.driver.serve_while_waiting = lambda: (rig.serve(), other_master_sync())
    rig.driver.on_activate()
    assert drive.statusword == OE
    assert rig.driver.syncs == 0
    w = rig.driver.wiring[0]
    for _ in range(5):
        rig.command.position[:] = (drive.position + 50) / w.counts_per_rad
        rig.driver.write(rig.t, DT, rig.command)
        rig.slaves.service(rig.now)
        other_master_sync()
        rig.t += DT
        rig.driver.read(rig.t, DT, rig.state)
    assert rig.driver.syncs == 0  # only RPDOs went out
    assert rig.state.fresh.all()
    assert rig.state.velocity[0] == pytest.approx(50 / w.counts_per_rad / DT, rel=1e-6)  # over the cycle time


def test_a_nan_position_target_holds_the_actual_position_and_says_so(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.drives[0].position = 777
    rig.start()
    rig.command.position[:] = float("nan")
    rig.cycle(3)
    assert rig.drives[0].targets[-1][0x607A] == 777
    assert sum("0x607a target nan" in msg for _, msg in rig.events) == 1


def test_stop_homing_halts_and_reports_stopped_once_cyclic_again(rigs: Any) -> None:
    rig = rigs({"hip": 3}, drives={"hip": {"node_id": 3, "homing": {"method": 37}}})
    rig.start()
    rig.hold()
    rig.driver.start_homing("hip")
    rig.cycle(4)
    rig.driver.stop_homing("hip")
    assert rig.driver.homing("hip") == (Homing.RUNNING, "")  # not cyclic yet
    rig.cycle()
    assert rig.drives[0].controlwords[-1] & 0x100  # halt
    rig.cycle(2)
    assert rig.driver.homing("hip") == (Homing.FAILED, "stopped")
    assert _sdo(rig, 0, 0x6060) == 8
    rig.cycle()
    assert rig.drives[0].controlwords[-1] == 0x0F  # operating on the command again


def test_a_drive_that_never_answers_the_mode_request_fails_the_homing(rigs: Any) -> None:
    rig = rigs({"hip": 3}, drives={"hip": {"node_id": 3, "homing": {"method": 37}}})
    rig.start()
    rig.hold()
    rig.slaves.network.unsubscribe(0x603)  # the SDO server goes deaf
    rig.driver.start_homing("hip")
    outcome, detail = Homing.RUNNING, ""
    for _ in range(400):
        rig.cycle()
        outcome, detail = rig.driver.homing("hip")
        if outcome is not Homing.RUNNING:
            break
    assert outcome is Homing.FAILED
    assert "did not confirm its cyclic mode" in detail and "did not answer the homing-mode request" in detail


def test_a_drive_that_cannot_map_the_torque_offset_gets_a_layout_without_it(rigs: Any, tmp_path: Path) -> None:
    text = EDS.read_text()
    section = text.index("[60B2]")
    end = text.index("[", section + 1)
    eds = tmp_path / "no_offset.eds"
    eds.write_text(text[:section] + text[section:end].replace("PDOMapping=0x1", "PDOMapping=0x0") + text[end:])
    rig = rigs({"hip": 3}, eds=eds)
    assert sorted(rig.driver.COMMAND_FIELDS) == ["position"]  # effort would be ignored: not offered
    rig.driver.on_configure()
    rig.slaves.service(rig.now)
    assert [v.index for v in rig.drives[0].node.rpdo[1].map] == [0x6040, 0x607A]
    rig.driver.read(0.0, DT, rig.state)
    rig.driver.on_activate()
    rig.command.position[:] = 0.01
    rig.command.effort[:] = 3.0
    rig.cycle()
    assert set(rig.drives[0].targets[-1]) == {0x6040, 0x607A}
    findings = Cia402Driver.review_files(rig.params, ["hip"], RATE, CONFIGS)
    assert [(f.level, f.message) for f in findings] == [
        ("warning", "hip: the EDS does not let 0x60b2 be mapped: effort (the torque offset) is not applied")
    ]
