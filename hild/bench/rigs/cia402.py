"""The CiA 402 bench rig: six CANopen drives of configs/cia402_generic.eds, emulated on one virtual channel.

The same rig as ``mit_can`` (:class:`hild.bench.rigs.mit_can.CanBenchRig`: one service loop, the frame tap, the rig
process when bridged) with the emulated drive of ``hild emulate`` (``drivers.can.emulator.cia402_firmware``) in
cyclic synchronous position, behind independent motor plants. hild produces SYNC after each cycle's RPDOs; every
drive answers one TPDO per SYNC. The latency probes watch the first drive: its RPDO's target position (command)
and its TPDO's position actual (reply), decoded with ``canopen``'s own PDO maps of the layout hild configured.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from drivers.can.bus import BusSpec
from drivers.can.emulator import MotorFirmware, Plant
from drivers.can.emulator.cia402_firmware import Cia402Firmware
from drivers.can.emulator.runtime import build_firmware
from drivers.can.params import Cia402Params
from hild.bench.rigs.mit_can import START_POSITIONS, CanBenchRig, Probe, bench_controllers, components_with_plants
from hild.config.loader import LoadedConfig

EDS = Path(__file__).resolve().parents[3] / "configs" / "cia402_generic.eds"
STALE_FEEDBACK_CYCLES = 50  # as the mit_can rig: the emulated drives share the machine's cores
RATED_TORQUE = 10.0  # N·m, the generic drive's 0x6076
EFFORT = 9.0  # N·m at the joint, below the drive's max torque
RPDO_BASE, TPDO_BASE = 0x200, 0x180  # RPDO1 and TPDO1 COB-IDs (CiA 301 predefined connection set) + node id
RPDO_MAPPING, TPDO_MAPPING = 0x1600, 0x1A00
TARGET_POSITION, POSITION_ACTUAL = 0x607A, 0x6064


def robot_config(drives: int, rate: float) -> dict[str, Any]:
    """A robot of ``drives`` CiA 402 joints ``j1..jn`` in CSP on one private virtual channel (component ``bus1``).

    Controllers as the ``mit_can`` rig's: ``joint_state_broadcaster`` (100 Hz, autostart), ``joint_trajectory``
    (position: CSP takes no velocity offset in one classic RPDO) and ``forward_position`` (the latency probes)."""
    if not 1 <= drives <= len(START_POSITIONS):
        raise ValueError(f"1 to {len(START_POSITIONS)} drives, not {drives}")
    names = [f"j{k + 1}" for k in range(drives)]
    return {
        "robot": {"name": f"cia402_{drives}"},
        "update_rate": rate,
        "clock": {"source": "wall"},
        "hardware": {
            "bus1": {
                "driver": "cia402",
                "params": {
                    "bus": {
                        "interface": "virtual",
                        "channel": f"hild-bench-{uuid.uuid4().hex[:10]}",
                        "bitrate": 1_000_000,
                    },
                    "eds": str(EDS),
                    "mode": "csp",
                    "reply_timeout_ms": 200,
                    "drives": {name: {"node_id": k + 1} for k, name in enumerate(names)},
                },
                "joints": {name: {} for name in names},
            }
        },
        "joints": {
            name: {
                "limits": {
                    "position": {"lower": -3.0, "upper": 3.0},
                    "soft_margin": 0.05,
                    "velocity": 3.0,
                    "acceleration": 8.0,
                    "jerk": 80.0,
                    "effort": EFFORT,
                },
                "hold": {"kp": 30.0, "kd": 1.0},
            }
            for name in names
        },
        "controllers": bench_controllers(names, ["position"]),  # CSP: no velocity offset in the 8-byte RPDO
        "safety": {"fault_action": "hold", "estop_action": "hold", "stale_feedback_cycles": STALE_FEEDBACK_CYCLES},
    }


class Cia402BenchRig(CanBenchRig):
    """The ``cia402`` rig (a ``hild.bench.rigs.BenchRig``): see the module docstring."""

    trajectory_scale = 0.5

    @staticmethod
    def robot_config(joints: int, rate: float) -> dict[str, Any]:
        return robot_config(joints, rate)

    def drives(self, loaded: LoadedConfig) -> Iterator[tuple[BusSpec, list[MotorFirmware], Plant, Probe]]:
        """Per ``cia402`` component: its bus, its emulated drives, their plant, and its first drive's probe."""
        for params, joints, plant in components_with_plants(loaded, Cia402Params, "the CiA 402 bench rig", "cia402"):
            firmware = build_firmware(params, joints, loaded.directory)
            drive = firmware[0]
            assert isinstance(drive, Cia402Firmware)
            yield params.bus, list(firmware), plant, PdoProbe(drive)


class PdoProbe:
    """The first drive's RPDO (target position: command) and TPDO (position actual: reply), located in the PDO
    mappings hild wrote to the drive by SDO and decoded with ``canopen``'s own object dictionary.

    The mapping is read when a frame is first decoded: by then the daemon has configured the drive."""

    def __init__(self, drive: Cia402Firmware) -> None:
        self.drive = drive
        self.joint = drive.wiring.joint
        node = drive.node_id
        self.ids = {RPDO_BASE + node, TPDO_BASE + node}
        self.lsb = 1.0 / drive.wiring.counts_per_rad
        self._fields: dict[int, tuple[str, int, Any]] | None = None

    def _locate(self) -> dict[int, tuple[str, int, Any]]:
        """COB-ID → (kind, byte offset, OD variable) of the watched object in the first RPDO/TPDO."""
        node, od = self.drive.node, self.drive.node.object_dictionary
        fields: dict[int, tuple[str, int, Any]] = {}
        for kind, mapping, cob, index in (
            ("command", RPDO_MAPPING, RPDO_BASE, TARGET_POSITION),
            ("reply", TPDO_MAPPING, TPDO_BASE, POSITION_ACTUAL),
        ):
            count = od[mapping][0].decode_raw(node.sdo.upload(mapping, 0))
            offset = 0
            for sub in range(1, count + 1):
                entry = od[mapping][sub].decode_raw(node.sdo.upload(mapping, sub))
                if entry >> 16 == index:
                    fields[cob + self.drive.node_id] = (kind, offset, od[index])
                    break
                offset += (entry & 0xFF) // 8
        return fields

    def decode(self, arbitration_id: int, data: bytes) -> tuple[str, float] | None:
        if self._fields is None:
            self._fields = self._locate()
        field = self._fields.get(arbitration_id)
        if field is None:
            return None
        kind, offset, variable = field
        size = len(variable.encode_raw(0))
        if len(data) < offset + size:
            return None
        return kind, variable.decode_raw(data[offset : offset + size]) * self.lsb
