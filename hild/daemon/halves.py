"""The API halves of a robot's controllers, for a client domain whose cycle runs in another process.

Each controller is built here from the same config as in the cycle process, with mailboxes that are cells of the
shared region: its ``inputs()`` and action server validate and plan in this process and put the prepared result
into the cells, where the cycle process's instance of the same controller takes it. Nothing here steps a
controller: ``update`` and the lifecycle run only in the cycle process, whose controller manager sets the
``active`` flag both halves read.
"""

from __future__ import annotations

from collections.abc import Callable

from hild import plugins
from hild.config.loader import LoadedConfig
from hild.controller import Controller, ControllerContext, JointLimitArrays
from hild.crossing.mailboxes import Mailboxes


def api_halves(
    loaded: LoadedConfig, mailboxes: Mailboxes, emit: Callable[[str, str, str], None]
) -> dict[str, Controller]:
    """Every configured controller, built for its API half; ``emit(level, source, message)`` takes its events.

    Build them before the cycle process starts: with ``mailboxes`` carving, this is what lays out the region."""
    cfg = loaded.config
    limits = JointLimitArrays.of(cfg)
    joints = tuple(cfg.joints)
    halves: dict[str, Controller] = {}
    for name, spec in cfg.controllers.items():
        cls = plugins.load(plugins.CONTROLLERS, spec.type)
        params = loaded.controller_params[name]
        if not isinstance(params, cls.Params):
            params = cls.Params.model_validate(params)
        context = ControllerContext(
            robot=cfg.robot.name,
            name=name,
            joints=joints,
            limits=limits,
            update_rate=cfg.update_rate,
            emit_event=lambda level, message, source=name: emit(level, source, message),
            notify=lambda: None,  # the API half writes no output: the cycle half does, and rings
            mailboxes=mailboxes.scoped(name),
        )
        halves[name] = cls(context, params)
    return halves
