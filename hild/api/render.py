"""Plain-text views of daemon replies for ``hild ctl``: pure functions from dicts to strings, easy to test."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any


def table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Left-aligned columns, two spaces apart; ``None`` shows as ``-``."""
    cells = [[("-" if v is None else str(v)) for v in row] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)).rstrip()]
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in cells]
    return "\n".join(lines)


def _us(stats: dict[str, Any], key: str) -> str:
    window = stats.get(key) or {}
    return f"{window.get('p50', 0):g}/{window.get('p99', 0):g}/{window.get('max', 0):g}"


def headline(status: dict[str, Any]) -> str:
    loop = status.get("loop") or {}
    return (
        f"{status.get('robot', '?')}: {str(status.get('mode', '?')).upper()}  t={status.get('stamp', 0):.3f} s  "
        f"{loop.get('update_rate', 0):g} Hz {loop.get('clock', '')} clock  cycles {loop.get('cycles', 0)}  "
        f"overruns {loop.get('overruns', 0)}  cycle µs p50/p99/max {_us(loop, 'duration_us')}  "
        f"period error µs {_us(loop, 'period_error_us')}"
    )


def _limits(joint: dict[str, Any]) -> str | None:
    return ",".join(joint.get("limits") or []) or None


def _mode(joint: dict[str, Any]) -> str:
    """The joint's mode (``teach`` when hand-guided), and the grasp its hold keeps (a gripper's hold effort)."""
    if joint.get("teach"):
        return "teach"
    kept = joint.get("hold_effort") or 0.0
    return f"{joint['mode']} (grasp {kept:.3g})" if kept else str(joint["mode"])


def status_text(status: dict[str, Any]) -> str:
    homing = {h["joint"] for h in status.get("homing", []) if h.get("state") == "running"}  # its drive moves it
    joints = table(
        ["JOINT", "MODE", "OWNER", "LIMITS", "FAULT"],
        [
            [
                j["name"],
                _mode(j) + (" (homing)" if j["name"] in homing else ""),
                j.get("owner"),
                _limits(j),
                j.get("fault"),
            ]
            for j in status.get("joints", [])
        ],
    )
    hardware = table(
        ["HARDWARE", "DRIVER", "STATE", "FAULT"],
        [[h["name"], h["driver"], h["state"], h.get("fault")] for h in status.get("hardware", [])],
    )
    return "\n\n".join([headline(status), joints, controllers_text(status.get("controllers", [])), hardware])


def controllers_text(controllers: Sequence[dict[str, Any]]) -> str:
    return table(
        ["CONTROLLER", "TYPE", "STATE", "CHAIN", "CLAIMED", "ERROR"],
        [
            [
                c["name"],
                c["type"],
                c["state"],
                _chain(c),
                ",".join(c.get("claimed") or []) or None,
                c.get("error") or None,
            ]
            for c in controllers
        ],
    )


def _chain(controller: dict[str, Any]) -> str | None:
    """``→ F`` for a controller chained to F; ``chainable`` (``, chained`` while one is) for one that exports
    references."""
    if controller.get("chain_to"):
        return f"→ {controller['chain_to']}"
    if controller.get("is_chainable"):
        return "chainable, chained" if controller.get("is_chained") else "chainable"
    return None


def parameters_text(parameters: Sequence[dict[str, Any]]) -> str:
    return table(
        ["PARAMETER", "VALUE", "WHILE ACTIVE", "DESCRIPTION"],
        [
            [p["name"], json.dumps(p["value"]), "yes" if p["dynamic"] else "no", p.get("description") or ""]
            for p in parameters
        ],
    )


def types_text(types: Sequence[dict[str, Any]]) -> str:
    return table(["TYPE", "CLASS"], [[t["type"], t["class"]] for t in types])


def interfaces_text(interfaces: Sequence[dict[str, Any]]) -> str:
    return table(
        ["INTERFACE", "CLAIMED BY", "AVAILABLE"],
        [[i["name"], i.get("claimed_by"), "no" if i.get("available") is False else "yes"] for i in interfaces],
    )


def hardware_text(hardware: Sequence[dict[str, Any]]) -> str:
    return table(
        ["HARDWARE", "DRIVER", "STATE", "JOINTS", "COMMAND FIELDS", "FAULT"],
        [
            [
                h["name"],
                h["driver"],
                h["state"],
                ",".join(h.get("joints", [])),
                ",".join(h.get("command_fields", [])),
                h.get("fault"),
            ]
            for h in hardware
        ],
    )


def switch_text(reply: dict[str, Any]) -> str:
    done = f"activated {reply.get('activated') or []}, deactivated {reply.get('deactivated') or []}"
    return done + (f"\n{reply['error']}" if reply.get("error") else "")


