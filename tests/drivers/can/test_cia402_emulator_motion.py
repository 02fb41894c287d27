"""The emulated CiA 402 drive's profile side, driven by `canopen`'s own master: the 402 state machine, the cyclic
synchronous modes moving the plant, following error, injected faults, reboot, the watchdog and homing.

See tests/drivers/can/cia402_rig.py for how time passes (only in `advance`, in sim time).
"""

from __future__ import annotations

import math
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import canopen
import pytest
from canopen.profiles.p402 import BaseNode402, State402

from drivers.can.emulator.canopen_node import NmtState
from drivers.can.emulator.runtime import build_runtime, describe
from drivers.can.params import Cia402Params
from hild.config.loader import LoadedConfig
from hild.config.model import RobotConfig
from tests.conftest import CONFIGS
from tests.drivers.can.cia402_rig import EDS, Cia402Rig, operational, wait_until

NODE = 3


@pytest.fixture
def rig() -> Iterator[Cia402Rig]:
    made = Cia402Rig((NODE,))
    yield made
    made.close()


def command_pdo(rig: Cia402Rig) -> canopen.pdo.PdoMap:
    """RPDO1 of type 1: controlword, target position; applied at the next SYNC."""
    rig.node.rpdo.read()
    rpdo = rig.node.rpdo[1]
    rpdo.clear()
    rpdo.add_variable(0x6040)
    rpdo.add_variable(0x607A)
    rpdo.trans_type = 1
    rpdo.enabled = True
    rpdo.save()
    return rpdo


def enable(rig: Cia402Rig, mode: int) -> None:
    rig.node.sdo[0x6060].raw = mode
    rig.node.state = "OPERATION ENABLED"  # canopen walks 2, 3, 4 over SDO (no statusword TPDO mapped)
    assert rig.firmware.state == "OPERATION ENABLED"


def emcy(rig: Cia402Rig, code: int) -> canopen.emcy.EmcyError:
    """The EMCY `code` once canopen's EmcyConsumer has logged it (its `wait` misses one that came before it waits)."""
    log = rig.node.emcy.log
    return wait_until(lambda: next((e for e in list(log) if e.code == code), None), f"EMCY {code:#06x}")


def cw(state: str) -> int:
    return State402.CW_COMMANDS_CODE[state]


# ---- state machine --------------------------------------------------------------------------------------------------


def test_the_402_state_machine_walked_by_canopen(rig: Cia402Rig) -> None:
    node = rig.node
    assert node.state == "SWITCH ON DISABLED"
    node.state = "OPERATION ENABLED"
    assert node.sdo[0x6041].raw & 0x6F == 0x27
    assert node.sdo[0x6041].raw & 0x0200  # remote
    assert rig.firmware.enabled
    node.state = "SWITCHED ON"  # transition 5
    assert not rig.firmware.enabled
    node.state = "OPERATION ENABLED"
    node.sdo[0x6040].raw = cw("QUICK STOP ACTIVE")  # transition 11, then 0x605A = 2: brake, Switch On Disabled
    rig.advance(0.01)
    assert node.state == "SWITCH ON DISABLED"
    node.state = "READY TO SWITCH ON"
    node.sdo[0x6040].raw = cw("SWITCH ON DISABLED") & 0  # disable voltage: transition 7
    assert node.state == "SWITCH ON DISABLED"
    node.sdo[0x6040].raw = 0x0F  # enable operation from Switch On Disabled: no transition exists
    assert node.state == "SWITCH ON DISABLED"
    node.state = "OPERATION ENABLED"
    node.state = "SWITCH ON DISABLED"  # transition 9
    assert not rig.firmware.enabled


def test_the_402_state_machine_over_pdos_as_canopen_sets_it_up(rig: Cia402Rig) -> None:
    """canopen's BaseNode402 on PDOs: controlword and mode in an RPDO, statusword and display in a TPDO, on SYNC."""
    node = rig.node
    node.tpdo.read()
    node.rpdo.read()
    tpdo, rpdo = node.tpdo[1], node.rpdo[1]
    tpdo.clear()
    tpdo.add_variable(0x6041)
    tpdo.add_variable(0x6061)
    tpdo.trans_type = 1
    tpdo.enabled = True
    tpdo.save()
    rpdo.clear()
    rpdo.add_variable(0x6040)
    rpdo.add_variable(0x6060)
    rpdo.trans_type = 1
    rpdo.enabled = True
    rpdo.save()
    node.setup_402_state_machine(read_pdos=False)
    operational(rig)
    rpdo.start(0.005)  # the master's cyclic RPDO and SYNC (wall clock; the drive acts on each SYNC at once)
    rig.network.sync.start(0.005)
    try:
        node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
        node.state = "OPERATION ENABLED"
        assert rig.firmware.state == "OPERATION ENABLED" and rig.firmware.mode_display == 10
        node.state = "SWITCH ON DISABLED"
        assert rig.firmware.state == "SWITCH ON DISABLED"
    finally:
        rig.network.sync.stop()
        rpdo.stop()


