"""The arm in 3D: model shapes logged once (static), body poses sent as columns at the decimated pose rate.

Shapes come from :class:`hild.dynamics.kinematics.Kinematics` as plain arrays (mujoco stays in its room). Each body
is an entity ``arm/<body>`` whose ``Transform3D`` is its world pose; its geoms are static children with their local
pose, so the viewer composes them. Planes (floors) are left out: they would dwarf the arm.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr

from hild.dynamics.kinematics import GeomShape, Kinematics
from hild.telemetry.layout import ARM, body_path


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    return wxyz[..., [1, 2, 3, 0]]


def _shape(g: GeomShape) -> Any | None:
    color = np.clip(g.rgba * 255, 0, 255).astype(np.uint8)
    solid = rr.components.FillMode.Solid
    if g.kind == "box":
        return rr.Boxes3D(half_sizes=[g.size], colors=[color], fill_mode=solid)
    if g.kind == "sphere":
        return rr.Ellipsoids3D(half_sizes=[[g.size[0]] * 3], colors=[color], fill_mode=solid)
    if g.kind == "ellipsoid":
        return rr.Ellipsoids3D(half_sizes=[g.size], colors=[color], fill_mode=solid)
    if g.kind == "cylinder":
        return rr.Cylinders3D(lengths=[2 * g.size[1]], radii=[g.size[0]], colors=[color], fill_mode=solid)
    if g.kind == "capsule":
        half = g.size[1]
        return rr.Capsules3D(
            lengths=[2 * half], radii=[g.size[0]], translations=[[0, 0, -half]], colors=[color], fill_mode=solid
        )
    if g.kind == "mesh" and g.vertices is not None and g.faces is not None:
        return rr.Mesh3D(vertex_positions=g.vertices, triangle_indices=g.faces, albedo_factor=color)
    return None  # planes, height fields, SDFs


class ArmScene:
    """Static shapes and per-tick body transforms of one arm model."""

    def __init__(self, kinematics: Kinematics) -> None:
        self.kinematics = kinematics
        self.bodies = kinematics.body_names
        self.paths = tuple(body_path(b) for b in self.bodies)

    def log_static(self, rec: rr.RecordingStream) -> None:
        """Shapes and their local poses, once per recording stream."""
        rec.log(ARM, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for g in self.kinematics.geoms:
            shape = _shape(g)
            if shape is None:
                continue
            parent = body_path(self.bodies[g.body]) if g.body >= 0 else f"{ARM}/world"
            path = f"{parent}/{g.name}"
            rec.log(path, rr.Transform3D(translation=g.pos, quaternion=_xyzw(g.quat)), static=True)
            rec.log(path, shape, static=True)

    def pose_columns(self, positions: np.ndarray) -> list[tuple[str, Any]]:
        """``(entity, Transform3D columns)`` per body for each row of joint positions (k × joints)."""
        xyz, wxyz = self.kinematics.body_poses(positions)
        quat = _xyzw(wxyz)
        return [
            (path, rr.Transform3D.columns(translation=xyz[:, b], quaternion=quat[:, b]))
            for b, path in enumerate(self.paths)
        ]
