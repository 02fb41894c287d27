"""The CiA 402 drive state machine as the cycle needs it: the state a statusword shows, and which controlword
walks a drive toward Operation Enabled or keeps it where it is.

Masks, values and controlwords come from ``canopen.profiles.p402.State402``; this module turns them into flat
lookup tables (statusword low bits → state number, state number → controlword) so the cycle does one list index
per drive and no string compare.
"""

from __future__ import annotations

from canopen.profiles.p402 import State402

__all__ = [
    "CW_FAULT_RESET",
    "CW_HALT",
    "CW_HOMING_START",
    "DISABLED_CW",
    "HOLD_CW",
    "STATE_NAMES",
    "WALK_CW",
    "state_of",
]

STATE_NAMES: tuple[str, ...] = (*State402.SW_MASK, "UNKNOWN")
"""State numbers: the index into this tuple (``SW_MASK``'s order, then UNKNOWN for a statusword matching none)."""
NOT_READY, SWITCH_ON_DISABLED, READY, SWITCHED_ON, OPERATION_ENABLED, FAULT, FAULT_REACTION, QUICK_STOP, UNKNOWN = (
    STATE_NAMES.index(name)
    for name in (
        "NOT READY TO SWITCH ON",
        "SWITCH ON DISABLED",
        "READY TO SWITCH ON",
        "SWITCHED ON",
        "OPERATION ENABLED",
        "FAULT",
        "FAULT REACTION ACTIVE",
        "QUICK STOP ACTIVE",
        "UNKNOWN",
    )
)
FAULTED = frozenset({FAULT, FAULT_REACTION})

_STATE_TABLE: list[int] = []
for _low in range(0x80):
    _STATE_TABLE.append(
        next((i for i, (mask, value) in enumerate(State402.SW_MASK.values()) if _low & mask == value), UNKNOWN)
    )


def state_of(statusword: int) -> int:
    """The state number a statusword shows (bits 0–3, 5, 6 decide)."""
    return _STATE_TABLE[statusword & 0x7F]


_CW = State402.CW_COMMANDS_CODE
CW_FAULT_RESET = State402.CW_SWITCH_ON_DISABLED  # bit 7: fault reset, acting on its rising edge
CW_HOMING_START = 0x0010  # bit 4 in homing mode: start homing (rising edge)
CW_HALT = 0x0100  # bit 8

WALK_CW: tuple[int, ...] = tuple(
    {
        SWITCH_ON_DISABLED: _CW["READY TO SWITCH ON"],  # shutdown: transition 2
        READY: _CW["SWITCHED ON"],  # switch on: 3
        SWITCHED_ON: _CW["OPERATION ENABLED"],  # enable operation: 4
        OPERATION_ENABLED: _CW["OPERATION ENABLED"],
    }.get(state, _CW["DISABLE VOLTAGE"])
    for state in range(len(STATE_NAMES))
)
"""The controlword that takes a drive one step toward Operation Enabled (only ever on activate or an operator's
enable). QUICK STOP ACTIVE goes through Switch On Disabled (disable voltage, transition 12), never straight back
(16); FAULT stays (only a fault reset leaves it)."""

HOLD_CW: tuple[int, ...] = tuple(
    {
        READY: _CW["READY TO SWITCH ON"],
        SWITCHED_ON: _CW["SWITCHED ON"],
        OPERATION_ENABLED: _CW["OPERATION ENABLED"],
        QUICK_STOP: _CW["QUICK STOP ACTIVE"],
    }.get(state, _CW["DISABLE VOLTAGE"])
    for state in range(len(STATE_NAMES))
)
"""The controlword that keeps a drive in the state it is in (no enable a drive did not ask for)."""

DISABLED_CW = _CW["DISABLE VOLTAGE"]
"""Disable voltage: transitions 7, 9, 10, 12 to Switch On Disabled."""
