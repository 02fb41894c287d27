"""The emulated drives, one import away: every firmware model and the base they share."""

from drivers.can.emulator.base import MotorFirmware, ThermalModel
from drivers.can.emulator.cia402_firmware import Cia402Firmware
from drivers.can.emulator.mit_firmware import DamiaoFirmware, MitFirmware, MyActuatorFirmware, TMotorFirmware
from drivers.can.emulator.odrive_firmware import ODriveFirmware

__all__ = [
    "Cia402Firmware",
    "DamiaoFirmware",
    "MitFirmware",
    "MotorFirmware",
    "MyActuatorFirmware",
    "ODriveFirmware",
    "TMotorFirmware",
    "ThermalModel",
]
