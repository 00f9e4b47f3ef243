"""The plugins in LeRobot's own tools (LeRobot 0.6.1, its real command lines), against a
real Telerobot server on the simulation: discovered as LeRobot discovers plugins,
`lerobot-record` with the Telerobot robot and teleoperator while a scripted operator
drives through the server, `lerobot-replay` of an episode Telerobot exported, and
LeRobot's own dataset reading both."""

from __future__ import annotations

import json
import math
import shutil
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from conftest import TOKEN, run_lerobot, serving

from telerobot.client import Telerobot

AUTH = {"Authorization": f"Bearer {TOKEN}"}
JOG = [0.05, -0.03, 0.04, 0.03, 0.05, 0.02]  # rad, one step of the replayed episode
SMALL_VIDEO = {
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_VIDEO_WIDTH": "640",  # (the timecode the frames are dated by is 528 px)
    "TELEROBOT_VIDEO_HEIGHT": "360",
    "TELEROBOT_VIDEO_FPS": "15",
}


def test_lerobot_discovers_both_plugins_by_their_distribution_names() -> None:
    from lerobot.robots.config import RobotConfig
    from lerobot.teleoperators.config import TeleoperatorConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    robot = RobotConfig.get_choice_class("telerobot")
    teleop = TeleoperatorConfig.get_choice_class("telerobot")
    assert robot.__module__ == "lerobot_robot_telerobot.config_telerobot"
    assert teleop.__module__ == "lerobot_teleoperator_telerobot.config_telerobot"


def _drive_as_an_operator(
    url: str, done: threading.Event, stop: threading.Event, arm: str | None = None
) -> None:
    """A person at the page: once LeRobot's robot holds control, takes control over it,
    moves the first joint (of ``arm``, on a two-arm server) there and back, and lets go;
    again and again until ``stop``, so every episode holds a move however late LeRobot
    starts writing rows (on a busy machine its first rows came after a single move had
    ended: a flat action column)."""
    deadline = time.monotonic() + 120
    while httpx.get(url + "api/v1/safety").json()["controller"] != "lerobot":
        if time.monotonic() > deadline or stop.is_set():
            return
        time.sleep(0.1)
    while not stop.is_set() and time.monotonic() < deadline:
        time.sleep(0.5)  # a few rows of the robot's own between the moves
        with Telerobot(url, TOKEN, name="scripted operator", take_over=True) as person:
            for step in (0.08, 0.08, -0.08, -0.08):  # (a jog's step is at most 0.1 rad)
                person.move_joints([step, 0, 0, 0, 0, 0], relative=True, arm=arm)
        done.set()