def test_quick_stop_option_6_stays_in_quick_stop_active_and_enables_again(rig: Cia402Rig) -> None:
    rig.node.sdo[0x605A].raw = 6
    enable(rig, 9)
    rig.node.sdo[0x60FF].raw = round(2.0 * rig.firmware.wiring.velocity_per_rad_s)  # 2 rad/s
    rig.advance(0.3)
    assert rig.plant.velocities[0] == pytest.approx(2.0, abs=0.1)
    rig.node.sdo[0x6040].raw = cw("QUICK STOP ACTIVE")
    rig.advance(0.3)
    assert rig.node.state == "QUICK STOP ACTIVE"
    assert abs(rig.plant.velocities[0]) < 0.05  # braked to standstill, held
    assert rig.node.sdo[0x6041].raw & 0x0400  # target reached: stopped
    rig.node.sdo[0x6040].raw = 0x0F  # transition 16
    assert rig.node.state == "OPERATION ENABLED"


def test_fault_reset_needs_a_rising_edge_of_bit_7(rig: Cia402Rig) -> None:
    rig.node.sdo[0x6040].raw = 0x80  # bit 7 already high before the fault
    rig.on_drive(lambda: rig.firmware.inject_fault(0x5530))
    assert rig.node.state == "FAULT"
    rig.node.sdo[0x6040].raw = 0x80  # still high: no edge
    assert rig.node.state == "FAULT"
    rig.node.sdo[0x6040].raw = 0x0F  # enable does nothing in FAULT
    assert rig.node.state == "FAULT"
    rig.node.sdo[0x6040].raw = 0x00
    rig.node.sdo[0x6040].raw = 0x80  # 0 → 1
    assert rig.node.state == "SWITCH ON DISABLED"
    assert rig.node.sdo[0x603F].raw == 0


# ---- modes -----------------------------------------------------------------------------------------------------------


def test_csp_moves_the_plant_to_the_target_within_the_window(rig: Cia402Rig) -> None:
    rig.node.sdo[0x6065].raw = 2000  # following error window: counts
    rig.node.sdo[0x6066].raw = 50
    rpdo = command_pdo(rig)
    operational(rig)
    enable(rig, 8)
    assert rig.node.sdo[0x6041].raw & 0x1000  # CSP: the drive follows the command value
    cpr = rig.firmware.wiring.counts_per_rad
    step = 0.3 / 500  # 0.3 rad in 0.5 s, one target per 1 ms SYNC
    targets = iter([round(min(k * step, 0.3) * cpr) for k in range(1, 1000)])

    def cycle() -> None:
        rpdo["Controlword"].raw = 0x0F
        rpdo["Target position"].raw = next(targets)
        rpdo.transmit()
        rig.network.sync.transmit()

    rig.advance(0.8, each=cycle)
    assert rig.plant.positions[0] == pytest.approx(0.3, abs=0.002)
    assert rig.firmware.state == "OPERATION ENABLED"  # never outside the window for 50 ms
    assert abs(rig.node.sdo[0x60F4].raw) < 2000
    assert rig.node.sdo[0x6064].raw == pytest.approx(0.3 * cpr, abs=50)


def test_cst_applies_the_target_torque_in_per_mille_of_the_rated_torque(rig: Cia402Rig) -> None:
    enable(rig, 10)
    rig.node.sdo[0x6071].raw = 250  # 25 % of 10 N·m
    rig.node.sdo[0x60B2].raw = 50  # + 5 % torque offset
    rig.advance(0.01)
    assert rig.firmware.applied_torque == pytest.approx(3.0)
    assert rig.node.sdo[0x6077].raw == 300
    assert rig.plant.velocities[0] > 0.0
    rig.node.sdo[0x6071].raw = 30000  # far above 0x6072 = 3000 ‰
    rig.advance(0.001)
    assert rig.firmware.applied_torque == pytest.approx(30.0)
    assert rig.node.sdo[0x6041].raw & 0x0800  # internal limit active


