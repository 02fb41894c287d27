"""The cycle log: every cycle's full record, in a ring the recorder and the flight recorder read (docs/recording.md).

The cycle writes one row per cycle after its write (``CycleLogTap.record``, a few in-place numpy copies, no
allocation); the row holds everything a recording needs to be cycle-exact: the cycle's clock and wall time, the
accepted reading, the final command (all five servo fields), each joint's mode, owner, plausibility and fault, and
the external torque estimate. The ring keeps at least ``recording.blackbox_seconds`` of cycles, so it *is* the flight
recorder's memory: nothing extra is kept on the cycle for it. It lives in the shared region (a cell carved by the
region's creator), so it outlives a client domain that dies; single producer, any number of readers, each with its
own position (a slow reader skips and counts, never slows the cycle).

``CycleRows`` is what a reader copies out, and what the episode files are written from and read back into.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

OWNER_NONE = 0  # the owner code of a joint no controller commands (held, faulted, e-stopped)


@dataclass(frozen=True)
class CycleRows:
    """Rows of the cycle log, oldest first; every array owns its memory. ``k`` rows, ``n`` joints (robot order)."""

    tick: np.ndarray  # int64 (k,): the engine's cycle count
    t: np.ndarray  # float64 (k,): the cycle clock, s
    wall: np.ndarray  # float64 (k,): CLOCK_REALTIME at the cycle's read, s since the epoch
    period: np.ndarray  # float64 (k,): the cycle's dt, s
    duration: np.ndarray  # float64 (k,): the previous completed cycle's duration (wake → write done), s
    measured_position: np.ndarray  # float64 (k, n): the accepted reading (after the plausibility check)
    measured_velocity: np.ndarray
    measured_effort: np.ndarray
    fresh: np.ndarray  # bool (k, n): a new reading was accepted this cycle (False: silent or rejected)
    fault: np.ndarray  # int16 (k, n): the joint's latched fault (hild.cycle.supervisor.Fault; 0 = none)
    position: np.ndarray  # float64 (k, n): the final command, the supervisor's (joint space)
    velocity: np.ndarray
    effort: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    mode: np.ndarray  # int8 (k, n): hild.modes.JointMode
    owner: np.ndarray  # int16 (k, n): the commanding controller's code (OWNER_NONE: none); Snapshot.controller_codes
    tau_ext: np.ndarray  # float64 (k, n): the external torque estimate, NaN while no observer runs

    def __len__(self) -> int:
        return len(self.tick)

    def select(self, keep: np.ndarray | slice) -> CycleRows:
        """The rows ``keep`` picks (a boolean mask, indices or a slice), as a new ``CycleRows``."""
        return CycleRows(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})

    @classmethod
    def concat(cls, parts: list[CycleRows], joints: int) -> CycleRows:
        """Parts joined in order (an empty list gives zero rows of ``joints`` joints)."""
        if not parts:
            return cls.empty(joints)
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})

    @classmethod
    def empty(cls, joints: int) -> CycleRows:
        scalar = {"tick": np.int64}
        per_joint = {"fresh": np.bool_, "fault": np.int16, "mode": np.int8, "owner": np.int16}
        out = {}
        for f in fields(cls):
            if f.name in ("tick", "t", "wall", "period", "duration"):
                out[f.name] = np.zeros(0, dtype=scalar.get(f.name, np.float64))
            else:
                out[f.name] = np.zeros((0, joints), dtype=per_joint.get(f.name, np.float64))
        return cls(**out)
