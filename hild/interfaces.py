"""Command interfaces and exclusive claims.

A command interface is named ``<joint>/<field>`` with field one of the servo command's ``position, velocity,
effort, kp, kd``. A claim is exclusive, and stricter than ros2_control: all claimed fields of one joint belong to
the same controller, because the five fields form one servo command and mixing owners has no safe meaning.

A controller that claims effort may also ask for **gravity on top** of it (``Controller.gravity_joints``): the
supervisor then adds the robot model's gravity torque to that controller's effort for those joints, as a real arm's
driver does under an effort-interface controller (docs/safety.md, "Gravity on top of an effort command").
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

__all__ = [
    "FIELDS",
    "ClaimError",
    "ClaimMasks",
    "build_masks",
    "check_claims",
    "interface_name",
    "parse_interface",
]

FIELDS = ("position", "velocity", "effort", "kp", "kd")


class ClaimError(ValueError):
    pass


def interface_name(joint: str, field: str) -> str:
    return f"{joint}/{field}"


def parse_interface(name: str) -> tuple[str, str]:
    joint, sep, field = name.rpartition("/")
    if not sep or not joint or field not in FIELDS:
        raise ClaimError(f"bad interface name {name!r}: expected '<joint>/<{'|'.join(FIELDS)}>'")
    return joint, field


def check_claims(claimant: str, claims: Iterable[str], available: set[str]) -> None:
    for name in claims:
        parse_interface(name)
        if name not in available:
            raise ClaimError(f"{claimant}: interface {name!r} does not exist")


@dataclass(slots=True)
class ClaimMasks:
    """Per-joint view of who claims what, rebuilt at each switch and read by the supervisor every cycle."""

    owner: np.ndarray  # controller slot index per joint, -1 = unclaimed
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    gravity: np.ndarray  # the supervisor adds the gravity torque to the owner's effort command (effort claims only)

    @classmethod
    def empty(cls, n: int) -> ClaimMasks:
        return cls(np.full(n, -1, dtype=np.int64), *(np.zeros(n, dtype=bool) for _ in (*FIELDS, "gravity")))


def build_masks(
    joint_index: Mapping[str, int],
    claims_by_slot: Mapping[int, Iterable[str]],
    owner_names: Mapping[int, str],
    gravity_by_slot: Mapping[int, Iterable[str]] | None = None,
) -> ClaimMasks:
    """Turn the active controllers' claims into masks; raises ClaimError on any conflict. ``gravity_by_slot``: the
    joints each controller wants gravity added to its effort on (a joint whose effort it does not claim is
    refused: there is no effort of its own to add to)."""
    masks = ClaimMasks.empty(len(joint_index))
    taken: dict[str, int] = {}
    for slot, claims in claims_by_slot.items():
        for name in claims:
            joint, field = parse_interface(name)
            if name in taken:
                raise ClaimError(f"{name} is claimed by both {owner_names[taken[name]]} and {owner_names[slot]}")
            i = joint_index[joint]
            if masks.owner[i] not in (-1, slot):
                other = owner_names[int(masks.owner[i])]
                raise ClaimError(f"joint {joint} is commanded by {other}; {owner_names[slot]} cannot claim {name}")
            taken[name] = slot
            masks.owner[i] = slot
            getattr(masks, field)[i] = True
    for slot, joints in (gravity_by_slot or {}).items():
        for joint in joints:
            i = joint_index[joint]
            if masks.owner[i] != slot or not masks.effort[i]:
                raise ClaimError(
                    f"{owner_names[slot]} asks for gravity on top of its effort on {joint}, which it "
                    "does not command by effort"
                )
            masks.gravity[i] = True
    return masks