def test_following_error_faults_with_emcy_8611(rig: Cia402Rig) -> None:
    node = rig.node
    node.sdo[0x6065].raw = 1000
    node.sdo[0x6066].raw = 20
    node.sdo[0x6072].raw = 10  # 0.1 N·m: too weak to follow
    enable(rig, 8)
    node.emcy.reset()
    node.sdo[0x607A].raw = round(1.0 * rig.firmware.wiring.counts_per_rad)
    assert node.sdo[0x6041].raw & 0x2000  # bit 13: following error, before the timeout
    rig.advance(0.015)
    assert node.state == "OPERATION ENABLED"  # not yet 20 ms
    rig.advance(0.02)
    error = emcy(rig, 0x8611)
    assert error.register & 0x21 == 0x21  # generic + device profile
    assert node.state == "FAULT"
    assert node.sdo[0x603F].raw == 0x8611
    assert node.sdo[0x1001].raw & 0x01
    assert node.sdo[0x1003][1].raw == 0x8611
    assert rig.firmware.applied_torque == 0.0


# ---- faults, reboot, watchdog ----------------------------------------------------------------------------------------


def test_injected_fault_sends_its_emcy_and_disables(rig: Cia402Rig) -> None:
    enable(rig, 10)
    rig.on_drive(lambda: rig.firmware.inject_fault(0x2310))
    error = emcy(rig, 0x2310)
    assert error.register & 0x03 == 0x03  # generic + current
    assert rig.node.state == "FAULT"
    assert not rig.firmware.enabled
    rig.node.sdo[0x6040].raw = 0x80
    wait_until(lambda: not rig.node.emcy.active, "the EMCY error reset (0x0000)")
    assert rig.node.state == "SWITCH ON DISABLED"
    with pytest.raises(ValueError, match="EMCY error code"):
        rig.firmware.inject_fault(0x10000)


def test_over_temperature_faults_with_emcy_4310(rig: Cia402Rig) -> None:
    enable(rig, 10)
    rig.on_drive(lambda: setattr(rig.firmware, "over_temperature", rig.firmware.temperature_rotor + 0.01))
    rig.node.sdo[0x6071].raw = 2000
    rig.advance(0.5)
    emcy(rig, 0x4310)
    assert rig.firmware.fault == 0x4310


def test_reboot_boots_up_again_in_pre_operational_with_ram_settings_lost(rig: Cia402Rig) -> None:
    rig.node.sdo[0x6065].raw = 1234
    operational(rig)
    enable(rig, 8)
    booted = rig.booted_again()
    rig.on_drive(rig.firmware.reboot)
    wait_until(booted, "the boot-up frame")
    assert rig.firmware.nmt_state == NmtState.PRE_OPERATIONAL
    assert rig.node.state == "SWITCH ON DISABLED"
    assert rig.node.sdo[0x6065].raw == 0xFFFFFFFF
    assert rig.node.sdo[0x6061].raw == 0


def test_sync_watchdog_faults_with_emcy_8130(rig: Cia402Rig) -> None:
    rig.node.sdo[0x1006].raw = 1000  # 1 ms: the watchdog is 50 periods
    operational(rig)
    enable(rig, 10)
    rig.advance(0.2, each=rig.network.sync.transmit)
    assert rig.node.state == "OPERATION ENABLED"
    rig.advance(0.049)
    assert rig.firmware.state == "OPERATION ENABLED"  # 49 ms of silence: still inside
    rig.advance(0.003)
    emcy(rig, 0x8130)
    assert rig.node.state == "FAULT"


def test_leaving_nmt_operational_starves_the_sync_watchdog(rig: Cia402Rig) -> None:
    rig.node.sdo[0x1006].raw = 1000  # 1 ms: 50 ms without a feed
    operational(rig)
    enable(rig, 10)
    rig.advance(0.1, each=rig.network.sync.transmit)
    rig.node.nmt.state = "PRE-OPERATIONAL"
    wait_until(lambda: rig.firmware.nmt_state == NmtState.PRE_OPERATIONAL, "pre-operational")
    rig.advance(0.045, each=rig.network.sync.transmit)  # SYNC goes on, but PDO traffic has stopped
    assert rig.firmware.state == "OPERATION ENABLED"
    rig.advance(0.01, each=rig.network.sync.transmit)
    emcy(rig, 0x8130)
    assert rig.node.state == "FAULT"


