"""[record]'s "Done when", end to end through ``hild run`` (three processes, the recorder a fourth), on the twin and
on Damiao drives emulated behind the loopback CAN rig: three episodes while a trajectory and a servo stream run, the
client domain killed (-9) during the third; then every reader the issue names opens the files, the LeRobot export
matches the cycle log, episodes 1–2 are complete and episode 3 was recovered by the next client domain with at most
200 ms lost; an e-stop leaves a black box."""

from __future__ import annotations

import json
import math
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from hild.api.client import HildClient
from hild.api.ros2.types import type_hash
from hild.bench.children import free_endpoint
from hild.bench.daemon import CanProcesses, HildRun
from hild.bench.scenarios import JTC_ARM, SERVO_WRIST, arm6_config
from hild.modes import JointMode
from hild.record.lerobot import export_lerobot
from hild.record.mcap_files import read_blackbox, read_episode
from hild.record.model import BLACKBOX_DIR, EpisodeMeta, mcap_name

RATE = 500.0
FPS = 30.0
LOST_LIMIT = 0.2  # s the open episode may lose to a crash


def _motion(client: HildClient, seconds: float, stop: threading.Event | None = None) -> None:
    """A trajectory goal on the arm's first three joints and a 100 Hz servo stream on the wrist, together."""
    state = client.next_message("joint_states", timeout=5.0)
    home = dict(zip(state["name"], state["position"], strict=True))
    arm, wrist = list(home)[:3], list(home)[3:]
    goal = {
        "trajectory": {
            "joint_names": arm,
            "points": [
                {"positions": [home[j] + 0.15 for j in arm], "time_from_start": seconds / 2},
                {"positions": [home[j] for j in arm], "time_from_start": seconds},
            ],
        }
    }
    handle = client.send_goal(JTC_ARM, goal)
    stream = client.servo_stream(SERVO_WRIST)
    began = time.monotonic()
    while (t := time.monotonic() - began) < seconds and not (stop is not None and stop.is_set()):
        stream.send([home[j] + 0.1 * math.sin(math.tau * 0.5 * t) for j in wrist])
        time.sleep(0.01)
    handle.close()


