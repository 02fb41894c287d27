"""The arm model through MuJoCo, outside the twin: the one room besides ``drivers/mujoco`` that imports mujoco
(docs/architecture.md, "Rules"). One module per use:

- :mod:`hild.dynamics.model`       loading a model (MJCF or URDF, MuJoCo's own loader) and finding its joints:
  what the twin, the emulator's plant and everything below share, so they always agree on the same file;
- :mod:`hild.dynamics.gravity`     the gravity feed-forward of hold and controllers (runs on the cycle);
- :mod:`hild.dynamics.momentum`    the momentum observer: the external torque estimate of the contact check (cycle);
- :mod:`hild.dynamics.friction`    the identified friction model (plain numpy);
- :mod:`hild.dynamics.tool`        the tool point's position and Jacobian: the virtual walls (on the cycle) and the
  collision reflex's retract;
- :mod:`hild.dynamics.collision`   the arm touching itself at a commanded pose (the walls' option, on the cycle);
- :mod:`hild.dynamics.kinematics`  body poses and shapes for the telemetry's 3D view;
- :mod:`hild.dynamics.inspection`  what the importer and ``hild check`` ask of a model: joint inertia over poses,
  contacts at a pose.
"""
