"""MuJoCo digital twin driver (``driver: mujoco``): see :mod:`drivers.mujoco.twin` and docs/drivers.md."""

from drivers.mujoco.twin import MujocoTwin, MujocoTwinParams

__all__ = ["MujocoTwin", "MujocoTwinParams"]