def test_consumer_heartbeat_watchdog_faults_with_emcy_8130(rig: Cia402Rig) -> None:
    rig.node.sdo[0x1016][1].raw = (0x7F << 16) | 50  # the master, node 127, every ≤ 50 ms
    operational(rig)
    enable(rig, 10)

    def master_heartbeat() -> None:
        rig.network.send_message(0x77F, [NmtState.OPERATIONAL])

    for _ in range(10):
        master_heartbeat()
        rig.advance(0.02)
    assert rig.node.state == "OPERATION ENABLED"
    rig.advance(0.06)
    emcy(rig, 0x8130)
    assert rig.firmware.fault == 0x8130


def test_the_watchdog_is_off_outside_operation_enabled(rig: Cia402Rig) -> None:
    rig.node.sdo[0x1006].raw = 1000
    operational(rig)
    rig.advance(0.2)
    assert rig.node.state == "SWITCH ON DISABLED"
    assert rig.firmware.fault == 0


# ---- homing ----------------------------------------------------------------------------------------------------------


def test_homing_method_37_makes_the_current_position_the_home_offset(rig: Cia402Rig) -> None:
    rig.on_drive(lambda: rig.plant.positions.__setitem__(0, 1.2))
    rig.advance(0.001)
    rig.node.sdo[0x6098].raw = 37
    rig.node.sdo[0x607C].raw = 5000
    enable(rig, 6)
    assert rig.node.sdo[0x6041].raw & 0x3400 == 0x0400  # not started: target reached only
    rig.node.sdo[0x6040].raw = 0x1F  # homing operation start
    status = rig.node.sdo[0x6041].raw
    assert status & 0x3400 == 0x1400  # attained + target reached
    assert rig.node.sdo[0x6064].raw == pytest.approx(5000, abs=1)
    rig.advance(0.1)
    assert rig.plant.positions[0] == pytest.approx(1.2, abs=0.01)  # held where it was


def test_homing_to_the_index_pulse_moves_and_takes_time(rig: Cia402Rig) -> None:
    rig.on_drive(lambda: rig.plant.positions.__setitem__(0, 0.3))
    rig.advance(0.001)
    rig.node.sdo[0x6098].raw = 34  # index pulse in the positive direction
    rig.node.sdo[0x6099][2].raw = round(2.0 * rig.firmware.wiring.velocity_per_rad_s)  # 2 rad/s
    enable(rig, 6)
    rig.node.sdo[0x6040].raw = 0x1F
    rig.advance(0.5)
    assert rig.node.sdo[0x6041].raw & 0x3400 == 0  # in progress
    assert rig.plant.velocities[0] == pytest.approx(2.0, abs=0.1)
    rig.advance(3.0)
    assert rig.node.sdo[0x6041].raw & 0x3400 == 0x1400
    assert rig.plant.positions[0] == pytest.approx(2 * math.pi, abs=0.05)  # held at the next index
    assert rig.node.sdo[0x6064].raw == pytest.approx(0, abs=0.05 * rig.firmware.wiring.counts_per_rad)


def test_halt_interrupts_homing(rig: Cia402Rig) -> None:
    rig.node.sdo[0x6098].raw = 33
    rig.node.sdo[0x6099][2].raw = round(1.0 * rig.firmware.wiring.velocity_per_rad_s)
    rig.on_drive(lambda: rig.plant.positions.__setitem__(0, 3.0))
    rig.advance(0.001)
    enable(rig, 6)
    rig.node.sdo[0x6040].raw = 0x1F
    rig.advance(0.2)
    rig.node.sdo[0x6040].raw = 0x11F  # halt
    rig.advance(0.3)
    assert rig.node.sdo[0x6041].raw & 0x3400 == 0x0400  # interrupted
    assert abs(rig.plant.velocities[0]) < 0.05


def test_an_unsupported_homing_method_reports_a_homing_error(rig: Cia402Rig) -> None:
    rig.node.sdo[0x6098].raw = 17  # a limit-switch method this drive has no switches for
    enable(rig, 6)
    rig.node.sdo[0x6040].raw = 0x1F
    assert rig.node.sdo[0x6041].raw & 0x3400 == 0x2400  # homing error, at standstill
    assert rig.firmware.state == "OPERATION ENABLED"  # an error of the procedure, not a drive fault


# ---- runtime ---------------------------------------------------------------------------------------------------------


