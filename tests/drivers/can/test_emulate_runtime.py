"""`hild emulate`'s runtime: firmware per config, transmissions, the twin behind CAN, control channel, remote bus.

Lockstep rigs: the engine and the emulator share in-process ``virtual`` buses; a cycle is ``engine.step`` then
``runtime.service(t + dt)``, and lifecycle waits service the emulator at a frozen time (no sim time passes while
the daemon configures, as on a twin). Only the control-channel and remote-bus tests run on the wall clock, and
they wait for replies, never for time.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
import yaml

from drivers.can.emulator import DamiaoFirmware, MyActuatorFirmware, ODriveFirmware, TMotorFirmware
from drivers.can.emulator.runtime import BrakedPlant, EmulatorRuntime, RuntimeOptions, build_runtime, request
from drivers.can.protocol import damiao_registers as reg
from drivers.can.protocol.mit import MitRanges
from drivers.can.protocol.models import MODELS
from drivers.mujoco.plant import TwinPlant
from hild.api.goals import GoalEndpoint
from hild.cli import build_parser, main
from hild.config import load_config
from hild.controllers.joint_trajectory import JointTrajectoryController
from hild.cycle.engine import Engine
from hild.motion.reference import OFFSETS, standard_trajectory
from tests.conftest import CONFIGS, joint

DM8009 = MODELS["damiao"]["DM8009"]
DM4340 = MODELS["damiao"]["DM4340"]
HOME = np.array([0.0, 1.0, -1.6, -0.9708, 1.5708, 0.0])  # arm6.xml keyframe "home"


def arm6(bus: dict[str, Any] | None = None, **patch: Any) -> dict[str, Any]:
    """configs/arm6_vcan.yaml on the sim clock, on a private virtual bus, model path made absolute."""
    data = yaml.safe_load((CONFIGS / "arm6_vcan.yaml").read_text())
    data["robot"]["model"] = str(CONFIGS / "arm6.xml")
    data["clock"] = {"source": "sim", "real_time_factor": 0}
    channel = f"arm6-{uuid.uuid4().hex[:10]}"
    data["hardware"]["arm"]["params"]["bus"] = bus or {"interface": "virtual", "channel": channel}
    data.update(patch)
    return data


class CanRig:
    """A lockstep engine on the config's CAN bus and the emulator runtime behind it."""

    def __init__(self, path: Path, options: RuntimeOptions | None = None) -> None:
        loaded = load_config(path)
        self.runtime = build_runtime(loaded, options or RuntimeOptions(max_step=0.001))
        self.runtime.open()
        self.engine = Engine(loaded)
        self.now = 0.0
        for slot in self.engine.hardware:
            slot.component.serve_while_waiting = lambda: self.runtime.service(self.now)  # type: ignore[attr-defined]

    def start(self) -> CanRig:
        self.engine.start()
        return self

    def cycle(self, count: int = 1) -> None:
        for _ in range(count):
            self.engine.run_cycles(1)
            self.now += self.engine.period
            self.runtime.service(self.now)

    def close(self) -> None:
        if self.engine.started:
            self.engine.stop()
        self.runtime.close()


@pytest.fixture
def rigs(write_config: Callable[..., Path]) -> Iterator[Callable[..., CanRig]]:
    made: list[CanRig] = []

    def make(config: dict[str, Any], options: RuntimeOptions | None = None, name: str = "robot.yaml") -> CanRig:
        rig = CanRig(write_config(config, name), options)
        made.append(rig)
        return rig

    yield make
    for rig in made:
        rig.close()


# ---- firmware per config ------------------------------------------------------------------------------------


