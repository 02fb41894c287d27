"""Pure CAN codecs: MIT-protocol family (Damiao, T-Motor AK, MyActuator), Damiao registers, ODrive CAN Simple.

No I/O and no state: every function maps values to frames or frames to values, so the host driver and the
emulator share one definition of each wire format.
"""

from drivers.can.protocol.errors import FrameError

__all__ = ["FrameError"]
