"""``hild check`` on ``safety.walls`` with the model loaded: the tool frame exists, so a config that passes
``check`` never fails ``run`` on it. The schema already refuses an empty box, a zero normal and walls enabled
without any (hild/config/model.py, ``WallsSection``)."""

from __future__ import annotations

from hild.config.loader import LoadedConfig
from hild.config.safety import SafetyFinding


def review_walls(loaded: LoadedConfig) -> list[SafetyFinding]:
    """Errors for walls the daemon could not build; a note naming the tool frame and the walls otherwise."""
    cfg = loaded.config
    spec = cfg.safety.walls
    if not spec.enabled:
        return []
    if cfg.robot.model is None:
        return [
            SafetyFinding(
                "error", ("safety", "walls", "enabled"), "virtual walls need the arm's model (robot.model) for the tool"
            )
        ]
    from hild.dynamics.tool import ToolPoint  # mujoco stays behind this seam

    where = ("safety", "walls", "site" if spec.site is not None else "body" if spec.body is not None else "enabled")
    try:
        tool = ToolPoint(
            loaded.directory / cfg.robot.model,
            list(cfg.joints),
            site=spec.site,
            body=spec.body,
            offset=spec.tool_offset,
        )
    except ValueError as exc:
        return [SafetyFinding("error", where, str(exc))]
    count = (6 if spec.box is not None else 0) + len(spec.planes)
    collision = ", self-collision checked" if spec.self_collision else ""
    loaded.notes.append(
        f"virtual walls: {count} on the tool at {tool.frame} + {list(spec.tool_offset)} m, margin {spec.margin:g} m"
        + collision
    )
    return []
