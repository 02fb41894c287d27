"""Firmware-faithful emulated CAN drives on any python-can bus, for tests, `hild emulate` and benchmarks."""

from drivers.can.emulator.core import Emulator
from drivers.can.emulator.firmware import (
    Cia402Firmware,
    DamiaoFirmware,
    MotorFirmware,
    MyActuatorFirmware,
    ODriveFirmware,
    ThermalModel,
    TMotorFirmware,
)
from drivers.can.emulator.plant import MotorPlant, Plant

__all__ = [
    "Cia402Firmware",
    "DamiaoFirmware",
    "Emulator",
    "MotorFirmware",
    "MotorPlant",
    "MyActuatorFirmware",
    "ODriveFirmware",
    "Plant",
    "TMotorFirmware",
    "ThermalModel",
]
