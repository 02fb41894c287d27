"""CiA 301/402 error codes (EMCY frames, 0x603F) in words, and the EMCY frame itself.

The table names the standard codes a CiA 402 drive reports (CiA 301 general codes, CiA 402 drive codes); a code it
does not list is named by ``canopen``'s own error-group description (``EmcyError.get_desc``), so every code gets
at least its class (current, voltage, temperature, monitoring …) and its hex value.
"""

from __future__ import annotations

from canopen.emcy import EMCY_STRUCT, EmcyError

__all__ = ["EMCY_STRUCT", "ERROR_CODES", "describe_error_code", "emcy_code"]

ERROR_CODES: dict[int, str] = {
    0x1000: "generic error",
    0x2110: "short circuit / earth leakage (input)",
    0x2120: "earth leakage (input)",
    0x2130: "short circuit (input)",
    0x2211: "internal over-current",
    0x2220: "continuous over-current (device)",
    0x2230: "short circuit / earth leakage (device)",
    0x2310: "continuous over-current",
    0x2311: "continuous over-current (motor)",
    0x2320: "short circuit / earth leakage (output)",
    0x2330: "earth leakage (output)",
    0x2340: "short circuit (output)",
    0x2350: "load level fault (I²t, thermal state)",
    0x3110: "mains over-voltage",
    0x3120: "mains under-voltage",
    0x3130: "phase failure",
    0x3210: "DC-link over-voltage",
    0x3220: "DC-link under-voltage",
    0x3230: "load error (DC link)",
    0x3310: "output over-voltage",
    0x4110: "excess ambient temperature",
    0x4210: "excess device temperature",
    0x4310: "excess drive temperature",
    0x4410: "excess supply temperature",
    0x5112: "supply low voltage (U1)",
    0x5113: "supply low voltage (U2)",
    0x5114: "supply low voltage (U3)",
    0x5210: "measurement circuit",
    0x5410: "output stages",
    0x5530: "data storage (EEPROM) error",
    0x6010: "software reset (watchdog)",
    0x6100: "internal software",
    0x6320: "parameter error",
    0x7110: "brake chopper",
    0x7120: "motor",
    0x7121: "motor blocked",
    0x7122: "motor error or commutation malfunction",
    0x7300: "sensor",
    0x7303: "resolver 1 fault",
    0x7305: "incremental sensor 1 fault",
    0x7310: "speed (sensor)",
    0x7320: "position (sensor)",
    0x8110: "CAN overrun (frames lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8141: "bus off",
    0x8150: "CAN-ID collision",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x8311: "excess torque",
    0x8331: "torque fault",
    0x8400: "velocity speed controller",
    0x8500: "position controller",
    0x8611: "following error",
    0x8612: "reference limit",
    0x8613: "homing error",
    0x8700: "sync controller",
    0x9000: "external error",
    0xF001: "deceleration",
    0xF002: "sub-synchronous run",
    0xF003: "stroke operation",
    0xF004: "control",
}
"""Standard CiA 301 (communication) and CiA 402 (drive) error codes."""


def describe_error_code(code: int) -> str:
    """The code's standard name, else canopen's description of its group; always with the hex value."""
    name = ERROR_CODES.get(code)
    if name is None:
        group = EmcyError(code, 0, b"", 0.0).get_desc()
        name = f"{group.lower()} error" if group else "unknown error"
    return f"{name} ({code:#06x})"


def emcy_code(data: bytes | bytearray) -> tuple[int, int]:
    """(error code, error register) of an EMCY frame; raises ``struct.error`` on one shorter than 8 bytes."""
    code, register, _vendor = EMCY_STRUCT.unpack_from(data)
    return code, register
