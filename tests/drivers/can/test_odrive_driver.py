"""odrive_can against the emulated ODrive 0.6 axes on in-process virtual buses, in lockstep."""

from __future__ import annotations

import math
import struct
from typing import Any

import can
import numpy as np
import pytest

from drivers.can.emulator import MotorPlant, ODriveFirmware
from drivers.can.odrive_driver import FAULT_NOT_CLOSED_LOOP, ODriveCanDriver
from drivers.can.params import ODriveCanParams
from drivers.can.protocol import odrive as od
from drivers.can.protocol.odrive import AxisState, ControlMode, ODriveError
from hild.hardware import HardwareError
from tests.drivers.can.lockstep import LockstepRig, rig_factory

RATE = 500.0
DT = 1.0 / RATE
TAU = 2.0 * math.pi


class Rig(LockstepRig):
    """One odrive_can driver and its emulated axes on a private virtual channel, stepped in lockstep."""

    def __init__(self, nodes: dict[str, int], *, positions: list[float] | None = None, **params: Any) -> None:
        super().__init__("odrive", tuple(nodes), RATE, wait_step=5e-4)
        raw = {
            "bus": {"interface": "virtual", "channel": self.channel},
            "axes": {joint: {"node_id": node} for joint, node in nodes.items()},
            "reply_timeout_ms": 50,
            **params,
        }
        encoder_period = raw.get("encoder_rate_ms", 0.0) / 1000.0
        n = len(nodes)
        self.attach(
            ODriveCanDriver(self.context("legs"), ODriveCanParams.model_validate(raw)),
            [ODriveFirmware(node, encoder_period=encoder_period) for node in nodes.values()],
            MotorPlant(n, inertia=0.01, damping=0.01, positions=positions or [0.0] * n),
        )

    def hold(self, kp: float = 50.0, kd: float = 1.0) -> None:
        super().hold(kp, kd)


rigs = rig_factory(Rig)


def test_configure_reads_where_each_axis_is_without_arming(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4}, positions=[1.0, -2.0])
    rig.driver.on_configure()
    assert all(fw.axis_state == AxisState.IDLE for fw in rig.firmwares)
    rig.driver.read(0.0, DT, rig.state)
    np.testing.assert_allclose(rig.state.position, [1.0, -2.0], rtol=1e-6)  # rev → rad, float32 on the wire
    assert rig.state.fresh.all() and not rig.state.fault.any()


def test_activate_requests_closed_loop_and_holds_where_it_is(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4}, positions=[0.5, 0.25])
    rig.start()
    assert all(fw.axis_state == AxisState.CLOSED_LOOP_CONTROL for fw in rig.firmwares)
    rig.hold()
    rig.cycle(100)
    np.testing.assert_allclose(rig.state.position, [0.5, 0.25], atol=1e-3)
    assert rig.state.fresh.all() and not rig.state.fault.any()