def mixed_robot() -> dict[str, Any]:
    """Four CAN components on four virtual buses (every firmware kind) and a mock joint that is not emulated."""

    def bus() -> dict[str, str]:
        return {"interface": "virtual", "channel": f"mixed-{uuid.uuid4().hex[:10]}"}

    return {
        "robot": {"name": "mixed"},
        "update_rate": 500,
        "clock": {"source": "sim", "real_time_factor": 0},
        "hardware": {
            "dm": {
                "driver": "mit_can",
                "params": {
                    "bus": bus(),
                    "flavour": "damiao",
                    "motors": {
                        "a": {"id": 1, "reply_id": 0x11, "model": "DM8009"},
                        "b": {"id": 2, "reply_id": 0x12, "model": "DM4340", "ranges": {"v_max": 8.0}},
                    },
                },
                "joints": {"a": {}, "b": {"reduction": 2.0}},
            },
            "ak": {
                "driver": "mit_can",
                "params": {
                    "bus": bus(),
                    "flavour": "tmotor",
                    "master_id": 0,
                    "motors": {"c": {"id": 3, "model": "AK80-9"}},
                },
                "joints": {"c": {}},
            },
            "ma": {
                "driver": "mit_can",
                "params": {"bus": bus(), "flavour": "myactuator", "motors": {"d": {"id": 4, "model": "motion_mode"}}},
                "joints": {"d": {}},
            },
            "od": {
                "driver": "odrive_can",
                "params": {"bus": bus(), "axes": {"e": {"node_id": 5}}, "encoder_rate_ms": 2.0},
                "joints": {"e": {}},
            },
            "sim": {"driver": "mock", "joints": {"f": {}}},
        },
        "joints": {name: joint() for name in "abcdef"},
    }


def test_runtime_builds_the_configured_firmware_on_each_bus(rigs: Callable[..., CanRig]) -> None:
    rig = rigs(mixed_robot(), RuntimeOptions(initial_positions={"a": 0.2, "b": -0.3}))
    runtime = rig.runtime
    assert runtime.plant_kind == "motors"  # no robot.model
    assert [[j.name for j in r.joints] for r in runtime.rigs] == [["a", "b"], ["c"], ["d"], ["e"]]
    a, b, c, d, e = (j.firmware for j in runtime.joints)
    assert isinstance(a, DamiaoFirmware) and (a.motor_id, a.master_id, a.ranges) == (1, 0x11, DM8009)
    assert isinstance(b, DamiaoFirmware) and (b.motor_id, b.master_id) == (2, 0x12)
    assert b.ranges == MitRanges(12.5, 8.0, 28.0) and b.registers[reg.VMAX] == 8.0  # the override reaches the drive
    assert isinstance(c, TMotorFirmware) and (c.motor_id, c.master_id, c.ranges) == (3, 0, MODELS["tmotor"]["AK80-9"])
    assert isinstance(d, MyActuatorFirmware) and d.motor_id == 4
    assert isinstance(e, ODriveFirmware) and (e.node_id, e.encoder_period) == (5, 0.002)
    assert all(isinstance(r.plant, BrakedPlant) for r in runtime.rigs)
    # Initial positions are joint space: b sits behind a 2:1 transmission.
    np.testing.assert_allclose(runtime.rigs[0].plant.positions, [0.2, -0.6])

    # The host drivers' own start-up checks (Damiao PMAX/VMAX/TMAX and CTRL_MODE, replies before enable) pass,
    # every drive ends up enabled, and the engine holds where the emulated joints stand.
    rig.start()
    assert all(j.firmware.enabled for j in runtime.joints)
    rig.cycle(250)
    np.testing.assert_allclose(rig.engine.state.position[:2], [0.2, -0.3], atol=2e-3)
    assert rig.engine.status()["mode"] == "hold"
    assert all(j["fault"] is None for j in rig.engine.status()["joints"])


def test_component_selection_and_plant_refusals(write_config: Callable[..., Path]) -> None:
    loaded = load_config(write_config(mixed_robot()))
    only = build_runtime(loaded, RuntimeOptions(components=["ak"]))
    assert [j.name for j in only.joints] == ["c"]
    with pytest.raises(ValueError, match=r"components \['sim'\] are not CAN drivers"):
        build_runtime(loaded, RuntimeOptions(components=["sim"]))
    with pytest.raises(ValueError, match=r"no hardware component \['ghost'\]"):
        build_runtime(loaded, RuntimeOptions(components=["ghost"]))
    with pytest.raises(ValueError, match=r"--plant twin needs robot\.model"):
        build_runtime(loaded, RuntimeOptions(plant="twin"))
    with pytest.raises(ValueError, match="needs --plant twin"):
        build_runtime(loaded, RuntimeOptions(keyframe="home"))
    with pytest.raises(ValueError, match="not emulated: \\['f'\\]"):
        build_runtime(loaded, RuntimeOptions(initial_positions={"f": 0.1}))
    mixed = mixed_robot()
    mixed["robot"]["model"] = str(CONFIGS / "arm6.xml")
    with pytest.raises(ValueError, match="couples one bus to the model, the config has 4"):
        build_runtime(load_config(write_config(mixed, "twin.yaml")))


# ---- transmissions ------------------------------------------------------------------------------------------


