"""Two arms recorded, exported and repeated through a real server (docs/recording.md,
docs/lerobot.md, docs/tasks.md): a recording made while both simulated SO-101s move has
each arm on channels of its own; its LeRobot export is LeRobot's bimanual SO follower
(``bi_so_follower``, ``left_shoulder_pan.pos`` … ``right_gripper.pos``, the single arm's
units, the cameras as ever), read back with pyarrow and by LeRobot itself; the review's
timeline has both arms; and a task repeats both arms' motions together."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pyarrow.parquet as pq
import pytest

from telerobot.client import Telerobot
from telerobot.client.lerobot.units import JointUnits
from telerobot.drivers.robot.models import load_model
from telerobot.server.recording.reader import read
from tests.support import TOKEN, until
from tests.support.browser import NO_VIDEO
from tests.support.servers import serving

TWO_ARMS = {
    **NO_VIDEO,
    "TELEROBOT_ARMS": "left=so101:sim,right=so101:sim",
    # The cameras as every export has them (a small picture: the test is of the columns).
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_VIDEO_WIDTH": "160",
    "TELEROBOT_VIDEO_HEIGHT": "120",
}
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ARMS = ("left", "right")
SO101 = load_model("so101")
# What each arm's tool does while taught: the left rises, the right goes sideways (mm a step).
STEPS = 30
JOG = {"left": [0.0, 0.0, 0.002], "right": [0.0, 0.002, 0.0]}


@dataclass
class Taught:
    base: str  # the server (still running)
    file: str  # the recording's name on it
    mcap: Path  # a copy of it
    dataset: Path  # a copy of its export
    export: dict[str, Any]  # the export's summary
    start: dict[str, np.ndarray]  # each arm's tool before and after
    end: dict[str, np.ndarray]


def tool(robot: Telerobot, arm: str) -> np.ndarray:
    return np.array(robot.arm(arm).state()["position"])


def still(robot: Telerobot) -> bool:
    return all(robot.arm(arm).state()["status"] == "READY" for arm in ARMS)


@pytest.fixture(scope="module")
def taught(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Taught]:
    """One episode taught with both arms moving at once (an operator's jogs, each arm's
    command a few ms after the other's), recorded, downloaded and exported."""
    here = tmp_path_factory.mktemp("two-arms")
    with (
        serving(TWO_ARMS) as base,
        httpx.Client(base_url=base + "api/v1/", headers=AUTH, timeout=60) as http,
    ):
        until(lambda: http.get("video").json()["worker_alive"], 60, "the media worker", poll=0.1)
        assert http.post("recordings", json={"name": "two arms"}).status_code == 200
        with Telerobot(base, TOKEN, name="teacher") as robot:  # (the lease taken: /safety)
            start = {arm: tool(robot, arm) for arm in ARMS}
            http.post("recordings/active/episodes", json={"task": "both arms"})
            for _ in range(STEPS):
                for arm in ARMS:
                    robot.move_cartesian(JOG[arm], relative=True, wait=False, arm=arm)
                time.sleep(0.03)
            until(lambda: still(robot), 10, "both arms at rest", poll=0.05)
            end = {arm: tool(robot, arm) for arm in ARMS}
            http.post("recordings/active/episodes/end", json={"success": True})
            file = http.post("recordings/active/stop").json()["file"]
        mcap = here / file
        mcap.write_bytes(http.get(f"recordings/{file}/download").content)
        r = http.post(f"recordings/{file}/export/lerobot", json={})
        assert r.status_code == 200, r.text
        export = r.json()
        shutil.copytree(export["path"], here / "dataset")
        yield Taught(base, file, mcap, here / "dataset", export, start, end)


def taught_way(arm: str, moved: np.ndarray) -> None:
    """``moved`` is the way ``arm`` was jogged: most of it (a dead-man halt on a busy
    machine may cut a step short), and little else."""
    way = np.array(JOG[arm]) / np.linalg.norm(JOG[arm])
    along = float(moved @ way)
    assert 0.04 < along < STEPS * np.linalg.norm(JOG[arm]) + 0.003, (arm, moved)
    assert np.linalg.norm(moved - along * way) < 0.005, (arm, moved)


def test_the_arms_moved_as_taught(taught: Taught) -> None:
    for arm in ARMS:
        taught_way(arm, taught.end[arm] - taught.start[arm])


def test_each_arm_is_recorded_on_channels_of_its_own(taught: Taught) -> None:
    messages = list(read(taught.mcap))
    topics = {topic for topic, _, _ in messages}
    for arm in ARMS:
        assert {f"/arms/{arm}/state", f"/arms/{arm}/force"} <= topics
    assert "/arms" in topics
    assert not {"/robot/state", "/force"} & topics  # a one-arm recording's channels
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for topic, _, m in messages:
        by_topic.setdefault(topic, []).append(m)
    # /arms: which arms, their models, where each base stands (the right across, facing).
    (said,) = by_topic["/arms"]
    assert [(a["name"], a["model"], a["dof"]) for a in said["arms"]] == [
        ("left", "so101", 6),
        ("right", "so101", 6),
    ]
    assert said["arms"][0]["joint_names"] == list(SO101.joint_names)
    right_mount = np.array(said["arms"][1]["mount"])
    assert right_mount[0, 3] > 0.3 and right_mount[0, 0] == pytest.approx(-1.0)
    # Each arm's states moved its own way, at the same time as the other's.
    moving: dict[str, tuple[float, float]] = {}
    for arm in ARMS:
        states = by_topic[f"/arms/{arm}/state"]
        assert all(s["arm"] == arm for s in states)
        p = np.array([s["position"] for s in states])
        taught_way(arm, p[-1] - p[0])
        step = np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-4
        t = np.array([s["t"] for s in states])[1:][step]
        moving[arm] = (float(t[0]), float(t[-1]))
        forces = by_topic[f"/arms/{arm}/force"]
        assert len(forces) > 500 and all(len(f["values"]) == 6 for f in forces)
    assert moving["left"][0] < moving["right"][1] and moving["right"][0] < moving["left"][1]
    # Foxglove's transforms: each arm's base in the workcell's, its tool in its base.
    frames = {
        (x["parent_frame_id"], x["child_frame_id"]) for x in by_topic["/tf"][-1]["transforms"]
    }
    for arm in ARMS:
        assert ("base", f"{arm}/base") in frames and (f"{arm}/base", f"{arm}/tool") in frames
    # The commands name the arm they moved.
    moved = [
        c["args"].get("arm")
        for c in by_topic["/commands"]
        if c["accepted"] and c["kind"] == "cartesian_increment"
    ]
    assert set(moved) == set(ARMS) and min(map(moved.count, ARMS)) >= STEPS - 2
    safety = by_topic["/safety"]  # (which arms' force limit holds, on several arms)
    assert safety and all(s["force_limited_arms"] == [] for s in safety)
    # The list says the arm model it was made with (each arm's, not the server's default).
    meta = httpx.get(taught.base + f"api/v1/recordings/{taught.file}/metadata").json()
    assert meta["robot_model"] == "so101"


def test_the_review_timeline_has_both_arms(taught: Taught) -> None:
    tl = httpx.get(taught.base + f"api/v1/recordings/{taught.file}/timeline", timeout=60).json()
    topics = tl["topics"]
    for arm in ARMS:
        states, forces = topics[f"/arms/{arm}/state"], topics[f"/arms/{arm}/force"]
        assert len(states) > 20 and len(forces) > 20
        assert states[-1]["position"] == pytest.approx(taught.end[arm].tolist(), abs=0.002)
        assert all(0 <= s["time"] <= tl["duration"] for s in states)
    assert [a["name"] for a in topics["/arms"][0]["arms"]] == list(ARMS)


def expected_names() -> dict[str, list[str]]:
    joints = [f"{arm}_{j}.pos" for arm in ARMS for j in SO101.joint_names]
    pose = ["x", "y", "z", *(f"r{r}{c}" for r in range(1, 4) for c in range(1, 4))]
    return {
        "observation.state": joints,
        "action": joints,
        "observation.tool_pose": [f"{arm}_{n}" for arm in ARMS for n in pose],
        "observation.force": [
            f"{arm}_{n}" for arm in ARMS for n in ("fx", "fy", "fz", "tx", "ty", "tz")
        ],
    }


def test_the_export_is_lerobots_bimanual_so_follower(taught: Taught) -> None:
    root = taught.dataset
    info = json.loads((root / "meta/info.json").read_text())
    assert info["robot_type"] == "bi_so_follower"
    names = expected_names()
    assert names["observation.state"][0] == "left_shoulder_pan.pos"
    assert names["observation.state"][-1] == "right_gripper.pos"
    features = info["features"]
    for key, want in names.items():
        assert features[key]["names"] == want, key
        assert features[key]["shape"] == [len(want)], key
    assert features["telerobot.age_ms"]["shape"] == [3]
    for cam in ("observation.images.left", "observation.images.right"):  # as ever
        assert features[cam]["dtype"] == "video" and features[cam]["shape"] == [120, 160, 3]
    assert taught.export["episodes"] == 1 and taught.export["tasks"] == ["both arms"]
    data = pq.read_table(root / "data/chunk-000/file-000.parquet")
    assert data.num_rows == info["total_frames"] == taught.export["frames"] > 10
    for key, want in names.items():
        assert data.column(key).type.list_size == len(want), key
    # Each arm's columns are its own, in the single arm's units (degrees as LeRobot reads
    # an SO-101's servos, the gripper 0–100 %): the last row is where each arm came to rest.
    units = JointUnits.of("so101", SO101.joint_names, SO101.qlim)
    state = np.array(data.column("observation.state").to_pylist())
    action = np.array(data.column("action").to_pylist())
    pose = np.array(data.column("observation.tool_pose").to_pylist())
    last = {topic: m for topic, _, m in read(taught.mcap) if topic.endswith("/state")}
    for k, arm in enumerate(ARMS):
        joints = np.array(last[f"/arms/{arm}/state"]["joints"])  # at rest at the end
        cols = slice(6 * k, 6 * k + 6)
        # (0.1°: the export samples at its frame rate, and an arm READY may still creep by
        # hundredths of a degree in the last frame's 33 ms; a quiet run saw 0.016°)
        assert state[-1, cols] == pytest.approx(units.to_lerobot(joints), abs=0.1), arm
        assert action[-1, cols] == pytest.approx(units.to_lerobot(joints), abs=0.2), arm
        assert np.ptp(state[:, cols], axis=0).max() > 1.0, f"{arm}'s joints never moved"
        assert pose[-1, 12 * k : 12 * k + 3] == pytest.approx(taught.end[arm], abs=2e-3)
    assert not np.allclose(state[:, :6], state[:, 6:])  # two arms, not one twice


LEROBOT_READS = """
import json, sys
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.robots.bi_so_follower import BiSOFollower, BiSOFollowerConfig
from lerobot.robots.so_follower import SOFollowerConfig
from lerobot.utils.feature_utils import hw_to_dataset_features

ds = LeRobotDataset(repo_id="telerobot/two-arms", root=sys.argv[1], video_backend="pyav")
# LeRobot's own bimanual SO follower (built, not connected): its name and the features
# lerobot-record would give its dataset.
config = BiSOFollowerConfig(
    left_arm_config=SOFollowerConfig(port="/dev/null"),
    right_arm_config=SOFollowerConfig(port="/dev/null"),
)
robot = BiSOFollower(config)
wanted = {
    **hw_to_dataset_features(robot.observation_features, "observation"),
    **hw_to_dataset_features(robot.action_features, "action"),
}
shapes = set()
for i in range(len(ds)):  # every row, its video frames found within lerobot's tolerance
    item = ds[i]
    shapes.add(tuple((k, tuple(item[k].shape)) for k in sorted(item) if hasattr(item[k], "shape")))
print(json.dumps({
    "robot": robot.name,
    "robot_type": ds.meta.robot_type,
    "wanted": {k: v["names"] for k, v in wanted.items()},
    "names": {k: ds.features[k]["names"] for k in wanted},
    "rows": len(ds),
    "shapes": [dict(s) for s in shapes],
}))
"""


def test_lerobot_reads_it_as_its_bimanual_so_follower(taught: Taught) -> None:
    """LeRobot itself (``LeRobotDataset``, in its own venv: ``TELEROBOT_LEROBOT_PYTHON``)
    reads every row, and its ``bi_so_follower`` names the state and action columns as the
    export does."""
    import importlib.util

    python = os.environ.get("TELEROBOT_LEROBOT_PYTHON") or None  # (make test: its venv)
    if python is None:
        if importlib.util.find_spec("lerobot") is None:
            pytest.skip("lerobot is not installed (set TELEROBOT_LEROBOT_PYTHON)")
        python = sys.executable
    out = subprocess.run(
        [python, "-c", LEROBOT_READS, str(taught.dataset)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    assert out.returncode == 0, out.stderr[-3000:]
    said = json.loads(out.stdout.strip().splitlines()[-1])
    assert said["robot"] == said["robot_type"] == "bi_so_follower"
    assert said["names"] == said["wanted"]
    assert said["wanted"]["observation.state"] == expected_names()["observation.state"]
    assert said["rows"] == taught.export["frames"]
    (shapes,) = said["shapes"]  # every row alike
    assert shapes["observation.state"] == shapes["action"] == [12]
    assert shapes["observation.tool_pose"] == [24] and shapes["observation.force"] == [12]
    assert shapes["observation.images.left"] == shapes["observation.images.right"] == [3, 120, 160]


def test_a_task_repeats_both_arms_motions_together(taught: Taught) -> None:
    """The taught episode repeated as a task (each arm first back to its start: the
    approach), recorded: both arms go from their first pose to their last at the same
    time, each by commands that name it, and the task is done."""
    base = taught.base
    with (
        httpx.Client(base_url=base + "api/v1/", headers=AUTH, timeout=60) as http,
        Telerobot(base, TOKEN, name="supervisor") as robot,
    ):
        assert http.post("recordings", json={"name": "repeat"}).status_code == 200
        task = robot.start_task(taught.file, episode=0, approach=True)
        assert task["state"] == "approaching"
        view = robot.wait_task(task["id"], timeout_s=60)
        file = http.post("recordings/active/stop").json()["file"]
        assert view["state"] == "done", view
        for arm in ARMS:
            assert np.linalg.norm(tool(robot, arm) - taught.end[arm]) < 0.005, arm
        repeat = http.get(f"recordings/{file}/download").content
    path = Path(taught.mcap).with_name("repeat.mcap")
    path.write_bytes(repeat)
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for topic, _, m in read(path):
        by_topic.setdefault(topic, []).append(m)
    running = [m["t"] for m in by_topic["/tasks"] if m["state"] == "running"]
    assert running and all(m["arms"] == list(ARMS) for m in by_topic["/tasks"])
    began = running[0]
    spans = {}
    for arm in ARMS:
        states = [s for s in by_topic[f"/arms/{arm}/state"] if s["t"] >= began]
        p = np.array([s["position"] for s in states])
        # From its path's first pose to its last, the way it was taught.
        assert np.linalg.norm(p[0] - taught.start[arm]) < 0.006, arm
        assert p[-1] == pytest.approx(taught.end[arm], abs=0.005)
        step = np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-4
        t = np.array([s["t"] for s in states])[1:][step]
        spans[arm] = (float(t[0]), float(t[-1]))
    # Together: each arm moved while the other did, over the same stretch of time.
    (l0, l1), (r0, r1) = spans["left"], spans["right"]
    assert abs(l0 - r0) < 0.2 and abs(l1 - r1) < 0.2, spans
    named = {
        c["args"].get("arm")
        for c in by_topic["/commands"]
        if c["source"] == "task" and c["kind"] == "cartesian_increment" and c["accepted"]
    }
    assert named == set(ARMS)