def test_silent_axis_at_configure_is_listed(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.firmwares[1].silent = True
    with pytest.raises(
        HardwareError, match=r"did not answer on virtual:odrive-\w+: knee \(node 4: no heartbeat and no"
    ):
        rig.driver.on_configure()
    assert rig.driver.link.bus is None


def test_position_mode_sends_input_pos_with_feed_forwards(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.command.position[:] = 0.3
    rig.command.velocity[:] = 0.4
    rig.command.effort[:] = 0.25
    rig.command.kp[:] = 100.0
    rig.command.kd[:] = 2.0
    rig.cycle()
    fw = rig.firmwares[0]
    assert fw.control_mode == ControlMode.POSITION_CONTROL
    assert fw.input_pos == pytest.approx(0.3 / TAU, rel=1e-6)
    assert fw.input_vel == round(0.4 / TAU, 3)  # int16 × 0.001 rev/s
    assert fw.input_torque == 0.25


def test_velocity_and_torque_modes_follow_the_gains_and_switch_only_on_change(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    fw = rig.firmwares[0]
    rig.command.kp[:] = 0.0
    rig.command.kd[:] = 1.0
    rig.command.velocity[:] = 1.5
    rig.command.effort[:] = 0.1
    rig.cycle()
    assert fw.control_mode == ControlMode.VELOCITY_CONTROL
    assert (fw.input_vel, fw.input_torque) == (pytest.approx(1.5 / TAU), pytest.approx(0.1))
    sent = rig.driver.link.frames_sent
    rig.cycle()
    assert rig.driver.link.frames_sent - sent == 2  # Set_Input_Vel + the estimates request, no mode frame
    rig.command.kd[:] = 0.0
    rig.command.effort[:] = -0.7
    sent = rig.driver.link.frames_sent
    rig.cycle()
    assert rig.driver.link.frames_sent - sent == 3  # Set_Controller_Mode once, then input + request
    assert fw.control_mode == ControlMode.TORQUE_CONTROL and fw.input_torque == pytest.approx(-0.7)


def test_axis_errors_become_named_fault_codes(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.start()
    rig.hold()
    rig.cycle(5)
    rig.firmwares[1].inject_fault(ODriveError.DC_BUS_OVER_VOLTAGE)
    rig.cycle(60)  # the next heartbeat (100 ms) carries it
    code = int(rig.state.fault[1])
    assert rig.state.fault[0] == 0
    assert code & 0xFFFF_FFFF == ODriveError.DC_BUS_OVER_VOLTAGE
    assert code & FAULT_NOT_CLOSED_LOOP
    text = rig.driver.describe_fault(code)
    assert "DC_BUS_OVER_VOLTAGE" in text and "axis in IDLE, not CLOSED_LOOP_CONTROL" in text


def test_reset_clears_errors_but_never_re_arms(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.hold()
    fw = rig.firmwares[0]
    fw.inject_fault(ODriveError.WATCHDOG_TIMER_EXPIRED)
    rig.cycle(60)
    assert rig.state.fault[0] & ODriveError.WATCHDOG_TIMER_EXPIRED
    with pytest.raises(HardwareError, match="reset first"):
        rig.driver.enable()
    rig.driver.clear_faults()
    rig.cycle(60)
    assert fw.axis_error == 0 and fw.axis_state == AxisState.IDLE  # Clear_Errors only
    assert rig.state.fault[0] == FAULT_NOT_CLOSED_LOOP | AxisState.IDLE << 33
    assert rig.driver.enable("hip") == ["hip"]  # the explicit operator command
    rig.cycle(60)
    assert fw.axis_state == AxisState.CLOSED_LOOP_CONTROL and rig.state.fault[0] == 0


def test_reboot_is_a_fault(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.hold()
    rig.firmwares[0].reboot()
    rig.cycle(60)
    assert rig.state.fault[0] == FAULT_NOT_CLOSED_LOOP | AxisState.IDLE << 33
    assert rig.firmwares[0].axis_state == AxisState.IDLE


def test_axis_with_errors_at_startup_is_not_armed(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4})
    rig.firmwares[0].inject_fault(ODriveError.MOTOR_OVER_TEMP)
    rig.start()
    assert rig.firmwares[0].axis_state == AxisState.IDLE
    assert rig.firmwares[1].axis_state == AxisState.CLOSED_LOOP_CONTROL
    assert any("hip: not armed" in msg for _, msg in rig.events)
    assert rig.state.fault[0] & ODriveError.MOTOR_OVER_TEMP


def test_missing_heartbeat_makes_the_axis_stale(rigs: Any) -> None:
    rig = rigs({"hip": 3, "knee": 4}, heartbeat_timeout_ms=250)
    rig.start()
    rig.hold()
    rig.cycle(10)
    assert rig.state.fresh.all()
    rig.firmwares[1].heartbeat_period = 0.0  # estimates still answered, heartbeats stop
    fresh_cycles = 0
    for _ in range(200):
        rig.cycle()
        if rig.state.fresh[1]:
            fresh_cycles += 1
        assert rig.state.fresh[0]
    assert not rig.state.fresh[1]
    assert fresh_cycles <= 0.25 * RATE + 1  # stale once the last heartbeat is older than 250 ms


def test_missing_estimates_are_stale_at_once_in_request_mode(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.hold()
    rig.cycle()
    rig.firmwares[0].silent = True
    rig.cycle()
    assert not rig.state.fresh[0]


def test_cyclic_estimates_need_no_requests(rigs: Any) -> None:
    rig = rigs({"hip": 3}, encoder_rate_ms=2.0, positions=[0.7])
    rig.start()
    rig.hold()
    handled = rig.firmwares[0].counters["handled"]
    sent = rig.driver.link.frames_sent
    rig.cycle(50)
    assert rig.driver.link.frames_sent - sent == 50  # only Set_Input_Pos, no RTR
    assert rig.firmwares[0].counters["handled"] - handled == 50
    assert rig.state.fresh.all()
    assert rig.state.position[0] == pytest.approx(0.7, abs=1e-3)


def test_temperature_torque_and_garbage_frames(rigs: Any) -> None:
    rig = rigs({"hip": 3}, event_interval=10.0)
    rig.start()
    rig.hold()
    rig.bus.send(od.encode_temperature(3, 41.0, 55.5))
    rig.bus.send(
        can.Message(
            arbitration_id=od.arbitration_id(3, od.Cmd.GET_TORQUES),
            data=struct.pack("<ff", 1.0, 0.75),
            is_extended_id=False,
        )
    )
    rig.bus.send(od.encode_heartbeat(9, od.Heartbeat(0, 8, 0, True)))  # node 9: not ours
    short = can.Message(arbitration_id=od.arbitration_id(3, od.Cmd.HEARTBEAT), data=b"\x00\x00", is_extended_id=False)
    rig.bus.send(short)
    rig.bus.send(od.encode_set_input_pos(3, 1.0))  # another host commanding our axis
    rig.bus.send(od.encode_bus_voltage_current(3, 24.0, 0.5))  # a getter answer we do not use: skipped, not bad
    rig.cycle()
    assert rig.state.temperature[0] == 55.5 and rig.state.effort[0] == 0.75
    assert rig.driver.bad_frames.totals == {"unknown id": 1, "wrong length": 1, "unexpected command": 1}
    assert len([m for level, m in rig.events if "ignored CAN frames" in m]) == 1
    assert rig.state.fresh.all() and not rig.state.fault.any()


def test_deactivate_idles_the_axes(rigs: Any) -> None:
    rig = rigs({"hip": 3})
    rig.start()
    rig.driver.on_deactivate()
    rig.emulator.service(rig.now + DT)
    assert rig.firmwares[0].axis_state == AxisState.IDLE


# ---- class-level hooks ---------------------------------------------------------------------------------------------


def params(**raw: Any) -> ODriveCanParams:
    return ODriveCanParams.model_validate({"bus": {"interface": "virtual", "channel": "x"}, **raw})


def test_review_reports_ids_fd_timeouts_and_joints() -> None:
    p = params(
        axes={"a": {"node_id": 1}, "b": {"node_id": 1}, "c": {"node_id": 2}},
        heartbeat_rate_ms=100,
        heartbeat_timeout_ms=50,
        encoder_rate_ms=10,
        bus={"interface": "virtual", "channel": "x", "fd": True},
    )
    found = [f"{f.level}: {f.message}" for f in ODriveCanDriver.review(p, ["a", "b", "d"], RATE)]
    assert found == [
        "error: no axis configured for joints ['d']",
        "error: axes configured for joints this component does not drive: ['c']",
        "error: b: node id 1 is also used by a",
        "error: bus.fd: ODrive CAN Simple runs on classic CAN frames",
        "error: heartbeat_timeout_ms 50 must exceed heartbeat_rate_ms 100",
        "warning: encoder_rate_ms 10 is slower than the cycle (2 ms): feedback is reused between estimates",
    ]
    assert ODriveCanDriver.review(params(axes={"a": {"node_id": 1}}), ["a"], RATE) == []


def test_bus_usage_counts_inputs_requests_and_heartbeats() -> None:
    (usage,) = ODriveCanDriver.bus_usage(params(axes={"a": {"node_id": 1}, "b": {"node_id": 2}}), ["a", "b"], RATE)
    per_axis = RATE * (135 + 55 + 135) + 10 * 135  # input, RTR, estimates reply per cycle; heartbeat at 10 Hz
    assert usage.bits_per_second == pytest.approx(2 * per_axis)
    assert usage.capacity == 1_000_000 and usage.bus == "virtual:x"
    assert usage.ids == frozenset(range(32, 96))  # both nodes' whole id blocks
    (cyclic,) = ODriveCanDriver.bus_usage(params(axes={"a": {"node_id": 1}}, encoder_rate_ms=10), ["a"], RATE)
    assert cyclic.bits_per_second == pytest.approx(RATE * 135 + 100 * 135 + 10 * 135)


def test_kp_and_kd_are_not_offered_to_controllers() -> None:
    assert frozenset({"position", "velocity", "effort"}) == ODriveCanDriver.COMMAND_FIELDS