@pytest.fixture(params=["twin", "damiao"])
def arm(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[HildRun]:
    """``hild run`` at 500 Hz with a trajectory controller on the first three joints and a servo on the wrist,
    recording to ``tmp_path/recordings``: on the MuJoCo twin, or on Damiao drives emulated by ``hild emulate`` behind
    the loopback CAN rig (configs/arm6_can_loopback.yaml)."""
    recording = {"dir": str(tmp_path / "recordings"), "fps": FPS}
    if request.param == "twin":
        data = arm6_config("twin", RATE, interference=True)
        data["recording"] = recording
        config = tmp_path / "arm6_twin.yaml"
        config.write_text(json.dumps(data))
        with HildRun(config, free_endpoint(), "arm6", cwd=tmp_path) as run:
            yield run
        return
    rig = CanProcesses(tmp_path)
    try:
        data = yaml.safe_load(rig.config.read_text())
        joints = list(data["joints"])
        data["controllers"][JTC_ARM] = {
            "type": "joint_trajectory",
            "params": {"joints": joints[:3], "command_interfaces": ["position", "velocity"]},
        }
        data["controllers"][SERVO_WRIST] = {"type": "servo", "params": {"joints": joints[3:], "command_timeout": 0.25}}
        data["recording"] = recording
        rig.config.write_text(yaml.safe_dump(data, sort_keys=False))
        rig.start_daemon().close()
        assert rig.run is not None
        yield rig.run
    finally:
        rig.close()


def test_three_episodes_a_killed_client_domain_and_every_reader(arm: HildRun, tmp_path: Path) -> None:
    run = arm
    with run.connected() as client:
        client.switch(activate=[JTC_ARM, SERVO_WRIST])
        finished = []
        for k in range(2):
            client.record_start(task=f"episode {k + 1}")
            _motion(client, 1.5)
            finished.append(client.record_stop())
        third = client.record_start(task="episode 3")
        _motion(client, 1.0)
        doomed = run.client_process()
        killed_wall = time.time()
        os.kill(doomed, signal.SIGKILL)
    run.wait_gone(doomed, "the killed client domain")
    third_dir = Path(third["directory"])
    run.wait(lambda: EpisodeMeta.read(third_dir).state == "recovered", "the next client domain to recover it")
    blackboxes = Path(finished[0]["directory"]).parent / BLACKBOX_DIR
    with run.client() as client:
        assert client.record_status()["recorder"] == "running"
        estop_wall = time.time()
        client.estop()
        box = run.wait(lambda: sorted(blackboxes.glob("*.mcap")), "the e-stop's black box")[0]
        client.reset()
    rows, _, _ = read_blackbox(box)
    assert rows.wall[0] < estop_wall < rows.wall[-1], "the black box holds the cycles around the e-stop"
    assert np.any(rows.mode == JointMode.ESTOP)

    # Episodes 1–2: complete; every reader opens them; counts = cycles; hashes = the face's.
    for reply in finished:
        directory = Path(reply["directory"])
        episode = read_episode(directory)
        assert episode.meta.state == "complete"
        assert len(episode.rows) == reply["cycles"] > 1.4 * RATE
        assert np.all(np.diff(episode.rows.tick) == 1), "every cycle, once"
        assert str(directory / mcap_name(episode.meta.id)) in reply["files"]
        with open(directory / mcap_name(episode.meta.id), "rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert summary.statistics is not None
        counts = summary.statistics.channel_message_counts
        by_topic = {c.topic: counts[c.id] for c in summary.channels.values()}
        assert by_topic["/joint_states"] == by_topic["/hild/command"] == len(episode.rows)
        for channel in topics.values():
            schema = summary.schemas[channel.schema_id]
            assert channel.metadata["topic_type_hash"] == type_hash(schema.name)
        with AnyReader([directory]) as reader:
            js = [c for c in reader.connections if c.topic == "/joint_states"]
            assert sum(1 for _ in reader.messages(connections=js)) == len(episode.rows)
    # Episode 3: recovered, at most 200 ms lost to the kill.
    third_episode = read_episode(third_dir)
    assert third_episode.meta.state == "recovered"
    lost = killed_wall - float(third_episode.rows.wall[-1])
    assert lost <= LOST_LIMIT, f"{lost * 1000:.0f} ms lost"
    assert np.all(np.diff(third_episode.rows.tick) == 1)

    # The LeRobot export: ⌊duration·fps⌋ ± 1 frames per episode, monotonic timestamps, state/action = the cycle log.
    episodes = [read_episode(Path(r["directory"])) for r in finished] + [third_episode]
    out = tmp_path / "dataset"
    export_lerobot(episodes, out, FPS)
    table = pq.read_table(sorted((out / "data").rglob("*.parquet"))[0]).to_pydict()
    for index, episode in enumerate(episodes):
        mine = [i for i, e in enumerate(table["episode_index"]) if e == index]
        rows = episode.rows
        duration = float(rows.t[-1] - rows.t[0])
        assert abs(len(mine) - math.floor(duration * FPS)) <= 1
        stamps = np.array([table["timestamp"][i] for i in mine])
        assert np.all(np.diff(stamps) > 0)
        frames = np.array([table["frame_index"][i] for i in mine])
        at = rows.t[0] + frames / FPS  # each frame holds the last cycle at or before its time
        picked = np.searchsorted(rows.t, at + 1e-9, side="right") - 1
        state = np.array([table["observation.state"][i] for i in mine])
        action = np.array([table["action"][i] for i in mine])
        np.testing.assert_array_equal(state, rows.measured_position[picked].astype(np.float32))
        np.testing.assert_array_equal(action, rows.position[picked].astype(np.float32))