def cia402_config(tmp_path: Path, bus: dict[str, str], joints: dict[str, dict[str, Any]], **robot: str) -> LoadedConfig:
    """A config with one cia402 section, loaded by hand: the emulator does not need the cia402 host driver."""
    drives = {name: {"node_id": k + 1, **joints[name].pop("drive", {})} for k, name in enumerate(joints)}
    params = {"bus": bus, "eds": str(EDS), "drives": drives}
    data = {
        "robot": {"name": "cia402", **robot},
        "update_rate": 500,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {"arm": {"driver": "cia402", "params": params, "joints": joints}},
        "joints": {
            name: {
                "limits": {"position": {"lower": -3.0, "upper": 3.0}, "velocity": 2.0, "effort": 20.0},
                "hold": {"kp": 50.0, "kd": 2.0},
            }
            for name in joints
        },
    }
    return LoadedConfig(
        path=tmp_path / "robot.yaml",
        config=RobotConfig.model_validate(data),
        driver_params={"arm": Cia402Params.model_validate(params)},
    )


def test_build_runtime_serves_cia402_sections(tmp_path: Path) -> None:
    bus = {"interface": "virtual", "channel": f"cia402-{uuid.uuid4().hex[:10]}"}
    loaded = cia402_config(tmp_path, bus, {"a": {}, "b": {"reduction": 2.0, "drive": {"mode": "cst"}}})
    runtime = build_runtime(loaded)
    firmwares = [j.firmware for j in runtime.joints]
    assert [fw.node_id for fw in firmwares] == [1, 2]
    assert [fw.wiring.mode for fw in firmwares] == ["csp", "cst"]
    assert runtime.joints[1].reduction == 2.0
    assert describe(runtime)[0].endswith(": 2 drives (a=cia402 node 1, b=cia402 node 2)")
    runtime.open()
    try:
        runtime.service(0.0)
        assert runtime.handle({"op": "fault", "joint": "b", "code": 0x3210})["ok"]
        assert [j["fault"] for j in runtime.status()["joints"]] == [0, 0x3210]
        reply = runtime.handle({"op": "fault", "joint": "a", "code": 0x12345})
        assert not reply["ok"] and "EMCY error code" in reply["error"]
        assert runtime.handle({"op": "clear"})["ok"]
        assert [j["fault"] for j in runtime.status()["joints"]] == [0, 0]
    finally:
        runtime.close()


def test_the_twin_plant_sits_behind_cia402_drives(tmp_path: Path) -> None:
    bus = {"interface": "virtual", "channel": f"cia402-{uuid.uuid4().hex[:10]}"}
    names = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    loaded = cia402_config(tmp_path, bus, {name: {} for name in names}, model=str(CONFIGS / "arm6.xml"))
    runtime = build_runtime(loaded)
    assert runtime.plant_kind == "twin" and len(runtime.joints) == 6
    runtime.open()
    try:
        for k in range(20):
            runtime.service(0.002 * k)
        status = runtime.status()
        assert all(j["braked"] and not j["enabled"] for j in status["joints"])  # disabled drives: brakes hold
    finally:
        runtime.close()


def test_canopen_reaches_the_drives_over_the_served_remote_bus(tmp_path: Path) -> None:
    loaded = cia402_config(tmp_path, {"interface": "remote", "channel": "ws://127.0.0.1:54701/"}, {"a": {}})
    runtime = build_runtime(loaded)
    runtime.open(serve_remote=("127.0.0.1", 0))
    thread = threading.Thread(target=runtime.run, args=(0.0005,), daemon=True)
    thread.start()
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    try:
        address = runtime.remote_address
        assert address is not None
        network.connect(interface="remote", channel=f"ws://127.0.0.1:{address[1]}/", receive_own_messages=False)
        node = network.add_node(BaseNode402(1, str(EDS)))
        node.sdo.RESPONSE_TIMEOUT = 2.0
        assert node.sdo[0x1008].raw == "hild generic CiA 402 drive"
        node.sdo[0x1017].raw = 10
        node.nmt.state = "OPERATIONAL"
        wait_until(lambda: node.nmt.state == "OPERATIONAL", "the heartbeat carrying OPERATIONAL")
        node.state = "OPERATION ENABLED"
        assert runtime.status()["joints"][0]["enabled"]
    finally:
        network.disconnect()
        runtime.stop_event.set()
        thread.join(10)
        runtime.close()
