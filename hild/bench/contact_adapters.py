"""The one seam between the contact bench and the pieces it measures: observer + reflex, walls, teach mode.

``hild bench --only contact`` (hild.bench.contact) reaches those pieces only through `ContactAdapters`, so a test
can put doubles in (tests/bench/test_contact.py) and wiring a piece differently is a change to this file alone:

* **observer and reflex**: `observer_safety(on)` — the ``safety.contact`` keys that switch the momentum observer
  and collision reflex on (or off, for the cycle-cost baseline); the thresholds are configs/arm6_can.yaml's own;
  `collision_latched(engine)` — true from the cycle the supervisor latched the collision fault;
  `tau_ext(engine)` — the observer's external torque per joint (N·m) or None; `collision_force_threshold()` — the
  Cartesian collision threshold of configs/arm6_can.yaml (``safety.contact.force.collision``, N), which the peak
  contact force is judged against (2 × it).
* **walls**: `walls_safety(lower, upper)` — the ``safety.walls`` keys of a box the tool must stay in (world, m).
* **teach**: `teach_controllers(joints)` — controller entries to add to the config (name → entry), and
  `TEACH_CONTROLLER` the one to activate for hand-guiding.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hild.bench.contact_rig import ARM6_CAN
from hild.config.documents import load_document
from hild.cycle.engine import Engine
from hild.cycle.supervisor import Fault
from hild.modes import JointMode

TEACH_CONTROLLER = "teach"


class ContactAdapters:
    """The pieces as hild has them (see the module docstring for what each method does)."""

    # ---- observer and collision reflex -----------------------------------------------------------------------
    def observer_safety(self, on: bool) -> dict[str, Any]:
        return {"contact": {"enabled": on}}

    def collision_latched(self, engine: Engine) -> bool:
        sup = engine.supervisor
        return bool(((sup.mode == int(JointMode.FAULT)) & (sup.fault == int(Fault.COLLISION))).any())

    def tau_ext(self, engine: Engine) -> np.ndarray | None:
        contact = engine.contact
        return None if contact is None else np.asarray(contact.tau_ext, dtype=float)

    def collision_force_threshold(self) -> float:
        force = load_document(ARM6_CAN)["safety"]["contact"]["force"]
        return float(force["collision"])

    # ---- virtual walls ---------------------------------------------------------------------------------------
    def walls_safety(self, lower: Sequence[float], upper: Sequence[float]) -> dict[str, Any]:
        return {"walls": {"enabled": True, "box": {"min": [float(v) for v in lower], "max": [float(v) for v in upper]}}}

    # ---- teach mode ------------------------------------------------------------------------------------------
    def teach_controllers(self, joints: Sequence[str]) -> dict[str, Any]:
        return {TEACH_CONTROLLER: {"type": TEACH_CONTROLLER, "params": {"joints": list(joints)}}}
