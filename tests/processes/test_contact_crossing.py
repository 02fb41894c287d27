"""tau_ext crosses from the cycle process to the client domain in the joint-state ring, as the state does."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from tests.conftest import CONFIGS
from tests.helpers import HildRun, free_endpoint


def test_tau_ext_reaches_joint_states_from_the_cycle_process(tmp_path: Path) -> None:
    raw = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    raw["robot"]["model"] = str(CONFIGS / "arm6.xml")
    raw["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "arm6.xml")
    raw["safety"]["contact"] = {"enabled": True}
    raw.pop("zenoh", None)
    config = tmp_path / "arm6.yaml"
    config.write_text(yaml.safe_dump(raw))
    with HildRun(config, free_endpoint(), "arm6") as run, run.client() as client:

        def running_sample() -> dict[str, Any] | None:
            sample = client.next_message("joint_states", timeout=2.0)
            return sample if all(x is not None for x in sample["tau_ext"]) else None

        states = run.wait(running_sample, "a joint_states sample with the observer running")
        assert run.stop() == 0
    assert len(states["tau_ext"]) == 6
    assert max(abs(x) for x in states["tau_ext"]) < 1.0  # the twin holds, untouched (plant and model agree)
