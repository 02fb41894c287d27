"""Where ``hild ctl pub`` streams: a controller's input, the JSON field its values go in, and how many it takes.

``list_controllers`` gives each controller's type, state and claimed interfaces but not its inputs, so the streamed
inputs of hild's controller types are named here (docs/protocol.md, "Commands" and "Streamed targets"). Each takes
one value per joint, in the controller's joint order, which is the order of its claims.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hild.interfaces import parse_interface

# controller type → {input name: the field of its JSON object that holds the values}
STREAMED: Mapping[str, Mapping[str, str]] = {
    "forward_command": {"commands": "values"},  # {"values": [...]}: positions, velocities or efforts
    "servo": {"target": "positions"},  # {"positions": [...]}: tracked jerk-limited
    "joint_impedance": {"target": "positions"},  # {"positions": [...]}: spring targets, the configured gains
}


class StreamInputError(ValueError):
    """The controller cannot take these values; the message says why and what would."""


@dataclass(frozen=True)
class StreamInput:
    controller: str
    input: str
    field: str
    joints: tuple[str, ...]

    def payload(self, values: Sequence[float]) -> dict[str, Any]:
        return {self.field: list(values)}


def _known() -> str:
    return ", ".join(f"{kind} ({', '.join(inputs)})" for kind, inputs in STREAMED.items())


def resolve(controllers: Sequence[Mapping[str, Any]], name: str, input_name: str | None, count: int) -> StreamInput:
    """The input of ``name`` that ``count`` values go to, from a ``list_controllers`` reply; refuse anything that
    would be dropped: an unknown or inactive controller, a type without a streamed input, the wrong count."""
    entry = next((c for c in controllers if c.get("name") == name), None)
    if entry is None:
        listed = ", ".join(f"{c.get('name')} ({c.get('type')})" for c in controllers) or "none"
        raise StreamInputError(f"no controller {name!r} (controllers: {listed})")
    kind = str(entry.get("type"))
    inputs = STREAMED.get(kind)
    if not inputs:
        raise StreamInputError(f"controller {name!r} ({kind}) has no streamed input hild ctl pub knows: {_known()}")
    if input_name is None:
        if len(inputs) > 1:
            raise StreamInputError(f"controller {name!r} ({kind}) has inputs {', '.join(inputs)}: choose with --input")
        input_name = next(iter(inputs))
    elif input_name not in inputs:
        raise StreamInputError(
            f"controller {name!r} ({kind}) has no input {input_name!r} (inputs: {', '.join(inputs)})"
        )
    state = entry.get("state")
    if state != "active":
        raise StreamInputError(
            f"controller {name!r} is {state}, not active: it would drop every sample "
            f"(hild ctl switch --activate {name})"
        )
    prefix = f"{entry['chain_to']}/" if entry.get("chain_to") else ""  # a chained one claims references
    joints = tuple(
        dict.fromkeys(parse_interface(claim.removeprefix(prefix))[0] for claim in entry.get("claimed") or ())
    )
    if count != len(joints):
        raise StreamInputError(
            f"controller {name!r} takes {len(joints)} value{'s' * (len(joints) != 1)} on {input_name}, one per joint "
            f"({', '.join(joints)}); given {count}"
        )
    return StreamInput(name, input_name, inputs[input_name], joints)
