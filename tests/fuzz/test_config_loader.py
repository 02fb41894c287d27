"""The config loader under hypothesis: any file ends in a config or a ConfigError naming the place, never another
exception, never a hang (random YAML, mutated real configs, raw bytes, deep nesting, tags, alias bombs)."""

from __future__ import annotations

import contextlib
import copy
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hild.config import ConfigError, load_config
from hild.config.loader import MAX_NODES, LoadedConfig
from tests.conftest import CONFIGS, mock_robot
from tests.fuzz import tally

HANG = 5.0  # s: a load still running after this is a hang
SLOW = 2.0  # s: no single load may take longer
VOCABULARY = (
    "robot", "name", "model", "update_rate", "clock", "source", "real_time_factor", "hardware", "driver", "params",
    "joints", "reduction", "direction", "offset", "limits", "position", "lower", "upper", "soft_margin", "velocity",
    "effort", "acceleration", "jerk", "hold", "kp", "kd", "position_gains", "velocity_gains", "controllers", "type",
    "autostart", "fallback_controllers", "safety", "stale_feedback_cycles", "fault_action", "zenoh", "listen",
    "telemetry", "sinks", "kind", "realtime", "priority", "mock", "mujoco", "mit_can", "forward_command", "a", "b",
    "interface", "command_timeout", "initial_positions", "motors", "id", "flavour", "bus", "<<",
)  # fmt: skip


def fuzz(examples: int) -> settings:
    return settings(
        max_examples=examples,
        database=None,
        derandomize=True,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        print_blob=False,
    )


class Hang(Exception):
    pass


@contextlib.contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Interrupt the (pure-Python) loader if it runs longer than ``seconds`` (main thread only)."""

    def expire(signum: int, frame: object) -> None:
        raise Hang(f"still loading after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def load_or_refuse(path: Path, what: str) -> LoadedConfig | ConfigError:
    """Load ``path``: a config, or a ConfigError whose every issue names this file and a line."""
    tally.count(what)
    start = time.monotonic()
    try:
        with time_limit(HANG):
            outcome: LoadedConfig | ConfigError = load_config(path)
    except ConfigError as exc:
        outcome = exc
    except BaseException:
        tally.CRASHES[what] += 1
        raise
    elapsed = time.monotonic() - start
    assert elapsed < SLOW, f"{elapsed:.2f} s"
    if isinstance(outcome, ConfigError):
        assert outcome.issues
        for issue in outcome.issues:
            assert issue.file == str(path) and issue.line is not None, str(issue)
            assert str(issue).startswith(f"{path}:{issue.line}: "), str(issue)
    return outcome


# ---- strategies ------------------------------------------------------------------------------------------------
keys = st.sampled_from(VOCABULARY) | st.text(max_size=10)
scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=10**30, max_value=10**400)
    | st.floats()  # .nan, .inf
    | st.text(max_size=20)
    | st.sampled_from(["mock", "sim", "wall", "hold", "disable", "position", "0x10", "1e999", "-.inf", "~", "yes"])
)
values = st.recursive(
    scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(keys, c, max_size=5), max_leaves=30
)  # fmt: skip
documents = st.dictionaries(keys, values, max_size=8).map(lambda d: yaml.safe_dump(d, allow_unicode=True))


def paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += paths(v, (*prefix, i))
    return out


def real_configs() -> list[dict[str, Any]]:
    can = yaml.safe_load((CONFIGS / "arm6_can.yaml").read_text())
    can["robot"]["model"] = str(CONFIGS / can["robot"]["model"])
    return [mock_robot(), can]


@st.composite
def mutated(draw: st.DrawFn) -> str:
    """A real config with one to three changes: a value replaced, a key deleted, an unknown key added."""
    config = copy.deepcopy(draw(st.sampled_from(real_configs())))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(paths(config)[1:]))
        parent = config
        for part in path[:-1]:
            parent = parent[part]
        op = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if op == "replace":
            parent[path[-1]] = draw(values)
        elif op == "delete" and isinstance(parent, dict):
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(keys)] = draw(values)
    return yaml.safe_dump(config, sort_keys=False, allow_unicode=True)


def bomb(width: int, depth: int) -> str:
    lines = [f"l0: &l0 [{', '.join(['lol'] * width)}]"]
    lines += [f"l{k}: &l{k} [{', '.join([f'*l{k - 1}'] * width)}]" for k in range(1, depth)]
    return "\n".join(lines) + "\n"


def nesting(n: int, kind: str) -> str:
    return "a: " + ("[" * n + "]" * n if kind == "flow" else "{b: " * n + "1" + "}" * n)


def aliased(d: dict[str, Any]) -> str:
    return "a: &x " + yaml.safe_dump(d, default_flow_style=True).strip() + "\nb: *x\nc: {<<: *x}\n"


ODDITIES = [
    "!!python/object/apply:os.system ['true']\n", "a: !!binary aGk=\n", "a: !!timestamp 2020-01-01\n",
    "a: !custom x\n", "a: !!set {x}\n", "? [a, b]\n: 1\n", "? {a: 1}\n: 2\n", "---\na: 1\n---\nb: 2\n",
    "a: *undefined\n", "a: &x 1\na: 2\n", "\t a: 1\n", "a: 'unterminated\n", "%YAML 1.1\n---\na: 1\n",
    "a: \x07\n", "robot: {name: r}\nupdate_rate: " + "9" * 5000 + "\n", "- just\n- a list\n", "",
]  # fmt: skip
yaml_features = st.one_of(
    st.builds(bomb, st.integers(2, 12), st.integers(2, 12)),
    st.builds(nesting, st.sampled_from([1, 2, 8, 63, 64, 65, 66, 300, 3000]), st.sampled_from(["flow", "map"])),
    st.builds(aliased, st.dictionaries(keys, scalars, max_size=3)),
    st.sampled_from(ODDITIES),
)


# ---- tests -------------------------------------------------------------------------------------------------------
@pytest.fixture
def config_path(tmp_path: Path) -> Path:
    return tmp_path / "robot.yaml"


def test_random_yaml_documents(config_path: Path) -> None:
    @fuzz(200)
    @given(text=documents | st.text(max_size=200))
    def property(text: str) -> None:
        config_path.write_text(text, encoding="utf-8", errors="surrogatepass")
        load_or_refuse(config_path, "config loader: random YAML")

    property()


def test_mutated_real_configs(config_path: Path) -> None:
    @fuzz(120)
    @given(text=mutated())
    def property(text: str) -> None:
        config_path.write_text(text, encoding="utf-8", errors="surrogatepass")
        load_or_refuse(config_path, "config loader: mutated configs")

    property()


def test_yaml_features_and_raw_bytes(config_path: Path) -> None:
    @fuzz(120)
    @given(data=yaml_features.map(lambda t: t.encode("utf-8", "surrogatepass")) | st.binary(max_size=100))
    def property(data: bytes) -> None:
        config_path.write_bytes(data)
        load_or_refuse(config_path, "config loader: YAML features, bytes")

    property()


def test_a_billion_laughs_is_refused_at_once(config_path: Path) -> None:
    config_path.write_text(bomb(10, 10))  # 10^10 values once expanded
    start = time.monotonic()
    outcome = load_or_refuse(config_path, "config loader: billion laughs")
    assert isinstance(outcome, ConfigError)
    assert time.monotonic() - start < 1.0
    [issue] = outcome.issues
    assert f"more than {MAX_NODES} values" in issue.message and "YAML bomb" in issue.message
