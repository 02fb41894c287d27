"""Every Zenoh endpoint of a real daemon, fed with hypothesis-made bad input.

For each endpoint: every query gets exactly one reply, ``ok: false`` with a reason (the service parser's own
reason, exactly, for services); streamed samples are dropped with a warning event; the daemon never dies, its cycle
keeps counting, its overall and per-joint modes do not change, no joint moves by a single bit (the mock mirrors
commands exactly), and its memory does not grow. A valid command at the end of each streamed run proves the
"nothing moved" check would have seen a command that got through.
"""

from __future__ import annotations

import json
import re

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hild.api.fields import (
    RequestError,
    boolean,
    controller_name,
    joint_name,
    mapping,
    names,
    parse_request,
    sender,
    text,
)
from hild.api.keys import SERVICES
from hild.api.queries import clip
from hild.api.record import action, note_text, positive, task_text
from hild.api.teach import joint_names
from tests.fuzz import strategies, tally
from tests.fuzz.checks import refused, unharmed
from tests.fuzz.daemon import FuzzDaemon, wait_for

# Answered ok whenever the fields parse; the others change state or need a field they may lack ("give the name").
READ_ONLY = {"status", "list_controllers", "list_interfaces", "list_hardware", "list_controller_types"}
NAMED = {"name": controller_name}
FIELDS = {
    "switch_controllers": {"activate": names, "deactivate": names, "strict": boolean},
    "set_zero": {"joint": joint_name, "confirm": boolean},
    "home": {"joint": joint_name},
    "enable": {"joints": names},
    "set_hardware_state": {"name": text, "state": text},
    "load_controller": {
        **NAMED,
        "type": text,
        "params": mapping,
        "fallback_controllers": names,
        "chain_to": controller_name,
        "by": sender,
    },
    "configure_controller": NAMED,
    "cleanup_controller": NAMED,
    "unload_controller": NAMED,
    "reload_controller": NAMED,
    "list_parameters": {"controller": controller_name},
    "get_parameters": {"controller": controller_name, "names": names},
    "set_parameters": {"controller": controller_name, "values": mapping, "by": sender},
    "teach": {"on": boolean, "joints": joint_names, "by": sender},
    "record": {"action": action, "task": task_text, "fps": positive, "note": note_text},
    "blackbox": {"seconds": positive},
}
TOO_DEEP = "malformed JSON: nested too deeply"


def fuzz(examples: int) -> settings:
    return settings(
        max_examples=examples,
        database=None,
        derandomize=True,  # the same examples on every run: a failure reproduces
        deadline=None,
        suppress_health_check=list(HealthCheck),
        print_blob=False,
    )


def expected_error(service: str, raw: bytes) -> str | None:
    """What the daemon's request parser says about ``raw``; None when it parses."""
    try:
        parse_request(raw, FIELDS.get(service, {}))
    except RequestError as exc:
        return clip(str(exc))
    return None


# ---- services ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("service", SERVICES)
def test_services(daemon: FuzzDaemon, service: str) -> None:
    endpoint = f"srv/{service}"

    @fuzz(120)
    @given(raw=strategies.service_requests(service))
    def property(raw: bytes) -> None:
        error = expected_error(service, raw)
        if error is None and service not in READ_ONLY:
            assume(False)  # a well-formed request that changes state (an e-stop, a switch): not bad input
        if error is None:
            tally.count(endpoint)
            reply, _ = daemon.query(endpoint, raw)
            assert reply["ok"] is True and reply["error"] is None
        else:
            given = refused(endpoint, daemon, raw)["error"]
            if given == TOO_DEEP and raw.count(b"[") + raw.count(b"{") >= 200:
                return  # how deep a parser gets before giving up depends on its thread's free stack
            if error.startswith("malformed JSON"):
                assert str(given).startswith("malformed JSON")
            else:
                assert given == error

    with unharmed(daemon):
        property()


def test_unknown_keys_get_no_reply(daemon: FuzzDaemon) -> None:
    chunk = st.from_regex(re.compile(r"[A-Za-z0-9_]{1,12}"), fullmatch=True)

    @fuzz(40)
    @given(
        suffix=st.one_of(
            chunk.filter(lambda s: s not in SERVICES).map(lambda s: f"srv/{s}"),
            chunk.filter(lambda s: s != "joint_trajectory").map(lambda s: f"ctrl/{s}/goal"),
        ),
        raw=strategies.raw_payloads,
    )
    def property(suffix: str, raw: bytes) -> None:
        tally.count("srv|ctrl/<unknown>")
        assert list(daemon.session.get(daemon.key(suffix), payload=raw, timeout=5.0)) == []
        assert daemon.alive()

    with unharmed(daemon):
        property()


# ---- goals -------------------------------------------------------------------------------------------------------
def test_goals(daemon: FuzzDaemon) -> None:
    @fuzz(500)
    @given(raw=strategies.bad_goals() | strategies.raw_payloads)
    def property(raw: bytes) -> None:
        refused("ctrl/joint_trajectory/goal", daemon, raw)

    with unharmed(daemon):
        property()


@pytest.mark.parametrize("verb", ["cancel", "result"])
def test_cancel_and_result(daemon: FuzzDaemon, verb: str) -> None:
    @fuzz(150)
    @given(raw=strategies.bad_goal_ids() | strategies.raw_payloads)
    def property(raw: bytes) -> None:
        refused(f"ctrl/joint_trajectory/{verb}", daemon, raw)

    with unharmed(daemon):
        property()


# ---- streamed inputs ----------------------------------------------------------------------------------------------
STREAMS = {
    "ctrl/fwd/commands": (strategies.bad_commands(), lambda: {"values": [0.5, -0.5]}),
    "ctrl/servo/target": (strategies.bad_targets(), lambda: {"positions": [0.6, -0.6]}),
}


@pytest.mark.parametrize("endpoint", list(STREAMS))
def test_streamed_inputs(daemon: FuzzDaemon, endpoint: str) -> None:
    bad, good = STREAMS[endpoint]
    drops_before = len(daemon.drop_events(endpoint))

    @fuzz(300)
    @given(raw=bad | strategies.raw_payloads)
    def property(raw: bytes) -> None:
        tally.count(endpoint)
        daemon.put(endpoint, raw)
        daemon.query("srv/list_hardware", b"")  # pace: the daemon has read the sample before the next one
        if not daemon.alive():
            tally.CRASHES[endpoint] += 1
            raise AssertionError(daemon.log.read_text()[-4000:])

    with unharmed(daemon):
        property()
    assert len(daemon.drop_events(endpoint)) > drops_before

    # The same input, valid, moves the joints: the checks above would have caught a bad sample that got through.
    daemon.motion.arm()

    def moved() -> bool:
        daemon.put(endpoint, json.dumps(good()).encode())
        return daemon.motion.max_deviation > 0.1

    wait_for(moved, what=f"a valid sample on {endpoint} to move the joints")