def test_lerobot_record_with_the_telerobot_robot_and_teleoperator(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with serving("--model", "so101", env=SMALL_VIDEO) as (url, _state):
        done, stop = threading.Event(), threading.Event()
        operator = threading.Thread(target=_drive_as_an_operator, args=(url, done, stop))
        operator.start()
        root = tmp_path / "recorded"
        try:
            said = run_lerobot(
                "lerobot-record",
                [
                    "--robot.type=telerobot",
                    "--robot.camera_width=320",
                    "--robot.camera_height=180",
                    "--robot.fps=15",
                    "--teleop.type=telerobot",
                    "--dataset.repo_id=telerobot/record-test",
                    f"--dataset.root={root}",
                    "--dataset.single_task=wave",
                    "--dataset.num_episodes=2",
                    "--dataset.episode_time_s=4",
                    "--dataset.reset_time_s=1",
                    "--dataset.fps=10",
                    "--dataset.push_to_hub=false",
                    "--play_sounds=false",
                ],
                url,
                tmp_path,
            )
        finally:
            stop.set()
            operator.join(60)
        assert done.is_set(), said[-3000:]
    ds = LeRobotDataset("telerobot/record-test", root=root, video_backend="pyav")
    assert ds.num_episodes == 2 and ds.meta.robot_type == "so_follower"
    # Shaped as LeRobot's own SO-101 datasets: the six joints, nothing else, as the state.
    assert ds.meta.features["observation.state"]["names"] == [
        "shoulder_pan.pos",
        "shoulder_lift.pos",
        "elbow_flex.pos",
        "wrist_flex.pos",
        "wrist_roll.pos",
        "gripper.pos",
    ]
    for i in range(len(ds)):
        item = ds[i]
        assert tuple(item["observation.images.left"].shape) == (3, 180, 320)
    pans = np.array([float(ds[i]["action"][0]) for i in range(len(ds))])
    assert pans.max() - pans.min() > 5.0, pans  # the operator's move, in degrees


def _features_as_lerobot_record_builds_them(robot: object) -> dict[str, dict]:
    """The dataset features ``lerobot-record`` builds for ``robot`` (LeRobot 0.6.1's own
    code, its default processors)."""
    from lerobot.datasets import aggregate_pipeline_dataset_features, create_initial_features
    from lerobot.processor import make_default_processors
    from lerobot.utils.feature_utils import combine_feature_dicts

    teleop, _, observation = make_default_processors()
    return combine_feature_dicts(
        aggregate_pipeline_dataset_features(
            pipeline=teleop, initial_features=create_initial_features(action=robot.action_features)
        ),
        aggregate_pipeline_dataset_features(
            pipeline=observation,
            initial_features=create_initial_features(observation=robot.observation_features),
        ),
    )


CAMERAS = ("left", "right")  # the server's stereo pair, as the plugin names it


def test_the_plugins_dataset_features_are_lerobots_so_follower_s() -> None:
    """The features ``lerobot-record`` builds for the plugin on an SO-101 server are those
    it builds for LeRobot's own ``so_follower`` with two cameras named as ours (built, not
    connected): the same state, action and images, names and shapes."""
    from lerobot.cameras.opencv import OpenCVCameraConfig
    from lerobot.robots.so_follower import SOFollower, SOFollowerRobotConfig
    from lerobot_robot_telerobot.config_telerobot import TelerobotConfig
    from lerobot_robot_telerobot.telerobot import Telerobot as TelerobotRobot

    size = {"width": 320, "height": 180, "fps": 15}
    cameras = {eye: OpenCVCameraConfig(index_or_path=i, **size) for i, eye in enumerate(CAMERAS)}
    theirs = SOFollower(SOFollowerRobotConfig(port="/dev/null", cameras=cameras))
    with serving("--model", "so101") as (url, _state):
        ours = TelerobotRobot(
            TelerobotConfig(url=url, token=TOKEN, camera_width=320, camera_height=180)
        )
        assert ours.robot_type == "so_follower"
        assert _features_as_lerobot_record_builds_them(ours) == (
            _features_as_lerobot_record_builds_them(theirs)
        )


def test_on_two_arms_the_plugins_features_are_lerobots_bi_so_follower_s() -> None:
    """On a server with two SO-101s named left and right (listed right first), the
    features ``lerobot-record`` builds for the plugin are those it builds for LeRobot's
    own ``bi_so_follower`` with the stereo pair as its top-level cameras: twelve joints,
    left's first, and the same action."""
    from lerobot.cameras.opencv import OpenCVCameraConfig
    from lerobot.robots.bi_so_follower import BiSOFollower, BiSOFollowerConfig
    from lerobot.robots.so_follower import SOFollowerConfig
    from lerobot_robot_telerobot.config_telerobot import TelerobotConfig
    from lerobot_robot_telerobot.telerobot import Telerobot as TelerobotRobot

    size = {"width": 320, "height": 180, "fps": 15}
    cameras = {eye: OpenCVCameraConfig(index_or_path=i, **size) for i, eye in enumerate(CAMERAS)}
    theirs = BiSOFollower(
        BiSOFollowerConfig(
            left_arm_config=SOFollowerConfig(port="/dev/null"),
            right_arm_config=SOFollowerConfig(port="/dev/null"),
            cameras=cameras,
        )
    )
    two_arms = {"TELEROBOT_ARMS": "right=so101:sim,left=so101:sim"}
    with serving(env=two_arms) as (url, _state):
        ours = TelerobotRobot(
            TelerobotConfig(url=url, token=TOKEN, camera_width=320, camera_height=180)
        )
        assert ours.robot_type == "bi_so_follower"
        assert _features_as_lerobot_record_builds_them(ours) == (
            _features_as_lerobot_record_builds_them(theirs)
        )


SO_LEADER_MOTORS = [
    "shoulder_pan",
    "shoulder_lift",
    "elbow_flex",
    "wrist_flex",
    "wrist_roll",
    "gripper",
]


def _emulated_leader(calibration: Path) -> tuple[object, str]:
    """An SO-101 leader arm for LeRobot's own ``so101_leader``: Telerobot's emulated
    Feetech bus (the servos' bytes, on a real pseudo-terminal) and, in LeRobot's
    calibration folder, the calibration its registers hold (so LeRobot asks nothing)."""
    from telerobot.drivers.motors.feetech.protocol import Register
    from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator

    bus = FeetechBusEmulator()
    link = BusLink.on_pty(bus).start()
    folder = calibration / "teleoperators" / "so_leader"
    folder.mkdir(parents=True)
    table = {
        name: {
            "id": servo_id,
            "drive_mode": 0,
            "homing_offset": bus.servos[servo_id].signed(Register.HOMING_OFFSET),
            "range_min": bus.servos[servo_id].u16(Register.MIN_POSITION_LIMIT),
            "range_max": bus.servos[servo_id].u16(Register.MAX_POSITION_LIMIT),
        }
        for servo_id, name in enumerate(SO_LEADER_MOTORS, start=1)
    }
    (folder / "leader.json").write_text(json.dumps(table))
    return link, link.url


def test_lerobot_teleoperate_with_lerobot_s_own_so101_leader(tmp_path: Path) -> None:
    """`lerobot-teleoperate` with LeRobot's own teleoperator (``so101_leader``, reading an
    emulated leader arm's servos) and the Telerobot robot: the simulated SO-101 follows
    the leader, through the server's limits and lease."""
    link, port = _emulated_leader(tmp_path / "calibration")
    leader = link.bus.servos  # type: ignore[attr-defined]
    pan_steps = 300  # the leader's shoulder_pan turned by hand, 26.4° (4096 steps a turn)

    def turn_by_hand() -> None:
        time.sleep(4.0)  # LeRobot connected and following
        leader[1].position += pan_steps

    with serving("--model", "so101") as (url, _state):
        hand = threading.Thread(target=turn_by_hand)
        hand.start()
        try:
            said = run_lerobot(
                "lerobot-teleoperate",
                [
                    "--robot.type=telerobot",
                    "--robot.use_cameras=false",
                    "--teleop.type=so101_leader",
                    f"--teleop.port={port}",
                    "--teleop.id=leader",
                    "--fps=30",
                    "--teleop_time_s=9",
                ],
                url,
                tmp_path,
                env={"HF_LEROBOT_CALIBRATION": str(tmp_path / "calibration")},
            )
        finally:
            hand.join()
            link.stop()  # type: ignore[attr-defined]
        state = httpx.get(url + "api/v1/robot/state").json()
    # The follower stands where the leader is: LeRobot's degrees from mid-range (its
    # 360/4095 per step against the model's 360/4096: within a few hundredths), the
    # shoulder turned by hand, the others at the leader's zero.
    deg = np.array(state["joints_deg"][:5]) * 4096 / 4095
    expected = np.array([pan_steps * 360 / 4095, 0, 0, 0, 0])
    assert np.abs(deg - expected).max() < 2.0, (deg, said[-1500:])


TWO_ARMS = {"TELEROBOT_ARMS": "right=so101:sim,left=so101:sim"}  # listed right first


def test_on_two_arms_lerobot_record_and_replay_take_lerobots_bimanual_shape(
    tmp_path: Path,
) -> None:
    """On a server with two SO-101s named left and right, `lerobot-record` with the
    Telerobot robot and teleoperator writes LeRobot's ``bi_so_follower`` dataset (twelve
    joints, left's first, for the state and the action) while a person moves the right
    arm; `lerobot-replay` of that episode drives the right arm through the same poses,
    the left one staying. The tokens are given on the command lines (none in the
    environment) and are nowhere in what LeRobot prints (it logs its whole config)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    names = [f"{side}_{motor}.pos" for side in ("left", "right") for motor in SO_LEADER_MOTORS]
    tokens_given = [f"--robot.token={TOKEN}"]
    no_token_around = {
        "TELEROBOT_OPERATOR_TOKEN": "",
        "TELEROBOT_STATE_DIR": str(tmp_path / "no-state"),  # (no stored token either)
    }
    root = tmp_path / "bimanual"
    with serving(env=TWO_ARMS) as (url, _state):
        done, stop = threading.Event(), threading.Event()
        person = threading.Thread(target=_drive_as_an_operator, args=(url, done, stop, "right"))
        person.start()
        try:
            recorded = run_lerobot(
                "lerobot-record",
                [
                    "--robot.type=telerobot",
                    *tokens_given,
                    "--robot.use_cameras=false",
                    "--teleop.type=telerobot",
                    f"--teleop.token={TOKEN}",
                    "--dataset.repo_id=telerobot/bimanual",
                    f"--dataset.root={root}",
                    "--dataset.single_task=wave",
                    "--dataset.num_episodes=1",
                    "--dataset.episode_time_s=6",
                    "--dataset.reset_time_s=1",
                    "--dataset.fps=10",
                    "--dataset.push_to_hub=false",
                    "--play_sounds=false",
                ],
                url,
                tmp_path,
                env=no_token_around,
            )
        finally:
            stop.set()
            person.join(60)
        assert done.is_set(), recorded[-3000:]
        ds = LeRobotDataset("telerobot/bimanual", root=root)
        actions = np.array([ds[i]["action"].numpy() for i in range(len(ds))])
        left_start = httpx.get(url + "api/v1/robot/state", params={"arm": "left"}).json()
        path: list[list[float]] = []
        stop = threading.Event()

        def watch() -> None:
            while not stop.is_set():
                right = httpx.get(url + "api/v1/robot/state", params={"arm": "right"}).json()
                path.append(right["joints_deg"])
                time.sleep(0.05)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            replayed = run_lerobot(
                "lerobot-replay",
                [
                    "--robot.type=telerobot",
                    *tokens_given,
                    "--robot.use_cameras=false",
                    "--dataset.repo_id=telerobot/bimanual",
                    f"--dataset.root={root}",
                    "--dataset.episode=0",
                    "--play_sounds=false",
                ],
                url,
                tmp_path,
                env=no_token_around,
            )
        finally:
            stop.set()
            watcher.join()
        left_end = httpx.get(url + "api/v1/robot/state", params={"arm": "left"}).json()
    assert ds.meta.robot_type == "bi_so_follower"
    assert ds.meta.features["observation.state"]["names"] == names
    assert ds.meta.features["action"]["names"] == names
    right_pan = names.index("right_shoulder_pan.pos")
    assert np.ptp(actions[:, right_pan]) > 5.0, actions[:, right_pan]  # the person's move
    assert np.ptp(actions[:, 0]) < 0.5, actions[:, 0]  # left's
    # The right arm passed near every pose of the episode (LeRobot's degrees: 360/4095
    # a step), the gripper aside; the left one stayed where it was.
    went = np.array(path)[:, :5] * 4096 / 4095
    right = actions[:, len(SO_LEADER_MOTORS) : len(SO_LEADER_MOTORS) + 5]
    assert np.ptp(went[:, 0]) > 5.0, went[:, 0]
    worst = max(_closest_pass(went, a) for a in right)
    assert worst < 3.0, (worst, replayed[-1500:])
    assert np.abs(np.subtract(left_end["joints"], left_start["joints"])).max() < 0.01
    for said in (recorded, replayed):
        assert "SecretStr('**********')" in said  # LeRobot printed its config…
        assert TOKEN not in said  # …with no token in it


def _record_an_episode(url: str) -> Path:
    """An SO-101 episode recorded and exported by the server: an operator's jogs out and
    back, about 0.5 rad/s a joint. (A scripted absolute move runs at the arm's own top
    speed, 3 rad/s for the SO-101; the robot plugin's joint commands, like every jog, are
    held to the server's 1 rad/s: such an episode replays late, docs/lerobot.md.)"""
    with httpx.Client(base_url=url + "api/v1/", headers=AUTH, timeout=120) as http:
        assert http.post("recordings", json={"name": "replay source"}).status_code == 200
        http.post("recordings/active/episodes", json={"task": "out and back"})
        with Telerobot(url, TOKEN, name="recorder") as arm:
            time.sleep(0.3)
            for sign in (1, -1):
                for _ in range(8):
                    arm.move_joints([sign * d for d in JOG], relative=True)
                    time.sleep(0.05)
            time.sleep(0.3)
        http.post("recordings/active/episodes/end", json={"success": True})
        file = http.post("recordings/active/stop").json()["file"]
        r = http.post(f"recordings/{file}/export/lerobot", json={})
        assert r.status_code == 200, r.text
        return Path(r.json()["path"])


def _closest_pass(path: np.ndarray, pose: np.ndarray) -> float:
    """How close (the largest joint's difference, degrees) a path sampled now and then
    came to ``pose``: at its readings, or on the straight line between two of them."""
    p0, step = path[:-1], np.diff(path, axis=0)
    along = ((pose - p0) * step).sum(axis=1) / np.maximum((step * step).sum(axis=1), 1e-12)
    between = p0 + np.clip(along, 0.0, 1.0)[:, None] * step
    at = np.abs(path - pose).max(axis=1).min()
    return float(min(at, np.abs(between - pose).max(axis=1).min()))


def test_lerobot_replay_drives_the_arm_through_a_recorded_episode(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with serving("--model", "so101") as (url, _state):
        root = _record_an_episode(url)
        info = json.loads((root / "meta/info.json").read_text())
        assert info["robot_type"] == "so_follower"
        ds = LeRobotDataset("telerobot/replay-source", root=root)
        actions = np.array([ds[i]["action"].numpy() for i in range(len(ds))])
        with Telerobot(url, TOKEN, name="setup") as arm:  # near the episode's start
            q = arm.state()["joints"]
            arm.move_joints([q[0] + 0.05, *q[1:]])
        path: list[list[float]] = []
        stop = threading.Event()

        def watch() -> None:
            while not stop.is_set():
                path.append(httpx.get(url + "api/v1/robot/state").json()["joints_deg"])
                time.sleep(0.05)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            said = run_lerobot(
                "lerobot-replay",
                [
                    "--robot.type=telerobot",
                    "--robot.use_cameras=false",
                    "--dataset.repo_id=telerobot/replay-source",
                    f"--dataset.root={root}",
                    "--dataset.episode=0",
                    "--play_sounds=false",
                ],
                url,
                tmp_path,
            )
        finally:
            stop.set()
            watcher.join()
    # The arm passed near every pose of the episode (the SO-101's LeRobot degrees are
    # 360/4095 per step: 0.02 % from the model's), the gripper in % of its range aside:
    # between two of the watcher's readings, 50 ms apart, the arm went on moving (on a
    # busy machine a pose it passed between them was 3.0001° from both).
    went = np.array(path)[:, :5] * 4096 / 4095
    worst = max(_closest_pass(went, a[:5]) for a in actions)
    assert worst < 3.0, (worst, said[-1500:])
    assert np.abs(went[-1] - actions[-1][:5]).max() < 3.0
    assert "clipped" not in said


def test_lerobot_reads_a_puma_export_made_with_video(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with serving(env=SMALL_VIDEO) as (url, _state):
        made = _record_puma(url)
        root = shutil.copytree(made["path"], tmp_path / "puma")  # (the server's folder goes)
    # Nothing held, whatever the machine's load (make test-slow-machine runs this with a
    # core busy): each row's state, forces and frame fresh. The video yields to control
    # (the media worker runs niced), so its camera thread wakes late at times: it then
    # renders the exposures it missed, each at its own time, and the pipeline takes
    # every frame while recording (drivers/camera/sim.py CATCH_UP_S, slot.py KEEP).
    # Before that, a row of 13 had a late frame in 2 of 22 runs with a core busy.
    assert made["stale_rows"] == {"state": 0, "force": 0, "frame": 0}, made
    assert made["repeated_frames"] == 0 and made["video_fps"] == pytest.approx(15, rel=1e-3)
    # The episode started with the recording's first frame (the server waits for it):
    # nothing of it cut; a cut would be listed and said, never silent.
    assert made["episodes_cut"] == [], made
    ds = LeRobotDataset("telerobot/puma", root=root, video_backend="pyav")
    info = ds.meta.info
    assert info.robot_type == "puma560" and ds.num_episodes == 1
    assert info.fps == made["fps"] == 15  # the configured rate (TELEROBOT_VIDEO_FPS)
    fps = info.fps
    ages = np.array(ds.hf_dataset["telerobot.age_ms"])  # state, force, frame (ms)
    assert ages[:, 0].max() <= 40.0 + 1e-3  # two of the state's 20 ms periods
    late_frames = int(np.count_nonzero(ages[:, 2] > 1000 / fps + 1e-3))
    assert made["stale_rows"]["frame"] == late_frames  # each flagged row counted
    for i in range(len(ds)):
        item = ds[i]
        assert abs(float(item["timestamp"]) - int(item["frame_index"]) / fps) < 0.5 / fps
        assert tuple(item["observation.images.right"].shape) == (3, 360, 640)
    degrees = np.array([ds[i]["observation.state"].numpy() for i in range(len(ds))])
    assert np.abs(degrees).max() > math.degrees(0.2)  # degrees, not radians


def _record_puma(url: str) -> dict[str, Any]:
    """A PUMA recording with video made through the REST API, exported: the export's
    summary (its ``path``, ``fps``, ``repeated_frames``, ``stale_rows``…)."""
    with httpx.Client(base_url=url + "api/v1/", headers=AUTH, timeout=120) as http:
        assert http.post("recordings", json={"name": "puma"}).status_code == 200
        # The rows start at the recording's first frame: a worker alive but not yet
        # encoding (a busy machine) had the whole move pass before it (no video at all).
        _until_video_is_recorded(http)
        http.post("recordings/active/episodes", json={"task": "reach"})
        with Telerobot(url, TOKEN, name="recorder") as arm:
            q = arm.state()["joints"]
            arm.move_joints([q[0] + 0.3, *q[1:]])
        http.post("recordings/active/episodes/end", json={"success": True})
        file = http.post("recordings/active/stop").json()["file"]
        r = http.post(f"recordings/{file}/export/lerobot", json={})
        assert r.status_code == 200, r.text
        summary: dict[str, Any] = r.json()
        return summary


def _until_video_is_recorded(http: httpx.Client, within: float = 60.0) -> None:
    """Wait until the media worker is encoding for the recording that just started."""
    deadline = time.monotonic() + within
    while not (
        (video := http.get("video").json())["worker_alive"]
        and video["stats"].get("frames_encoded", 0) > 0
    ):
        assert time.monotonic() < deadline, f"no video frame encoded in {within} s: {video}"
        time.sleep(0.2)


def test_a_supervised_rollouts_corrections_are_lerobots_intervention_column(
    tmp_path: Path,
) -> None:
    """A policy (the robot plugin's arm as a policy client) drives through one episode;
    a supervisor takes over twice and hands back. The export loads in LeRobot with one
    episode (the whole attempt) whose ``intervention`` is true on two runs of rows,
    each as long as its correction."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm

    fps = 10
    windows: list[float] = []
    with serving(env={**SMALL_VIDEO, "TELEROBOT_VIDEO_FPS": str(fps)}) as (url, _state):
        http = httpx.Client(base_url=url + "api/v1/", headers=AUTH, timeout=60)
        assert http.post("recordings", json={"name": "rollout"}).status_code == 200
        # The export's rows start at the recording's first video frame: on a busy machine
        # the media worker took over a second to start, and the first correction came
        # before any row (one run of rows where two corrections were made).
        _until_video_is_recorded(http)
        http.post("recordings/active/episodes", json={"task": "reach"})
        secret = http.post("policy-tokens", json={"name": "act-policy"}).json()["token"]
        arm = TelerobotArm(ArmOptions(url, secret, name="act-policy", cameras=False, policy=True))
        arm.connect()
        assert http.get("autonomy").json()["mode"] == "paused"  # until a person says go
        assert http.post("autonomy/resume").json()["mode"] == "autonomous"
        stop = threading.Event()

        def policy() -> None:  # a stand-in policy: joint 1 back and forth, 30 Hz
            start = arm.observation()
            names = [k for k in start if k.endswith(".pos")]
            k = 0
            while not stop.is_set():
                action = {n: float(start[n]) for n in names}
                action[names[0]] += 5.0 * math.sin(k / 30)
                arm.send(action)
                k += 1
                stop.wait(1 / 30)

        driver = threading.Thread(target=policy)
        driver.start()
        try:
            for _ in range(2):
                time.sleep(0.8)
                me = http.post("lease", json={"name": "supervisor"}).json()["client_id"]
                took = time.monotonic()
                assert http.get("autonomy").json()["mode"] == "correcting"
                time.sleep(0.6)
                http.delete("lease", headers={"X-Client-Id": me})  # hands back
                windows.append(time.monotonic() - took)
                assert http.get("autonomy").json()["mode"] == "autonomous"
            time.sleep(0.8)
        finally:
            stop.set()
            driver.join(10)
            arm.disconnect(settle=False)
        http.post("recordings/active/episodes/end", json={"success": True})
        file = http.post("recordings/active/stop").json()["file"]
        r = http.post(f"recordings/{file}/export/lerobot", json={})
        assert r.status_code == 200, r.text
        root = shutil.copytree(r.json()["path"], tmp_path / "rollout")
    ds = LeRobotDataset("telerobot/rollout", root=root)
    assert ds.num_episodes == 1  # the whole attempt, corrections included
    assert ds.meta.features["intervention"]["dtype"] == "bool"
    flags = np.array([bool(ds[i]["intervention"]) for i in range(len(ds))])
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(int), [0]])))
    runs = (edges[1::2] - edges[::2]).tolist()
    assert len(runs) == 2, flags.astype(int).tolist()
    for rows, window in zip(runs, windows, strict=True):
        assert abs(rows - window * fps) <= 2, (runs, windows)


def test_lerobot_rollout_drives_as_a_supervised_policy_and_the_page_can_take_over(
    tmp_path: Path,
) -> None:
    """LeRobot's own ``lerobot-rollout`` (its base strategy) runs a LeRobot policy (a
    small ACT, untrained: the plumbing is under test) on the simulation through the robot
    plugin as a policy. The supervision is the server's: an operator takes over mid-run
    (the policy's actions are then not applied; send_action gives back the server's
    target), hands back, and the rollout runs on to its end."""
    from harness.lerobot_policy import build_untrained, make_robot

    with serving(env={"TELEROBOT_VIDEO": "true", **SMALL_VIDEO}) as (url, _state):
        robot = make_robot(url, TOKEN, 320, 240, name="rollout-setup")
        robot.connect()
        try:
            policy = build_untrained(tmp_path / "act", robot, robot.get_observation())
        finally:
            robot.disconnect()
        http = httpx.Client(base_url=url + "api/v1/", headers=AUTH, timeout=60)
        seen: list[str] = []

        secret = http.post("policy-tokens", json={"name": "act-policy"}).json()["token"]

        def supervise() -> None:
            deadline = time.monotonic() + 120
            while http.get("autonomy").json()["mode"] != "paused":  # it took control
                assert time.monotonic() < deadline
                time.sleep(0.1)
            seen.append(http.post("autonomy/resume").json()["mode"])  # a person says go
            start = http.get("robot/state").json()["target_joints"]
            while http.get("robot/state").json()["target_joints"] == start:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            seen.append("the policy moved the arm")
            me = http.post("lease", json={"name": "supervisor"}).json()["client_id"]
            seen.append(http.get("autonomy").json()["mode"])
            time.sleep(1.0)
            http.delete("lease", headers={"X-Client-Id": me})
            seen.append(http.get("autonomy").json()["mode"])

        supervisor = threading.Thread(target=supervise)
        supervisor.start()
        said = run_lerobot(
            "lerobot-rollout",
            [
                "--robot.type=telerobot",
                "--robot.policy=true",
                f"--robot.policy_token={secret}",
                "--robot.client_name=act-policy",
                "--robot.camera_width=320",
                "--robot.camera_height=240",
                f"--policy.path={policy}",
                "--policy.device=cpu",
                "--strategy.type=base",
                "--duration=25",
                "--fps=15",
                "--play_sounds=false",
                "--return_to_initial_position=false",
            ],
            url,
            tmp_path,
        )
        supervisor.join(60)
        state = http.get("autonomy").json()
    assert seen == ["autonomous", "the policy moved the arm", "correcting", "autonomous"], (
        seen,
        said[-3000:],
    )
    assert state["mode"] == "off" and state["interventions"] == 1, state  # it left, one takeover


SECRET = "a-token-never-shown-0123456789abcdef"


def test_the_tokens_are_read_from_the_command_line_and_never_shown() -> None:
    """The plugins' tokens are SecretStr fields that LeRobot's parser (draccus) reads from
    ``--robot.token=…`` and ``--teleop.token=…``; neither the configs' repr, the dict
    LeRobot logs at start, a config written out, nor the error LeRobot raises quoting
    the config (a server unreachable) shows the token, and that error keeps the reason."""
    from dataclasses import asdict, make_dataclass
    from pprint import pformat

    import draccus
    from lerobot.robots.config import RobotConfig
    from lerobot.robots.utils import make_robot_from_config
    from lerobot.teleoperators.config import TeleoperatorConfig
    from lerobot.teleoperators.utils import make_teleoperator_from_config
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()

    # The robot and the teleoperator, as lerobot-record's config holds them.
    Command = make_dataclass("Command", [("robot", RobotConfig), ("teleop", TeleoperatorConfig)])

    nowhere = "http://127.0.0.1:9/"
    cfg = draccus.parse(
        Command,
        args=[
            "--robot.type=telerobot",
            f"--robot.url={nowhere}",
            f"--robot.token={SECRET}",
            f"--robot.policy_token=tpol_{SECRET}",
            "--teleop.type=telerobot",
            f"--teleop.url={nowhere}",
            f"--teleop.token={SECRET}",
        ],
    )
    assert cfg.robot.token.get_secret_value() == SECRET
    assert cfg.robot.policy_token.get_secret_value() == f"tpol_{SECRET}"
    assert cfg.teleop.token.get_secret_value() == SECRET
    written = json.dumps(draccus.encode(cfg))
    assert SECRET not in repr(cfg) + str(cfg) + pformat(asdict(cfg)) + written
    for make, config in (
        (make_robot_from_config, cfg.robot),
        (make_teleoperator_from_config, cfg.teleop),
    ):
        with pytest.raises(ValueError) as refused:
            make(config)
        said = f"{refused.value!r} {refused.value} {refused.value.__cause__}"
        assert f"cannot ask {nowhere} for its arms" in said and SECRET not in said, said


def test_lerobots_video_decoder_loads_with_no_traceback() -> None:
    """torchcodec, LeRobot's video decoder, finds FFmpeg's shared libraries (`make
    lerobot-deps` installs Debian's): without them every LeRobot command starts with a
    long traceback (docs/lerobot.md)."""
    import subprocess
    import sys

    said = subprocess.run(
        [sys.executable, "-c", "from torchcodec.decoders import VideoDecoder"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert said.returncode == 0 and "Traceback" not in said.stderr, said.stderr[-2000:]
