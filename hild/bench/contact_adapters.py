"""The one seam between the contact bench and the pieces it measures: observer + reflex, walls, teach mode.

``hild bench --only contact`` (hild.bench.contact) reaches those pieces only through `ContactAdapters`, so wiring
them in is a change to this file alone. Each ``*_missing()`` names the piece when this install lacks it; the
bench then reports that target as MISS "not available: <piece>" and never runs a stand-in. What each method must
do once its piece exists:

* **observer and reflex** ([B]): `observer_safety(on)` — the ``safety`` keys that switch the momentum observer and
  collision reflex on (or off, for the cycle-cost baseline); `collision_latched(engine)` — true from the cycle
  the supervisor latched the collision fault (a joint in mode FAULT with Fault COLLISION or a fault text naming a
  collision); `tau_ext(engine)` — the observer's external torque per joint (N·m) or None;
  `collision_force_threshold()` — the collision threshold expressed as a force at the tool (N), which the peak
  contact force is judged against (2 × it).
* **walls** ([C]): `walls_safety(lower, upper)` — the ``safety`` keys of a box the tool must stay in (world, m).
* **teach** ([D]): `teach_controllers(joints)` — controller entries to add to the config (name → entry), and
  `TEACH_CONTROLLER` the one to activate for hand-guiding.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from typing import Any

import numpy as np

from hild.config.model import SafetySection
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from hild.modes import JointMode
from hild.plugins import CONTROLLERS, available

OBSERVER_PIECE = "collision observer + reflex ([B] hild/cycle/contact.py, safety.contact, Fault COLLISION)"
WALLS_PIECE = "virtual walls ([C] hild/cycle/walls.py, safety.walls)"
TEACH_PIECE = "teach mode ([D] hild/controllers/teach.py, controller type teach)"
TEACH_CONTROLLER = "teach"
DEFAULT_COLLISION_FORCE_N = 20.0  # the force the detection target must catch: the reflex's threshold at the tool


def _module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False


class ContactAdapters:
    """The pieces as this install has them (see the module docstring for what each method must do)."""

    # ---- observer and collision reflex [B] ----------------------------------------------------------------------
    def observer_missing(self) -> str | None:
        have = (
            _module("hild.cycle.contact")
            and "contact" in SafetySection.model_fields
            and getattr(Fault, "COLLISION", None) is not None
        )
        return None if have else OBSERVER_PIECE

    def observer_safety(self, on: bool) -> dict[str, Any]:
        if not on and self.observer_missing():
            return {}  # the baseline without the piece: no key it would not know
        return {"contact": {"enabled": on}}

    def collision_latched(self, engine: Engine) -> bool:
        sup = engine.supervisor
        if not (sup.mode == int(JointMode.FAULT)).any():
            return False
        code = getattr(Fault, "COLLISION", None)
        if code is not None and (sup.fault == int(code)).any():
            return True
        return any("collision" in text.lower() for text in sup.fault_text)

    def tau_ext(self, engine: Engine) -> np.ndarray | None:
        contact = getattr(engine, "contact", None)
        value = getattr(contact, "tau_ext", None)
        return None if value is None else np.asarray(value, dtype=float)

    def collision_force_threshold(self) -> float:
        return DEFAULT_COLLISION_FORCE_N

    # ---- virtual walls [C] ----------------------------------------------------------------------------------------
    def walls_missing(self) -> str | None:
        have = _module("hild.cycle.walls") and "walls" in SafetySection.model_fields
        return None if have else WALLS_PIECE

    def walls_safety(self, lower: Sequence[float], upper: Sequence[float]) -> dict[str, Any]:
        return {"walls": {"enabled": True, "box": {"min": [float(v) for v in lower], "max": [float(v) for v in upper]}}}

    # ---- teach mode [D] -------------------------------------------------------------------------------------------
    def teach_missing(self) -> str | None:
        return None if TEACH_CONTROLLER in available(CONTROLLERS) else TEACH_PIECE

    def teach_controllers(self, joints: Sequence[str]) -> dict[str, Any]:
        return {TEACH_CONTROLLER: {"type": TEACH_CONTROLLER, "params": {"joints": list(joints)}}}