def test_twin_plant_maps_transmissions_both_ways() -> None:
    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    reduction = np.array([2.0, 3.0, 2.0, 1.0, 1.0, 1.0])
    direction = np.array([1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
    offset = np.array([0.0, 0.1, 0.3, 0.0, 0.0, -0.2])
    plant = TwinPlant(
        CONFIGS / "arm6.xml",
        joints,
        reduction=reduction,
        direction=direction,
        offset=offset,
        keyframe="home",
        gravity=False,
    )
    # Joint → actuator: q_act = direction · (q_joint − offset) · reduction.
    np.testing.assert_allclose(plant.positions, direction * (HOME - offset) * reduction, atol=1e-12)
    np.testing.assert_allclose(plant.joint_positions(), HOME, atol=1e-12)

    # Actuator torque → joint torque: τ_joint = direction · reduction · τ_act, applied on the joint's dof.
    torques = np.array([1.0, -2.0, 3.0, 0.5, 0.5, -0.25])
    plant.step(torques, 0.001)
    np.testing.assert_allclose(plant.data.qfrc_applied, direction * reduction * torques)
    # …and the motion it causes comes back in actuator space: velocity has the torque's sign on every drive.
    assert (np.sign(plant.velocities) == np.sign(torques)).all()
    np.testing.assert_allclose(plant.velocities, direction * reduction * plant.joint_velocities())

    # Writing the actuator-space state (a brake, a test) moves the model: q_joint = direction · q_act / r + offset.
    written = np.array([0.4, 0.9, -1.0, 0.2, 0.1, 0.0])
    plant.positions[:] = written
    plant.velocities[:] = 0.0
    np.testing.assert_allclose(plant.joint_positions(), direction * written / reduction + offset)
    plant.step(np.zeros(6), 1e-9)
    np.testing.assert_allclose(plant.data.qpos, direction * written / reduction + offset, atol=1e-9)
    np.testing.assert_allclose(plant.positions, written, atol=1e-9)


def test_engine_reads_joint_space_through_the_emulated_transmissions(rigs: Callable[..., CanRig]) -> None:
    config = arm6()
    config["hardware"]["arm"]["joints"]["wrist_2"] = {"direction": -1, "offset": 0.25}
    rig = rigs(config).start()
    twin = rig.runtime.twin
    assert twin is not None
    np.testing.assert_allclose(twin.joint_positions(), HOME, atol=1e-12)  # the emulator starts at "home"
    # arm6_vcan: shoulder 2:1, elbow 2:1 mirrored; wrist_2 mirrored with an offset here.
    expected = np.array([2.0, 2.0, -2.0, 1.0, -1.0, 1.0]) * (HOME - np.array([0, 0, 0, 0, 0.25, 0]))
    np.testing.assert_allclose(twin.positions, expected, atol=1e-12)
    p_lsb = 2 * 12.5 / 65535 / np.array([2.0, 2.0, 2.0, 1.0, 1.0, 1.0])
    assert (np.abs(rig.engine.state.position - HOME) <= p_lsb).all()  # the daemon sees joint space, quantised


# ---- the twin behind CAN ---------------------------------------------------------------------------------------


def quantisation_bound(*, moving: bool) -> np.ndarray:
    """Position error (rad, joint space) that 1 LSB of each quantised MIT quantity can cause on arm6_vcan.

    The firmware truncates, so each quantity may be off by up to 1 LSB; through the hold stiffness kp (joint space,
    r = reduction) that is: start pose read back p_lsb / r, position command p_lsb / r, torque feed-forward
    r · t_lsb / kp and, while moving, velocity feed-forward kd · v_lsb / (r · kp); p_lsb = 25/65535 rad,
    v_lsb = 2·v_max/4095, t_lsb = 2·t_max/4095. Standing: 0.5 mrad (DM8009 behind 2:1) and 1.0 mrad (DM4340);
    moving: 1.0 and 1.2 mrad.
    """
    reduction = np.array([2.0, 2.0, 2.0, 1.0, 1.0, 1.0])
    ranges = [DM8009] * 3 + [DM4340] * 3
    kp = np.array([400.0] * 3 + [60.0] * 3)
    kd = np.array([18.0] * 3 + [3.0] * 3)
    p_lsb = 25.0 / 65535
    v_lsb = np.array([2 * r.v_max / 4095 for r in ranges])
    t_lsb = np.array([2 * r.t_max / 4095 for r in ranges])
    bound = 2 * p_lsb / reduction + reduction * t_lsb / kp
    return bound + kd * v_lsb / (reduction * kp) if moving else bound


def test_twin_behind_can_holds_still_under_gravity(rigs: Callable[..., CanRig]) -> None:
    rig = rigs(arm6()).start()
    twin = rig.runtime.twin
    assert twin is not None
    start = twin.joint_positions()
    rows = []
    for _ in range(2500):  # 5 s at 500 Hz
        rig.cycle(1)
        rows.append(twin.joint_positions() - start)
    drift = np.array(rows)
    # Start-up: a Damiao drive is limp from enable until its first command (one cycle here), so the arm dips and
    # rings out under the hold gains (measured 1.7 mrad on shoulder_lift).
    assert np.abs(drift).max() < 2.5e-3
    settled = drift[500:]  # after the first second: still, within the quantisation of what the drives were sent
    one_lsb = 25.0 / 65535 / np.array([2.0, 2.0, 2.0, 1.0, 1.0, 1.0])  # the daemon cannot see less motion
    assert (settled.max(axis=0) - settled.min(axis=0) < one_lsb).all()
    assert (np.abs(settled[-1]) <= quantisation_bound(moving=False)).all(), settled[-1]
    lift = rig.engine.joints.index("shoulder_lift")
    assert rig.engine.state.effort[lift] > 20.0  # gravity (≈32 N·m at home) is really there and really countered
    assert rig.engine.status()["mode"] == "hold"
    assert not any(rig.runtime.rigs[0].plant.locked)  # type: ignore[attr-defined]  # brakes released: drives hold
    stats = rig.runtime.rigs[0].emulator.stats()  # type: ignore[union-attr]
    assert stats["unknown"] == stats["garbled"] == stats["error_frames"] == 0
    assert all(j.firmware.fault == 0 for j in rig.runtime.joints)  # the watchdog was fed all along


def test_brakes_hold_a_disabled_arm_and_without_them_it_falls(write_config: Callable[..., Path]) -> None:
    loaded = load_config(write_config(arm6()))
    moved = {}
    for brakes in (True, False):
        runtime = build_runtime(loaded, RuntimeOptions(brakes=brakes, max_step=0.001))
        runtime.open()
        try:
            assert runtime.twin is not None
            start = runtime.twin.joint_positions()
            for k in range(1, 251):  # 0.5 s with every drive disabled
                runtime.service(k * 0.002)
            moved[brakes] = np.abs(runtime.twin.joint_positions() - start)
        finally:
            runtime.close()
    assert moved[True].max() == 0.0
    assert moved[False][1] > 0.05  # shoulder_lift drops without a brake, like an unbraked Damiao arm


def run_standard_trajectory(engine: Engine, cycle: Callable[[], None], truth: Callable[[], np.ndarray]) -> np.ndarray:
    """Execute the standard trajectory from where the arm is; returns the true joint positions per cycle."""
    assert engine.switch(["joint_trajectory"], []).ok
    jtc = engine.manager.records["joint_trajectory"].instance
    assert isinstance(jtc, JointTrajectoryController)
    reply = GoalEndpoint.of(jtc.action).submit(standard_trajectory(engine.joints, engine.state.position.tolist()))
    assert reply["ok"], reply
    rows = []
    for _ in range(3000):
        cycle()
        rows.append(truth())
        results = {r.goal_id: r for r in GoalEndpoint.of(jtc.action).collect()}
        if reply["goal_id"] in results:
            assert results[reply["goal_id"]].status == "succeeded", results[reply["goal_id"]]
            return np.array(rows)
    raise AssertionError("the standard trajectory did not finish")


def test_twin_behind_can_executes_the_same_trajectory_as_the_twin_directly(
    rigs: Callable[..., CanRig], write_config: Callable[..., Path]
) -> None:
    """Same joints, gains and controllers; the only differences left are the MIT codec's quantisation.

    The direct twin gets what CAN adds besides quantisation: a command takes effect one cycle later (the drive
    receives it after the physics advanced; ``command_latency_cycles: 1``), torque saturates at the drives' joint-side
    range (2·54 N·m behind 2:1, 28 N·m) and the physics steps are the same 1 ms (``substeps: 2``, ``max_step``).

    Tolerance per joint: `quantisation_bound(moving=True)`, 1 LSB of every quantised quantity turned into a
    position error through the hold stiffness (1.0 mrad behind the DM8009s, 1.2 mrad on the DM4340s).
    Measured: 0.6–0.8 mrad along the whole trajectory.
    """
    can_rig = rigs(arm6(), name="can.yaml").start()
    twin_can = can_rig.runtime.twin
    assert twin_can is not None
    via_can = run_standard_trajectory(can_rig.engine, can_rig.cycle, twin_can.joint_positions)

    direct = arm6()
    names = list(direct["joints"])
    direct["hardware"] = {
        "twin": {
            "driver": "mujoco",
            "params": {
                "model": str(CONFIGS / "arm6.xml"),
                "keyframe": "home",
                "substeps": 2,
                "command_latency_cycles": 1,
                "torque_limits": {j: (108.0 if i < 3 else 28.0) for i, j in enumerate(names)},
            },
            "joints": {j: {} for j in names},
        }
    }
    engine = Engine(load_config(write_config(direct, "twin.yaml")))
    engine.start()
    try:
        data = engine.hardware[0].component.data  # type: ignore[attr-defined]
        directly = run_standard_trajectory(engine, lambda: engine.run_cycles(1), lambda: data.qpos.copy())
    finally:
        engine.stop()

    bound = quantisation_bound(moving=True)
    assert abs(len(via_can) - len(directly)) <= 1  # both finish in the same cycle (± the result's own cycle)
    n = min(len(via_can), len(directly))
    difference = np.abs(via_can[:n] - directly[:n]).max(axis=0)
    assert (difference <= bound).all(), (difference, bound)
    excursion = np.abs(directly - HOME).max(axis=0)
    np.testing.assert_allclose(excursion, np.abs(OFFSETS).max(axis=0), atol=0.05)  # it really went the whole way


# ---- control channel and remote bus ------------------------------------------------------------------------------


@pytest.fixture
def running(write_config: Callable[..., Path]) -> Iterator[tuple[EmulatorRuntime, tuple[str, int]]]:
    """The mixed robot's emulator on the wall clock in a thread, with its control socket on a free port."""
    runtime = build_runtime(load_config(write_config(mixed_robot())))
    runtime.open()
    address = runtime.start_control(("127.0.0.1", 0))
    thread = threading.Thread(target=runtime.run, args=(0.001,), daemon=True)
    thread.start()
    try:
        yield runtime, address
    finally:
        runtime.stop_event.set()
        thread.join(10)
        runtime.close()


def test_control_channel_injects_faults_and_reports_status(running: tuple[EmulatorRuntime, tuple[str, int]]) -> None:
    runtime, address = running
    status = request(address, {"op": "status"})
    assert status["ok"] and status["plant"] == "motors"
    assert [j["name"] for j in status["joints"]] == list("abcde")
    a = status["joints"][0]
    assert a["component"] == "dm" and a["enabled"] is False and a["braked"] is True and a["fault"] == 0
    assert [b["bus"].split(":")[0] for b in status["buses"]] == ["virtual"] * 4

    fault = request(address, {"op": "fault", "joint": "a", "code": 0xD})
    assert fault == {"ok": True, "joints": ["a"]}
    a_fw = runtime.joints[0].firmware
    assert a_fw.fault == 0xD
    assert request(address, {"op": "status"})["joints"][0]["fault"] == 0xD

    reply = request(address, {"op": "set", "joint": "c", "drop_replies": 0.5, "reply_delay": 0.01, "silent": True})
    assert reply["ok"] and reply["joints"] == ["c"]
    c_fw = runtime.joints[2].firmware
    assert (c_fw.drop_replies, c_fw.reply_delay, c_fw.silent) == (0.5, 0.01, True)
    assert request(address, {"op": "set", "silent": False})["joints"] == list("abcde")
    assert not any(j.firmware.silent for j in runtime.joints)

    assert request(address, {"op": "clear", "joint": "a"})["ok"] and a_fw.fault == 0
    # Glitches corrupt what a drive reports, in joint space, for the next replies (or until cleared).
    glitch = runtime.joints[1].firmware.glitch
    assert request(address, {"op": "glitch", "joint": "b", "value": 7.0, "replies": 3}) == {"ok": True, "joints": ["b"]}
    b = runtime.joints[1]
    assert glitch.replies[0] == 3 and glitch.value[0] == b.to_actuator(7.0)
    assert [glitch.corrupt(0, 0.1) for _ in range(4)] == [b.to_actuator(7.0)] * 3 + [0.1]
    assert request(address, {"op": "glitch", "joint": "b", "frozen": True, "sign_flip": True})["ok"]
    assert glitch.frozen[0] and glitch.sign_flip[0]
    assert request(address, {"op": "glitch", "joint": "b", "clear": True})["ok"] and not glitch.active
    assert request(address, {"op": "fault", "joint": "d", "code": 0x0004})["ok"]  # MyActuator: low voltage
    d_fw = runtime.joints[3].firmware
    assert d_fw.fault == 0x0004
    assert request(address, {"op": "reboot", "joint": "d"}) == {"ok": True, "joints": ["d"]}
    assert d_fw.fault == 0 and not d_fw.enabled  # a power cycle: healthy, disabled

    bad = [
        ({"op": "fault", "joint": "a", "code": 0x3}, "damiao fault codes are"),
        ({"op": "fault", "joint": "a"}, "integer 'code'"),
        ({"op": "fault", "code": 13}, "needs a 'joint'"),
        ({"op": "clear", "joint": "ghost"}, "unknown joint 'ghost'"),
        ({"op": "set", "joint": "a", "drop_replies": 2}, "probability"),
        ({"op": "set", "joint": "a", "silent": "yes"}, "true or false"),
        ({"op": "set", "joint": "a", "volume": 11}, "unknown setting 'volume'"),
        ({"op": "glitch", "joint": "a", "offset": "big"}, "finite number"),
        ({"op": "glitch", "joint": "a", "frozen": 1}, "true or false"),
        ({"op": "glitch", "joint": "a"}, "glitch takes"),
        ({"op": "glitch", "offset": 1.0}, "needs a 'joint'"),
        ({"op": "dance"}, "unknown op 'dance'"),
    ]
    for payload, why in bad:
        reply = request(address, payload)
        assert reply["ok"] is False and why in reply["error"], (payload, reply)
    for line, why in ((b"{not json", "not JSON"), (b"[1, 2]", "a JSON object")):
        reply = runtime.call(line)
        assert reply["ok"] is False and why in reply["error"], reply
    assert a_fw.fault == 0  # nothing above changed a drive

    assert request(address, {"op": "stop"}) == {"ok": True}
    assert runtime.stop_event.wait(10)


def test_served_remote_bus_reaches_the_emulated_drives(write_config: Callable[..., Path]) -> None:
    config = arm6(bus={"interface": "remote", "channel": "ws://127.0.0.1:54701/"})
    runtime = build_runtime(load_config(write_config(config)), RuntimeOptions(plant="motors"))
    runtime.open(serve_remote=("127.0.0.1", 0))
    thread = threading.Thread(target=runtime.run, args=(0.0005,), daemon=True)
    thread.start()
    try:
        address = runtime.remote_address
        assert address is not None and address[0] == "127.0.0.1" and address[1] > 0
        with can.Bus(interface="remote", channel=f"ws://127.0.0.1:{address[1]}/", receive_own_messages=False) as bus:
            bus.send(reg.refresh_request(0x03))  # elbow's drive, MST_ID 0x13
            reply = None
            for _ in range(100):
                reply = bus.recv(timeout=0.1)
                if reply is not None:
                    break
            assert reply is not None and reply.arbitration_id == 0x13 and reply.data[0] & 0x0F == 0x03
    finally:
        runtime.stop_event.set()
        thread.join(10)
        runtime.close()
    with pytest.raises(ValueError, match="no emulated component uses a bus with interface: remote"):
        build_runtime(load_config(write_config(arm6(), "virtual.yaml"))).open(serve_remote=("127.0.0.1", 0))


def test_emulate_command_line(write_config: Callable[..., Path], capsys: pytest.CaptureFixture[str]) -> None:
    args = build_parser().parse_args(
        ["emulate", "robot.yaml", "--serve-remote", "127.0.0.1:54701", "--control", "localhost:0", "--initial", "a=0.5"]
    )
    assert (args.serve_remote, args.control, args.initial) == (("127.0.0.1", 54701), ("localhost", 0), [("a", 0.5)])
    assert args.plant is None and args.brakes is True and args.rate is None
    for bad in (["--serve-remote", "54701"], ["--control", "host:port"], ["--initial", "a=x"], ["--plant", "moon"]):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["emulate", "robot.yaml", *bad])
    capsys.readouterr()
    twin_only = load_config(CONFIGS / "arm6_twin.yaml").path
    assert main(["emulate", str(twin_only)]) == 1
    assert "no CAN hardware component" in capsys.readouterr().err
