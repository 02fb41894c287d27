"""ruckig's online trajectory generator, for the controllers that re-plan on every cycle (``servo``, ``follow``).

ruckig lives in this room (docs/architecture.md, "Rooms"). The streaming controllers drive its per-cycle API
themselves — one input, one output, one ``update`` per cycle, limits and control interface changed in place — so the
room hands them ruckig's own types instead of a layer around each call, which would cost the cycle a Python call per
joint per cycle for nothing. ``planning`` is the offline side (whole plans for goals).
"""

from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, RuckigError, Synchronization

__all__ = [
    "ControlInterface",
    "InputParameter",
    "OutputParameter",
    "Result",
    "Ruckig",
    "RuckigError",
    "Synchronization",
]
