"""The contact observer's external torque estimate on the ROS 2 face: ``/<broadcaster>/external_joint_torques``, a
JointState whose ``effort`` is ``tau_ext`` (franka_ros2's convention), published only while ``safety.contact`` is on."""

from __future__ import annotations

import contextlib
import threading
from pathlib import Path

import numpy as np
import yaml
import zenoh

from hild.api.ros2 import types, wire
from tests.api.conftest import running
from tests.api.ros2.conftest import peer_of
from tests.conftest import CONFIGS
from tests.helpers import wait_for

JOINT_STATE = "sensor_msgs/msg/JointState"
TOPIC = "/joint_state_broadcaster/external_joint_torques"


def twin_config(tmp_path: Path, contact: bool) -> Path:
    raw = yaml.safe_load((CONFIGS / "arm6_twin.yaml").read_text())
    raw["robot"]["model"] = str(CONFIGS / "arm6.xml")
    raw["hardware"]["twin"]["params"]["model"] = str(CONFIGS / "arm6.xml")
    raw["clock"] = {"source": "sim", "real_time_factor": 0.0}
    raw["ros2"] = {"domain_id": 0, "namespace": "/"}
    raw["safety"]["contact"] = {"enabled": contact}
    raw.pop("zenoh", None)
    path = tmp_path / "arm6.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


peer_session = contextlib.contextmanager(peer_of)


def tokens(peer: zenoh.Session) -> list[str]:
    return [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**") if r.ok is not None]


def test_the_external_torque_estimate_is_published_as_joint_state_effort(tmp_path: Path) -> None:
    from hild.config import load_config
    from hild.cycle.engine import Engine

    engine = Engine(load_config(twin_config(tmp_path, contact=True)))
    samples: list[zenoh.Sample] = []
    lock = threading.Lock()

    def keep(sample: zenoh.Sample) -> None:
        with lock:
            samples.append(sample)

    with running(engine) as daemon, peer_session(daemon) as peer:
        sub = peer.declare_subscriber(wire.data_key(0, TOPIC, JOINT_STATE), keep)
        wait_for(lambda: len(samples) >= 3, what="three external torque samples")
        sub.undeclare()
    with lock:
        msg = types.decode(samples[-1].payload.to_bytes(), JOINT_STATE)
    assert list(msg.name) == list(engine.joints)
    assert len(msg.position) == len(msg.velocity) == 0
    assert len(msg.effort) == 6 and np.isfinite(msg.effort).all()
    assert np.abs(msg.effort).max() < 0.5  # the arm holds, untouched: nothing external


def test_without_the_observer_the_topic_is_not_offered(tmp_path: Path) -> None:
    from hild.config import load_config
    from hild.cycle.engine import Engine

    engine = Engine(load_config(twin_config(tmp_path, contact=False)))
    with running(engine) as daemon, peer_session(daemon) as peer:
        wait_for(lambda: any("%joint_states" in k for k in tokens(peer)), what="the face's joint_states token")
        keys = tokens(peer)
    assert not [k for k in keys if "external_joint_torques" in k]
