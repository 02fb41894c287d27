"""The key layout, in one place: the server declares these keys and the client asks for them.

Everything of one robot lives under ``hild/<robot>/``; see docs/protocol.md for the messages on each key.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

PREFIX = "hild"
ALIVE = "alive"
STATUS = "status"
EVENTS = "events"
SERVICES = (
    "status",
    "list_controllers",
    "switch_controllers",
    "list_interfaces",
    "list_hardware",
    "estop",
    "reset",
    "set_zero",
    "home",
    "enable",
    "set_hardware_state",
    "list_controller_types",
    "load_controller",
    "configure_controller",
    "cleanup_controller",
    "unload_controller",
    "reload_controller",
    "list_parameters",
    "get_parameters",
    "set_parameters",
    "tuned_config",
    "teach",
    "record",
    "blackbox",
)
# Second-level chunks the API itself uses; a controller output may not take one of these names.
RESERVED = frozenset(
    {ALIVE, STATUS, EVENTS, "srv", "ctrl", "client", "daemon"}
)  # client: goal senders' liveliness tokens

_CHUNK = re.compile(r"[A-Za-z0-9_\-.]+")  # the whole name (fullmatch: `$` would let a final "\n" by)


def check_chunk(name: str, what: str) -> str:
    """A name used as one key-expression chunk: no ``/``, no wildcards, no ``$``/``?``/``#``."""
    if not isinstance(name, str) or not _CHUNK.fullmatch(name) or name in (".", ".."):
        raise ValueError(f"{what} {name!r} cannot be used in a Zenoh key (allowed: letters, digits, _ - .)")
    return name


@dataclass(frozen=True)
class Keys:
    robot: str

    @property
    def root(self) -> str:
        return f"{PREFIX}/{self.robot}"

    @property
    def alive(self) -> str:
        return f"{self.root}/{ALIVE}"

    @property
    def status(self) -> str:
        return f"{self.root}/{STATUS}"

    @property
    def events(self) -> str:
        return f"{self.root}/{EVENTS}"

    def topic(self, name: str) -> str:
        """A published topic: ``status``, ``events`` or a controller output such as ``joint_states``."""
        return f"{self.root}/{name}"

    def controller_topic(self, controller: str, name: str) -> str:
        """A controller's own published topic (``hild.controller.ShapedOutput``), e.g. a broadcaster's ``wrench``."""
        return f"{self.root}/{controller}/{name}"

    def service(self, name: str) -> str:
        return f"{self.root}/srv/{name}"

    def input(self, controller: str, input_name: str) -> str:
        return f"{self.root}/ctrl/{controller}/{input_name}"


ALIVE_ANY = f"{PREFIX}/*/{ALIVE}"


def robot_of_alive_key(key: str) -> str | None:
    """``hild/<robot>/alive`` → ``<robot>``; None for any other key."""
    parts = key.split("/")
    if len(parts) == 3 and parts[0] == PREFIX and parts[2] == ALIVE:
        return parts[1]
    return None
