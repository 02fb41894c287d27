"""Mapping ranges per flavour and motor model, as the vendors' SDKs ship them.

Both ends must use the same ranges or every value is scaled wrongly, so a config names the model and may override
single fields (Damiao drives keep the true values in registers PMAX/VMAX/TMAX, which a driver should read back).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from drivers.can.protocol.mit import MitRanges

_P = 12.5

MODELS: dict[str, dict[str, MitRanges]] = {
    "damiao": {
        "DM3507": MitRanges(_P, 50.0, 5.0),
        "DM4310": MitRanges(_P, 30.0, 10.0),
        "DM4310_48V": MitRanges(_P, 50.0, 10.0),
        "DM4310P": MitRanges(_P, 50.0, 10.0),
        "DM4340": MitRanges(_P, 10.0, 28.0),
        "DM4340_48V": MitRanges(_P, 10.0, 28.0),
        "DM4340P": MitRanges(_P, 10.0, 28.0),
        "DM6006": MitRanges(_P, 45.0, 20.0),
        "DM8006": MitRanges(_P, 45.0, 40.0),
        "DM8009": MitRanges(_P, 45.0, 54.0),
        "DM10010L": MitRanges(_P, 25.0, 200.0),
        "DM10010": MitRanges(_P, 20.0, 200.0),
        "DMH3510": MitRanges(_P, 280.0, 1.0),
        "DMH6215": MitRanges(_P, 45.0, 10.0),
        "DMG6220": MitRanges(_P, 45.0, 10.0),
    },
    "tmotor": {
        "AK80-9": MitRanges(_P, 50.0, 18.0),
        "AK10-9": MitRanges(_P, 50.0, 65.0),
        "AK60-6": MitRanges(_P, 50.0, 15.0),
        "AK70-10": MitRanges(_P, 50.0, 25.0),
        "AK80-6": MitRanges(_P, 76.0, 12.0),
        "AK80-64": MitRanges(_P, 8.0, 144.0),
    },
    "myactuator": {
        # Protocol V4.3 §5.1 gives one set of motion-mode ranges for the whole X series.
        "motion_mode": MitRanges(_P, 45.0, 24.0),
    },
}

RANGE_FIELDS = tuple(f.name for f in dataclasses.fields(MitRanges))


def ranges_for(flavour: str, model: str, overrides: Mapping[str, float] | None = None) -> MitRanges:
    """The ranges of `model`, with any of p_max/v_max/t_max/kp_max/kd_max replaced by `overrides`.

    Raises ValueError naming the known choices, so a config error explains itself.
    """
    models = MODELS.get(flavour)
    if models is None:
        raise ValueError(f"unknown MIT flavour {flavour!r}; known: {sorted(MODELS)}")
    base = models.get(model)
    if base is None:
        raise ValueError(f"unknown {flavour} model {model!r}; known: {sorted(models)}")
    if not overrides:
        return base
    unknown = set(overrides) - set(RANGE_FIELDS)
    if unknown:
        raise ValueError(f"unknown range fields {sorted(unknown)}; allowed: {list(RANGE_FIELDS)}")
    return dataclasses.replace(base, **{k: float(v) for k, v in overrides.items()})
