"""CANopen CiA 402 drives: the ``cia402`` host driver, and the wiring it shares with the emulated drives.

The CANopen stack is the ``canopen`` library (object dictionaries from EDS/DCF, SDO, EMCY, NMT); it lives in this
room (``drivers/can``) only. The cyclic PDO exchange is hild's own: preallocated frames packed in place, as the MIT
and ODrive drivers do, so the cycle never goes through a library thread.
"""