def _number(values: Sequence[Any] | None, i: int) -> str | None:
    if values is None or i >= len(values) or values[i] is None:
        return None
    return f"{values[i]:+.4f}"


def watch_text(status: dict[str, Any], joint_states: dict[str, Any] | None, note: str = "") -> str:
    """The ``watch`` table: per joint its mode, owner, state and fault, under the status headline."""
    by_name: dict[str, int] = {}
    if joint_states is not None:
        by_name = {n: i for i, n in enumerate(joint_states.get("name") or [])}
    rows = []
    for joint in status.get("joints", []):
        i = by_name.get(joint["name"], -1)
        state = [
            _number(joint_states.get(f), i) if i >= 0 and joint_states else None
            for f in ("position", "velocity", "effort")
        ]
        rows.append([joint["name"], joint["mode"], joint.get("owner"), *state, joint.get("fault")])
    lines = [headline(status)]
    if note:
        lines.append(note)
    lines += ["", table(["JOINT", "MODE", "OWNER", "POSITION", "VELOCITY", "EFFORT", "FAULT"], rows)]
    return "\n".join(lines)


def result_text(result: dict[str, Any]) -> str:
    """A goal's result in one line: ``succeeded`` or ``aborted (-4): path tolerance violated on …``."""
    status = str(result.get("status", "?"))
    code = result.get("error_code", 0)
    detail = result.get("error_string") or ""
    where = _gripper_words(result)
    if status == "succeeded" and not detail:
        return f"goal {result.get('goal_id', '')}: succeeded{where}"
    return f"goal {result.get('goal_id', '')}: {status} ({code}){': ' + detail if detail else ''}{where}"


def _gripper_words(result: dict[str, Any]) -> str:
    """A gripper's result fields (parallel_gripper), when the result has them."""
    if "stalled" not in result:
        return ""
    position, effort = result.get("position"), result.get("effort")
    at = f"at {position:.4g}" if isinstance(position, int | float) else "at ?"
    pressing = f", effort {effort:.3g}" if isinstance(effort, int | float) else ""
    outcome = (
        "stalled on an object, holding it"
        if result["stalled"]
        else "reached"
        if result.get("reached_goal")
        else "stopped"
    )
    return f" ({outcome} {at}{pressing})"


def _seconds(value: Any) -> str:
    return f"{value:.2f} s" if isinstance(value, int | float) else "? s"


def record_started_text(reply: dict[str, Any]) -> str:
    """``record start``: the episode's id and where it goes; how to end it."""
    task = f"task {reply['task']!r}, " if reply.get("task") else ""
    fps = reply.get("fps")
    rate = f"{fps:g} fps" if isinstance(fps, int | float) else "fps ?"
    return (
        f"recording {reply.get('id')} ({task}{rate}) into {reply.get('directory')}\n"
        "end it with: hild ctl record stop (keep) or hild ctl record discard (delete)"
    )


def record_stopped_text(reply: dict[str, Any]) -> str:
    """``record stop``: the id, how long, how many cycles and drops, then each file on its own line."""
    dropped = reply.get("dropped", 0)
    warning = " (rows lost: the recorder fell behind)" if dropped else ""
    lines = [f"stopped {reply.get('id')}: {_figures(reply)}{warning}"]
    lines += [f"  {path}" for path in reply.get("files") or []]
    return "\n".join(lines)


def record_discarded_text(reply: dict[str, Any]) -> str:
    return f"discarded {reply.get('id')}: its directory is deleted"


def record_status_text(reply: dict[str, Any]) -> str:
    """``record status``: the open episode, or that none is, and the recorder's state and directory."""
    recorder = reply.get("recorder")
    if recorder == "disabled":
        return "recording is disabled on this daemon (recording.enabled: false)"
    why = f": {reply['failure']}" if reply.get("failure") and recorder != "running" else ""
    where = f"recorder {recorder}{why}, dir {reply.get('dir')}"
    head = f"recording {reply.get('id')}: {_figures(reply)}" if reply.get("recording") else "not recording"
    lines = [f"{head} ({where})"]
    last = reply.get("last")
    if isinstance(last, dict) and last.get("id"):
        lines.append(f"last: {last['id']}: {_figures(last)}")
    elif last:
        lines.append(f"last: {last}")
    return "\n".join(lines)


def _figures(episode: dict[str, Any]) -> str:
    return f"{_seconds(episode.get('duration'))}, {episode.get('cycles')} cycles, {episode.get('dropped', 0)} dropped"


def blackbox_text(reply: dict[str, Any]) -> str:
    return f"black box saved: {reply.get('file')} ({reply.get('cycles')} cycles, {_seconds(reply.get('seconds'))})"
