"""Export a recording's episodes as a LeRobot dataset (format v3.0), the way lerobot's
own ``LeRobotDataset`` writes one (huggingface/lerobot ``src/lerobot/datasets``:
``utils.py`` for the paths and ``info.json``, ``dataset_writer.py`` and
``dataset_metadata.py`` for the episode rows, ``compute_stats.py`` for the stats,
``configs/video.py`` for the default encoder)::

    meta/info.json                       codebase_version "v3.0", fps, features, paths
    meta/tasks.parquet                   task (the index) → task_index
    meta/stats.json                      per feature: min max mean std count q01 q10 q50 q90 q99
    meta/telerobot_export.json           ours: the recording, the video's rate, repeated rows
    meta/episodes/chunk-000/file-000.parquet   one row per episode (where its rows and
                                         video frames are, its stats)
    data/chunk-000/file-000.parquet      one row per frame, every episode
    videos/observation.images.{left,right}/chunk-000/file-000.mp4

The rows sit on the dataset's grid: episode ``e``'s row ``k`` is at ``start_e + k/fps``
on the recording's clock, and its ``timestamp`` is ``k/fps``, as lerobot requires (it
checks the spacing, and finds a row's video frame at ``from_timestamp + timestamp``).

One rule for the rate: rows never outpace the recorded video unless repeated frames
are allowed. The rate is ``fps`` as asked; else the rate the server was configured for
(the recording's ``/settings`` ``video_fps``: LeRobot cannot merge datasets of
different fps), lowered to the recorded video's real rate when the video ran slower
(a warning says so, and how to keep the configured rate); else the video's rate. The
video's rate is its frames over its span, measured from their capture times (a video
slowed by a busy machine ran at 10 fps though it was asked for 30, and its frames'
typical spacing can still say 30: bursts). An ``fps`` asked for above it (with
``REPEAT_TOLERANCE``) is refused, saying the rate to ask for. The summary says the
video's rate, how many rows repeat the frame before them, and warns when that is more
than a few (a video that stalled in an episode).

At each row time:

- image: the recorded video frame captured nearest to the row time (each half of the
  side-by-side frame is one camera; a frame is repeated or skipped when the camera ran
  slower or faster than the grid);
- ``observation.state`` (joints in LeRobot's units, ``telerobot.client.lerobot.units``:
  degrees, an SO-101's exactly as LeRobot's ``so_follower`` reads them, a gripper
  0–100 % of its range) and ``observation.tool_pose`` (position m, then the
  row-major rotation): the last ``/robot/state`` at or before the row time (held, not
  interpolated);
- ``observation.force`` (N, N·m, sensor frame): the mean of the ``/force`` samples in the
  row's interval ``(t - 1/fps, t]`` (the last sample before it if there is none);
- ``action``: the target joints of the last accepted command at or before the row time
  (``/commands`` with ``accepted`` and a ``target_joints``); before any, the state's
  ``target_joints``; in the state's units.
- ``telerobot.age_ms``: how old the row's state, newest force sample and frame are. A
  row whose state is more than two state periods old, whose force interval had no
  sample, or whose frame is more than a row period away is flagged stale there and
  counted (``stale_rows`` in the summary and ``meta/telerobot_export.json``, with a
  warning): never silently held. (Not ``observation.*``: LeRobot's policies take every
  ``observation.`` feature as an input.)

- ``intervention`` (bool, lerobot-rollout's DAgger column), only in a recording of a
  policy under supervision (``/autonomy``): true on the rows whose time falls while an
  operator had taken over from the policy (CORRECTING); paused is not a correction.
  An episode spans the whole attempt, its corrections included.

Episodes come from ``/episodes`` (``start``/``end``, the task from the last ``label``);
a recording without any is exported as one episode, the whole recording, with the task
``"(whole recording)"`` (the summary says so).

The state and action columns are named after the robot model's joints, with LeRobot's
``.pos`` (joint position) after each: ``joint1.pos`` … for the PUMA, ``shoulder_pan.pos``
… for the SO-101 (the names the API and the page use, one rule for every arm).

A multi-arm recording (its settings name the arms; each arm's ``/arms/<name>/state`` and
``/arms/<name>/force``) exports in LeRobot's bimanual convention: every arm's columns
side by side, each name prefixed with its arm's (``left_shoulder_pan.pos`` …
``right_gripper.pos``, ``left_x``, ``right_fx``), each arm in the single arm's units;
an arm's action is the last accepted command that named it. Two SO-101s named left and
right are LeRobot's ``bi_so_follower`` (``lerobot/robots/bi_so_follower``: left's columns
first); other arms' ``robot_type`` is theirs joined by ``+``. A one-arm recording's
export is as it always was.

The export's memory does not grow with the recording's video: the video is read twice
(its capture times first, then its frames, decoded and encoded one at a time) and the
image stats are counted into a histogram per channel. The encoder's log is kept to
errors (``SVT_LOG``; FFmpeg's own is off in PyAV). ``progress`` is told the fraction done.
"""

from __future__ import annotations

import json
import math
import os
import time
from array import array
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any, cast

import av
import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq
from av.video.reformatter import VideoReformatter

from telerobot.client.lerobot.units import (
    JointUnits,
    column_order,
    dataset_robot_type,
)
from telerobot.drivers.base import DriverUnavailable, TelerobotError
from telerobot.drivers.robot.models import DEFAULT_MODEL, RobotModel, load_model
from telerobot.server.recording.arms import RecordedArm, recorded_arms, recorded_settings
from telerobot.server.recording.reader import decode, read, read_raw

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000  # lerobot DEFAULT_CHUNK_SIZE
DATA_FILES_SIZE_IN_MB = 100  # DEFAULT_DATA_FILE_SIZE_IN_MB
VIDEO_FILES_SIZE_IN_MB = 200  # DEFAULT_VIDEO_FILE_SIZE_IN_MB
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EXPORT_INFO_PATH = "meta/telerobot_export.json"  # ours: the recorded video's rate, repeats
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)  # lerobot DEFAULT_QUANTILES
# lerobot's default encoder (VideoEncoderConfig): SVT-AV1, yuv420p, a keyframe every 2
# frames, crf 30, preset 12. libx264 when this PyAV has no SVT-AV1.
ENCODERS: tuple[tuple[str, dict[str, str], dict[str, Any]], ...] = (
    ("libsvtav1", {"crf": "30", "preset": "12"}, {"video.crf": 30, "video.preset": 12}),
    ("libx264", {"crf": "23", "preset": "veryfast"}, {"video.crf": 23, "video.preset": "veryfast"}),
)
GOP = 2
TIE_S = 1e-6  # times this close are the same time
WHOLE_RECORDING_TASK = "(whole recording)"
CAMERAS = ("left", "right")
MAX_STAT_IMAGES = 100  # images sampled per episode for the image stats (lerobot samples too)
# Rows may outpace the recorded video by this much (about one repeated frame in 20, the
# jitter of a steady camera) before an fps asked for is refused, or the repeats warned of.
REPEAT_TOLERANCE = 0.05
ALLOW_REPEATS = "--allow-repeated-frames; allow_repeated_frames over the API"
# The share of the work before the video (reading the recording) and after it (stats and
# files): the progress reported between is the video's, row by row.
LOAD_SHARE = 0.1
FINISH_SHARE = 0.05
VIDEO_TOPIC = "/video/stereo"
AUTONOMY_TOPIC = "/autonomy"
# A row's state, force or frame older than these is flagged (``telerobot.age_ms``,
# counted in the summary), never silently held: a state more than two of its periods
# old, a force interval with no sample, a frame more than one row period from the row.
STALE_STATE_PERIODS = 2.0
AGE_NAMES = ["state", "force", "frame"]
OLDEST_ARM = "; of several arms, the oldest arm's"

Progress = Callable[[float], None]


def joint_feature_names(model: RobotModel) -> list[str]:
    """The state/action columns' names: each of the model's joints with LeRobot's
    ``.pos`` (its position): joint1.pos … joint6.pos for the PUMA, shoulder_pan.pos …
    gripper.pos for the SO-101 (LeRobot's own names for its motors)."""
    return [f"{name}.pos" for name in model.joint_names]


POSE_NAMES = ["x", "y", "z", *(f"r{r}{c}" for r in range(1, 4) for c in range(1, 4))]
FORCE_NAMES = ["fx", "fy", "fz", "tx", "ty", "tz"]
Array = npt.NDArray[np.float64]


class ExportError(TelerobotError):
    """The recording cannot be exported (said why)."""

    code = "export_failed"
    http_status = 422


@dataclass(frozen=True)
class ExportSummary:
    out_dir: str
    episodes: int
    frames: int
    fps: int
    tasks: list[str]
    whole_recording: bool  # no episodes were recorded: the whole recording is one
    video_codec: str | None  # None: the recording has no video
    recorded_s: float  # how long the recording is
    export_s: float  # how long the export took
    skipped: list[str] = field(default_factory=list)  # episodes left out, and why
    # The recorded video's real rate (its frames over its span); None: no video.
    video_fps: float | None = None
    repeated_frames: int = 0  # rows that show the same recorded frame as the row before
    warnings: list[str] = field(default_factory=list)  # what the dataset should be read with
    # Rows whose state, force or frame was older than its bound (telerobot.age_ms).
    stale_rows: dict[str, int] = field(default_factory=dict)
    # Episodes the video did not cover whole (EpisodeCut, as dicts): shorter or left out.
    episodes_cut: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class _Layout:
    """The columns' names and what their descriptions say: one arm's as LeRobot's
    single-arm robots name them; several arms' side by side, each name prefixed with its
    arm's (``left_shoulder_pan.pos`` … ``right_gripper.pos``, ``left_x``, ``right_fx``),
    LeRobot's bimanual convention."""

    joint_names: list[str]
    pose_names: list[str]
    force_names: list[str]
    units_text: str
    robot_type: str
    state_topic: str = "/robot/state"
    force_topic: str = "/force"
    pose_frame: str = "the base frame"
    force_frame: str = "sensor frame"
    each_named: str = ""  # said of each arm's action

    @classmethod
    def of(cls, rec: _Recording) -> _Layout:
        arms = rec.arms
        if not rec.multi:
            units = arms[0].units
            return cls(
                joint_feature_names(arms[0].model),
                POSE_NAMES,
                FORCE_NAMES,
                units.describe(),
                units.robot_type,
            )
        described = list(dict.fromkeys(a.units.describe() for a in arms))
        return cls(
            [f"{a.name}_{n}" for a in arms for n in joint_feature_names(a.model)],
            [f"{a.name}_{n}" for a in arms for n in POSE_NAMES],
            [f"{a.name}_{n}" for a in arms for n in FORCE_NAMES],
            described[0]
            if len(described) == 1
            else "; ".join(f"{a.name}: {a.units.describe()}" for a in arms),
            dataset_robot_type([(a.name, a.model.name) for a in arms]),
            state_topic="/arms/<arm>/state",
            force_topic="/arms/<arm>/force",
            pose_frame="each arm's own base frame",
            force_frame="each arm's own sensor frame",
            each_named=" that named the arm",
        )


# ---------------------------------------------------------------- reading


def _stamp_s(value: Any) -> float:
    """A foxglove ``Time`` (``{sec, nsec}``) or a number (ns if huge, else s), in s."""
    if isinstance(value, dict):
        return float(value.get("sec", 0)) + float(value.get("nsec", 0)) * 1e-9
    v = float(value)
    return v * 1e-9 if v > 1e12 else v


class _Packed:
    """One arm's series as they are read: packed doubles."""

    def __init__(self) -> None:
        self.state_t, self.joints, self.targets = array("d"), array("d"), array("d")
        self.pose, self.force_t, self.force = array("d"), array("d"), array("d")
        self.command_t, self.command_target = array("d"), array("d")

    def state(self, t: float, m: dict[str, Any]) -> None:
        self.state_t.append(t)
        self.joints.extend(m["joints"])
        self.targets.extend(m.get("target_joints") or m["joints"])
        self.pose.extend([*m["position"], *m["rotation"]])

    def arm(self, name: str, model: RobotModel) -> _Arm:
        n = model.dof

        def packed(values: array[float], width: int) -> Array:
            return np.frombuffer(values, np.float64).reshape(-1, width)

        s_t, (s_joints, s_targets, s_pose) = _in_time_order(
            packed(self.state_t, 1).ravel(),
            packed(self.joints, n),
            packed(self.targets, n),
            packed(self.pose, 12),
        )
        f_t, (f_values,) = _in_time_order(packed(self.force_t, 1).ravel(), packed(self.force, 6))
        c_t, (c_target,) = _in_time_order(
            packed(self.command_t, 1).ravel(), packed(self.command_target, n)
        )
        return _Arm(name, model, s_t, s_joints, s_targets, s_pose, f_t, f_values, c_t, c_target)


@dataclass
class _Arm:
    """One arm's recorded series, each in time order."""

    name: str  # "arm" for a one-arm recording's
    model: RobotModel  # its settings' robot_model
    state_t: Array
    joints: Array
    targets: Array
    pose: Array
    force_t: Array
    force: Array
    command_t: Array
    command_target: Array

    @property
    def units(self) -> JointUnits:
        return JointUnits.of(self.model.name, self.model.joint_names, self.model.qlim)


@dataclass
class _Recording:
    path: Path
    arms: list[_Arm]  # one; or, of a multi-arm recording, in the order its columns take
    episodes: list[tuple[float, float, str]]  # (start, end, task) on the monotonic clock
    video_t: Array  # capture times, monotonic clock (the frames are read again to export)
    skipped: list[str]
    # A multi-arm recording (its settings name the arms): columns per arm, prefixed.
    multi: bool = False
    # What the recording's /settings said (None: a recording from before they were kept).
    configured_fps: float | None = None
    state_rate_hz: float | None = None
    # Supervised autonomy (/autonomy): when each mode began; empty without a policy.
    autonomy: list[tuple[float, str]] = field(default_factory=list)

    @property
    def model(self) -> RobotModel:
        """The arm recorded (the first, of several)."""
        return self.arms[0].model

    @property
    def state_t(self) -> Array:
        """The (first) arm's state times: the recording's span."""
        return self.arms[0].state_t


def _arms_recorded(path: Path, settings: dict[str, Any]) -> list[tuple[RecordedArm, RobotModel]]:
    """The arms the recording's settings name (arms.py), each with its model, in the
    order its columns take: LeRobot's bimanual arms left before right, else as the
    settings list them; one arm (recordings from before robot models: a PUMA) when they
    name none."""
    arms = []
    for arm in recorded_arms(settings):
        try:
            arms.append((arm, load_model(arm.model or DEFAULT_MODEL)))
        except DriverUnavailable as exc:
            raise ExportError(
                f"{path.name} is of a robot this version does not know: {exc}"
            ) from None
    return [arms[i] for i in column_order([(arm.name, model.name) for arm, model in arms])]


def _load(path: Path) -> _Recording:
    """Everything but the video's frames (of the video, its capture times), each series
    kept as packed doubles (a Python list of lists costs five times as much: 1 kHz of
    forces for an hour would take about a gigabyte). A multi-arm recording's arms each
    from their own channels (``/arms/<name>/state``, ``/arms/<name>/force``) and the
    commands that named them."""
    settings = recorded_settings(path)
    arms = _arms_recorded(path, settings)
    multi = arms[0][0].named  # each arm on its own channels
    series = {arm.name: _Packed() for arm, _ in arms}
    state_topics = {arm.state_topic: arm.name for arm, _ in arms}
    force_topics = {arm.force_topic: arm.name for arm, _ in arms}
    topics = [
        *state_topics,
        *force_topics,
        "/commands",
        "/episodes",
        AUTONOMY_TOPIC,
        VIDEO_TOPIC,
    ]
    only = arms[0][0].name
    events: list[dict[str, Any]] = []
    autonomy: list[tuple[float, str]] = []
    video_wall = array("d")
    offsets: list[float] = []  # wall (log time) − monotonic (t), from the JSON channels
    # As written: each topic's messages in the order they were logged (the log times of a
    # file never go back), without merging the chunks by time (a tenth of the export).
    for topic, log_ns, data, encoding in read_raw(path, topics, in_file_order=True):
        if topic == VIDEO_TOPIC:
            # Its capture time only: the frame itself (base64) is not decoded here.
            stamp = json.loads(data)["timestamp"] if encoding == "json" else None
            if stamp is None:
                stamp = decode(topic, data, encoding)["timestamp"]
            video_wall.append(_stamp_s(stamp))
            continue
        m = decode(topic, data, encoding)
        t = float(m["t"])
        if len(offsets) < 1000:
            offsets.append(log_ns * 1e-9 - t)
        if topic in state_topics:
            series[state_topics[topic]].state(t, m)
        elif topic in force_topics:
            arm = series[force_topics[topic]]
            arm.force_t.append(t)
            arm.force.extend(m["values"])
        elif topic == "/commands":
            if m.get("accepted") and m.get("target_joints") is not None:
                # Of several arms, the arm it named (a multi-arm server moves none unnamed).
                named = (m.get("args") or {}).get("arm") if multi else only
                if named in series:
                    series[named].command_t.append(t)
                    series[named].command_target.extend(m["target_joints"])
        elif topic == "/episodes":
            events.append(m)
        elif topic == AUTONOMY_TOPIC:
            autonomy.append((t, str(m.get("mode", "off"))))
    for state_topic, name in state_topics.items():
        if not series[name].state_t:
            raise ExportError(f"{path.name} has no {state_topic} messages: nothing to export")
    # The video's capture times are wall clock; the rest is on the server's monotonic
    # clock. Each JSON message has both (its log time and its t): the smallest offset is
    # the one least delayed by logging.
    offset = min(offsets)
    video_t = np.asarray(video_wall, np.float64) - offset
    order = np.argsort(video_t, kind="stable")  # (capture order is the stream's order)
    if not np.all(order == np.arange(len(order))):
        video_t = np.maximum.accumulate(video_t)
    episodes, skipped = _episodes(events, max(series[arm.name].state_t[-1] for arm, _ in arms))
    return _Recording(
        path=path,
        arms=[series[arm.name].arm(arm.name, model) for arm, model in arms],
        episodes=episodes,
        video_t=video_t,
        skipped=skipped,
        multi=multi,
        configured_fps=_positive(settings.get("video_fps")),
        state_rate_hz=_positive(settings.get("state_rate_hz")),
        autonomy=sorted(autonomy, key=lambda x: x[0]),
    )


def _corrected(autonomy: list[tuple[float, str]], t: Array) -> npt.NDArray[np.bool_]:
    """Whether the autonomy mode at each row time ``t`` was CORRECTING (an operator
    had taken over from the policy): the last change at or before it."""
    times = np.array([a for a, _ in autonomy])
    correcting = np.array([mode == "correcting" for _, mode in autonomy])
    at = np.searchsorted(times, t, side="right") - 1
    return np.where(at >= 0, correcting[np.maximum(at, 0)], False)


def _in_time_order(t: Array, *series: Array) -> tuple[Array, tuple[Array, ...]]:
    """``t`` and its ``series`` sorted by ``t`` (stable) if they are not already: read in
    file order, a topic is in the order it was logged, which a file written before log
    times were kept monotonic may not quite be."""
    if len(t) < 2 or bool(np.all(np.diff(t) >= 0)):
        return t, series
    order = np.argsort(t, kind="stable")
    return t[order], tuple(x[order] for x in series)


def _positive(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def _episodes(
    events: Iterable[dict[str, Any]], last_t: float
) -> tuple[list[tuple[float, float, str]], list[str]]:
    by_number: dict[int, dict[str, Any]] = {}
    for e in events:
        ep = by_number.setdefault(int(e["episode"]), {"task": ""})
        kind = e.get("event")
        if kind == "start":
            ep["start"] = float(e["t"])
            ep["task"] = e.get("task") or ep["task"]
        elif kind == "end":
            ep["end"] = float(e["t"])
            ep["task"] = e.get("task") or ep["task"]
        elif kind == "label":
            ep["task"] = e.get("task") or ep["task"]
    out: list[tuple[float, float, str]] = []
    skipped: list[str] = []
    for n in sorted(by_number):
        ep = by_number[n]
        if "start" not in ep:
            skipped.append(f"episode {n}: no start event")
            continue
        end = ep.get("end", last_t)
        if "end" not in ep:
            skipped.append(f"episode {n}: no end event, exported up to the recording's end")
        out.append((ep["start"], end, ep["task"] or f"episode {n}"))
    out.sort()
    return out, [s for s in skipped if "no start" in s] + [s for s in skipped if "no end" in s]


# ---------------------------------------------------------------- resampling


def _held(t_src: Array, values: Array, t: Array, before: Array | None = None) -> Array:
    """The last of ``values`` at or before each ``t``; ``before`` (row-wise, or the first
    value) where none is. Times a microsecond apart count as equal (the clocks are
    floats of some 10⁹ s: a state logged at a row's time must not fall either side)."""
    i = np.searchsorted(t_src, t + TIE_S, side="right") - 1
    out = values[np.clip(i, 0, max(len(values) - 1, 0))] if len(values) else np.zeros((len(t), 6))
    missing = i < 0
    if missing.any():
        out = out.copy()
        out[missing] = before[missing] if before is not None else values[0]
    return np.asarray(out, np.float64)


def _interval_mean(t_src: Array, values: Array, t: Array, period: float) -> Array:
    """The mean of ``values`` in ``(t - period, t]``; the last one before if none is."""
    if len(values) == 0:
        return np.zeros((len(t), 6))
    csum = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    hi = np.searchsorted(t_src, t + TIE_S, side="right")
    lo = np.searchsorted(t_src, t - period + TIE_S, side="right")
    n = hi - lo
    out = (csum[hi] - csum[lo]) / np.maximum(n, 1)[:, None]
    empty = n == 0
    if empty.any():
        out[empty] = values[np.clip(hi[empty] - 1, 0, len(values) - 1)]
    return np.asarray(out, np.float64)


def _state_period(rec: _Recording) -> float:
    """The state's period: as configured, else as recorded (its median spacing)."""
    if rec.state_rate_hz:
        return 1.0 / rec.state_rate_hz
    if len(rec.state_t) > 1:
        return float(np.median(np.diff(rec.state_t)))
    return 0.02


def _age_of_held(t_src: Array, t: Array) -> Array:
    """How old the value ``_held`` takes for each ``t`` is (s): its distance from the
    row for a row before the first."""
    if len(t_src) == 0:
        return np.full(len(t), -1.0)
    i = np.searchsorted(t_src, t + TIE_S, side="right") - 1
    return np.asarray(np.abs(t - t_src[np.clip(i, 0, len(t_src) - 1)]), np.float64)


def _ages(rec: _Recording, t: Array, source: npt.NDArray[np.int64] | None) -> Array:
    """Per row: the age of its state, of its newest force sample, of its frame (ms); of
    several arms, the oldest arm's state and force (an arm without forces: none)."""
    state = np.max([_age_of_held(a.state_t, t) for a in rec.arms], axis=0)
    force = np.max([_age_of_held(a.force_t, t) for a in rec.arms], axis=0)
    frame = np.abs(t - rec.video_t[source]) if source is not None else np.zeros(len(t))
    ms = np.stack([state, force, frame], axis=1) * 1000.0
    ms[:, 1] = np.where(force < 0, -1.0, ms[:, 1])
    return np.asarray(ms, np.float64)


def _nearest(t_src: Array, t: Array) -> npt.NDArray[np.int64]:
    i = np.clip(np.searchsorted(t_src, t), 1, len(t_src) - 1)
    left_closer = (t - t_src[i - 1]) <= (t_src[i] - t)
    return np.asarray(np.where(left_closer, i - 1, i), np.int64)


def video_rate(video_t: Array) -> float | None:
    """The recorded video's real rate: its frames over its span (None under two frames).
    Not the typical spacing: a video that came in bursts on a busy machine had most
    frames 33 ms apart and ran at 10 fps."""
    if len(video_t) < 2:
        return None
    span = float(video_t[-1] - video_t[0])
    return (len(video_t) - 1) / span if span > 0 else None


def default_fps(rate: float | None) -> int:
    """The rows' rate for a video that ran at ``rate``: the nearest whole number unless
    that outpaces the video by more than the tolerance (then the one below); 30 without
    video."""
    if rate is None:
        return 30
    fps = max(1, round(rate))
    return fps if fps <= rate * (1 + REPEAT_TOLERANCE) else max(1, math.floor(rate))


def _rate_text(rate: float | None) -> str:
    return f"the recorded video ran at {rate:.2f} fps" if rate else "the video is one frame"


def _repeats(source: list[npt.NDArray[np.int64]]) -> int:
    """Rows that show the same recorded frame as the row before them (per episode)."""
    return sum(int(np.count_nonzero(np.diff(s) == 0)) for s in source)


# ---------------------------------------------------------------- stats


def _stats(x: npt.NDArray[Any], axis: int | tuple[int, ...], keepdims: bool) -> dict[str, Any]:
    """lerobot's per-feature stats: min, max, mean, std, count, quantiles (exact here;
    lerobot estimates them from histograms)."""
    x = np.asarray(x, np.float64)
    count = x.shape[0]
    out: dict[str, Any] = {
        "min": np.min(x, axis=axis, keepdims=keepdims),
        "max": np.max(x, axis=axis, keepdims=keepdims),
        "mean": np.mean(x, axis=axis, keepdims=keepdims),
        "std": np.std(x, axis=axis, keepdims=keepdims),
        "count": np.array([count]),
    }
    for q in QUANTILES:
        out[f"q{round(q * 100):02d}"] = np.quantile(x, q, axis=axis, keepdims=keepdims)
    return out


class _ImageHistogram:
    """How many pixels of each channel had each value 0–255, over the sampled images:
    the image stats exactly as ``_stats`` over the stacked images would give them (the
    same quantiles, numpy's linear rule), from 6 kB however many images are counted.
    Holding the sampled images instead took hundreds of MB and most of the export's time."""

    def __init__(self) -> None:
        self.counts = np.zeros((3, 256), np.int64)
        self.images = 0

    def add(self, image: npt.NDArray[np.uint8]) -> None:
        for c in range(3):
            self.counts[c] += np.bincount(image[..., c].ravel(), minlength=256)
        self.images += 1

    @staticmethod
    def sum(histograms: Iterable[_ImageHistogram]) -> _ImageHistogram:
        out = _ImageHistogram()
        for h in histograms:
            out.counts += h.counts
            out.images += h.images
        return out

    def stats(self) -> dict[str, Any]:
        """Per channel, shape (3, 1, 1), in [0, 1], like lerobot's
        ``compute_episode_stats``; ``count`` is the number of images."""
        values = np.arange(256, dtype=np.float64)
        out: dict[str, list[float]] = {k: [] for k in ("min", "max", "mean", "std")}
        quantiles: dict[str, list[float]] = {f"q{round(q * 100):02d}": [] for q in QUANTILES}
        for counts in self.counts:
            n = int(counts.sum())
            present = np.flatnonzero(counts)
            mean = float(counts @ values) / n
            out["min"].append(float(present[0]))
            out["max"].append(float(present[-1]))
            out["mean"].append(mean)
            out["std"].append(math.sqrt(float(counts @ (values - mean) ** 2) / n))
            ends = np.cumsum(counts)  # the sorted pixels' value k is at ranks < ends[k]
            for q, key in zip(QUANTILES, quantiles, strict=True):
                rank = q * (n - 1)
                lo = math.floor(rank)
                below, above = np.searchsorted(ends, [lo, min(lo + 1, n - 1)], side="right")
                quantiles[key].append(below + (above - below) * (rank - lo))
        stats: dict[str, Any] = {
            k: np.asarray(v).reshape(3, 1, 1) / 255.0 for k, v in {**out, **quantiles}.items()
        }
        stats["count"] = np.array([self.images])
        return {k: stats[k] for k in ("min", "max", "mean", "std", "count", *quantiles)}


def _downsample(img: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    h, w = img.shape[:2]
    step = max(1, max(h, w) // 150)
    return img[::step, ::step]


def _tolist(stats: dict[str, Any]) -> dict[str, Any]:
    return {k: np.asarray(v).tolist() for k, v in stats.items()}


# ---------------------------------------------------------------- writing


def _pick_encoder() -> tuple[str, dict[str, str], dict[str, Any]]:
    for name, options, info in ENCODERS:
        try:
            av.codec.Codec(name, "w")
        except Exception:
            continue
        if name == "libsvtav1":
            options = {**options, "svtav1-params": f"lp={_svt_parallelism()}"}
        return name, options, info
    raise ExportError("this PyAV has neither SVT-AV1 nor libx264 to encode the videos")


def _svt_parallelism(cores: int | None = None) -> int:
    """SVT-AV1's level of parallelism for each of the two encoders (one per eye, run side
    by side): half the cores each. Left to itself, each sized its threads to the whole
    machine; on 2 cores the two encoders' threads then cost 25 % more CPU than the work
    (bench.export: 6.5 → 5.2 s of CPU, 11 → 8.7 s a recorded minute)."""
    return max(1, (cores or os.cpu_count() or 2) // len(CAMERAS))


def _no_realtime_threads() -> int:
    """Put every thread of this process that is in a realtime class back in the normal one;
    returns how many. SVT-AV1, when run as root, puts the thread that opens an encoder and
    its own workers in SCHED_FIFO at priority 99: left so, they (and every thread and
    process started from them later: the server's, a browser's) take a core from
    everything else on the machine, timers and force stream included, for as long as
    they run (a spinning one freezes a 2-core machine)."""
    reset = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            if os.sched_getscheduler(int(tid)) in (os.SCHED_FIFO, os.SCHED_RR):
                os.sched_setscheduler(int(tid), os.SCHED_OTHER, os.sched_param(0))
                reset += 1
        except OSError:  # the thread has ended
            continue
    return reset


def _vector_column(values: Array) -> pa.Array:
    width = values.shape[1]
    flat = pa.array(values.astype(np.float32).reshape(-1), pa.float32())
    return pa.FixedSizeListArray.from_arrays(flat, width)


def _feature(shape: list[int], names: list[str] | None, description: str) -> dict[str, Any]:
    return {"dtype": "float32", "shape": shape, "names": names, "description": description}


def _tasks_table(tasks: list[str]) -> pa.Table:
    """``meta/tasks.parquet`` as pandas writes lerobot's DataFrame (the task text is the
    index, ``task_index`` the column): the pandas metadata makes ``pd.read_parquet``
    give the index back."""
    table = pa.table(
        {
            "task_index": pa.array(range(len(tasks)), pa.int64()),
            "task": pa.array(tasks, pa.string()),
        }
    )
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": "task",
                "field_name": "task",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


class _Reporter:
    """Tells ``progress`` the fraction done, each whole percent once (a caller may print
    every call)."""

    def __init__(self, progress: Progress | None) -> None:
        self.progress = progress
        self.said = -1

    def __call__(self, fraction: float) -> None:
        percent = math.floor(min(max(fraction, 0.0), 1.0) * 100)
        if self.progress is not None and percent > self.said:
            self.said = percent
            self.progress(percent / 100)


def export_lerobot(
    recording_path: str | Path,
    out_dir: str | Path,
    fps: int | None = None,
    *,
    allow_repeated_frames: bool = False,
    progress: Progress | None = None,
) -> ExportSummary:
    """Write the recording's episodes into ``out_dir`` (which must not exist or be
    empty) as a LeRobot v3.0 dataset; see the module's docstring for the rules. An
    ``fps`` above the recorded video's rate is refused unless ``allow_repeated_frames``;
    ``progress`` is called with the fraction done (0 … 1), each percent once.

    The steps, each a function below: read the recording; choose the rate; place each
    episode's rows on the dataset's grid; say the features; fill the columns; judge
    each row's ages; write the videos, the data, the stats, the episodes, the tasks and
    the info (LeRobot's files), and ours beside them."""
    t_start = time.perf_counter()
    report = _Reporter(progress)
    report(0.0)
    recording_path = Path(recording_path)
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise ExportError(f"{out} is not empty: export into a new folder")
    if fps is not None and fps <= 0:
        raise ExportError("fps must be positive")
    rec = _load(recording_path)
    report(LOAD_SHARE)
    has_video = len(rec.video_t) > 0
    rate = video_rate(rec.video_t)
    warnings: list[str] = []
    fps = _choose_fps(rec, fps, rate, allow_repeated_frames, warnings)
    whole = not rec.episodes and not rec.skipped
    rows, kept, skipped, cuts = _episode_rows(rec, fps, has_video)
    warnings.extend(cut.text for cut in cuts)
    if not kept:
        raise ExportError(f"{recording_path.name}: no episode has data to export")
    tasks: list[str] = []
    for _, _, task in kept:
        if task not in tasks:
            tasks.append(task)

    out.mkdir(parents=True, exist_ok=True)
    layout = _Layout.of(rec)
    state_period = _state_period(rec)
    features = _features(rec, layout, state_period)
    columns, index_cols = _columns(rec, rows, kept, tasks, fps)
    total = sum(len(t) for t in rows)

    source, repeated, stale = _row_sources(
        rec, rows, columns, state_period, fps, has_video, rate, warnings
    )

    # Videos: decode the side-by-side stream once, write each half's rows in order.
    codec_name: str | None = None
    histograms = {c: [_ImageHistogram() for _ in kept] for c in CAMERAS}
    if has_video:
        codec_name, video_info = _write_videos(out, rec, source, fps, histograms, report)
        features.update(_video_features(video_info, rate, repeated))
    report(1.0 - FINISH_SHARE)
    for key in index_cols:
        dtype = {"timestamp": "float32", "intervention": "bool"}.get(key, "int64")
        features[key] = {"dtype": dtype, "shape": [1], "names": None}

    _write_data(out, columns, index_cols)
    cameras = CAMERAS if has_video else ()
    episode_stats = _write_stats(out, columns, index_cols, histograms, len(kept), cameras)
    _write_episodes(out, rows, kept, fps, cameras, episode_stats)
    pq.write_table(_tasks_table(tasks), out / "meta" / "tasks.parquet")
    _write_info(out, layout, len(kept), total, tasks, fps, has_video, features)
    # Ours, beside lerobot's files (which it reads by name): where the rows came from.
    _write_source_info(out, recording_path, fps, rate, repeated, stale, cuts, layout, warnings)

    recorded = float(rec.state_t[-1] - rec.state_t[0])
    report(1.0)
    return ExportSummary(
        out_dir=str(out),
        episodes=len(kept),
        frames=total,
        fps=fps,
        tasks=tasks,
        whole_recording=whole,
        video_codec=codec_name,
        recorded_s=recorded,
        export_s=time.perf_counter() - t_start,
        skipped=skipped,
        video_fps=rate,
        repeated_frames=repeated,
        warnings=warnings,
        stale_rows=stale,
        episodes_cut=[asdict(cut) for cut in cuts],
    )


def _row_sources(
    rec: _Recording,
    rows: list[Array],
    columns: dict[str, Any],
    state_period: float,
    fps: int,
    has_video: bool,
    rate: float | None,
    warnings: list[str],
) -> tuple[list[npt.NDArray[np.int64]], int, dict[str, int]]:
    """Which recorded frame each row shows, and how old each row's parts are (the
    column ``telerobot.age_ms``): each episode's rows' frames, how many rows repeat the
    frame before them, and the stale rows (``_flag_stale``); either said in
    ``warnings`` when too many."""
    total = sum(len(t) for t in rows)
    source = [
        _nearest(rec.video_t, t) if len(rec.video_t) > 1 else np.zeros(len(t), np.int64)
        for t in rows
    ]
    repeated = _repeats(source) if has_video else 0
    columns["telerobot.age_ms"] = [
        _ages(rec, t, src if has_video else None) for t, src in zip(rows, source, strict=True)
    ]
    stale = _flag_stale(columns["telerobot.age_ms"], state_period, fps, total, warnings)
    if repeated > REPEAT_TOLERANCE * total:
        warnings.append(
            f"{repeated} of {total} rows ({100 * repeated / total:.0f} %) show the same "
            f"recorded frame as the row before: {_rate_text(rate)}, unevenly or slower "
            "than the rows"
        )
    return source, repeated, stale


def _video_features(
    video_info: dict[str, Any], rate: float | None, repeated: int
) -> dict[str, dict[str, Any]]:
    """Each camera's feature: its video, and how its frames were chosen."""
    return {
        f"observation.images.{cam}": {
            "dtype": "video",
            "shape": [video_info["video.height"], video_info["video.width"], 3],
            "names": ["height", "width", "channels"],
            "info": video_info,
            "description": f"the {cam} camera: the recorded frame captured nearest to "
            f"the row time ({_rate_text(rate)}; {repeated} rows repeat the frame "
            "before them)",
        }
        for cam in CAMERAS
    }


def _write_info(
    out: Path,
    layout: _Layout,
    episodes: int,
    total: int,
    tasks: list[str],
    fps: int,
    has_video: bool,
    features: dict[str, Any],
) -> None:
    """LeRobot's ``meta/info.json``: the dataset's shape, its paths and features."""
    info = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": layout.robot_type,
        "total_episodes": episodes,
        "total_frames": total,
        "total_tasks": len(tasks),
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "fps": fps,
        "splits": {"train": f"0:{episodes}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if has_video else None,
        "features": features,
    }
    (out / "meta" / "info.json").write_text(json.dumps(info, indent=4, ensure_ascii=False))


def _write_source_info(
    out: Path,
    recording_path: Path,
    fps: int,
    rate: float | None,
    repeated: int,
    stale: dict[str, int],
    cuts: list[EpisodeCut],
    layout: _Layout,
    warnings: list[str],
) -> None:
    """Ours (``EXPORT_INFO_PATH``): the recording the rows came from, their units, and
    what the export warned of (the episodes the video cut short among it)."""
    source_info = {
        "recording": recording_path.name,
        "fps": fps,
        "video_fps": rate,  # as docs/recording.md, the answer and the command name it
        "repeated_frames": repeated,
        "stale_rows": stale,
        "episodes_cut": [asdict(cut) for cut in cuts],
        "units": {
            "observation.state": layout.units_text,
            "action": layout.units_text,
            "observation.tool_pose": "m, rotation matrix",
            "observation.force": "N, N·m",
        },
        "warnings": warnings,
    }
    (out / EXPORT_INFO_PATH).write_text(json.dumps(source_info, indent=4, ensure_ascii=False))


def _choose_fps(
    rec: _Recording,
    fps: int | None,
    rate: float | None,
    allow_repeated_frames: bool,
    warnings: list[str],
) -> int:
    """The dataset's rate, by one rule: rows never outpace the recorded video unless
    repeated frames are allowed. The rate is ``fps`` as asked; else the rate the server
    was configured for (LeRobot merges only datasets of one fps), lowered to the video's
    real rate when the video ran slower (said in a warning); else the video's rate. An
    ``fps`` asked for above the video's rate is refused, saying the rate to ask for."""
    if fps is None and rec.configured_fps is None:
        return default_fps(rate)
    asked = fps is not None
    fps = fps if fps is not None else max(1, round(rec.configured_fps or 1))
    if rate is None or fps <= rate * (1 + REPEAT_TOLERANCE):
        return fps
    slower = default_fps(rate)
    too_fast = (
        f"the recorded video ran at {rate:.2f} fps: {fps} rows a second"
        f" ({'asked for' if asked else 'configured'}) would show each of its frames on"
        f" about {fps / rate:.1f} rows"
    )
    keep = (
        f"allow repeated frames ({ALLOW_REPEATS}) to keep {fps} fps: each row whose frame"
        " is older than a row period is flagged in telerobot.age_ms"
    )
    if allow_repeated_frames:
        warnings.append(f"{too_fast} (allowed: those rows are flagged)")
        return fps
    if asked:
        raise ExportError(f"{too_fast}; ask for {slower} fps or fewer (--fps {slower}), or {keep}")
    warnings.append(f"{too_fast}: exported at {slower} fps instead; {keep}")
    return slower


@dataclass(frozen=True)
class EpisodeCut:
    """An episode the video did not cover whole: exported shorter, or left out, never
    unsaid (the command's output, the REST answer, ``meta/telerobot_export.json``)."""

    episode: int  # its number among the recording's episodes, from 0
    task: str
    start_s: float  # the episode's span on the recording's clock
    end_s: float
    lost_start_s: float  # seconds of it before the video's first frame
    lost_end_s: float  # after its last
    left_out: bool  # under two frames of it had video: not exported

    @property
    def text(self) -> str:
        lost = self.lost_start_s + self.lost_end_s
        what = "left out" if self.left_out else f"{lost:.2f} s shorter"
        return (
            f"episode {self.episode} '{self.task}' ({self.start_s:.3f}–{self.end_s:.3f} s):"
            f" {what}: the recorded video covers it from {self.lost_start_s:.2f} s after its"
            f" start to {self.lost_end_s:.2f} s before its end"
        )


def _episode_rows(
    rec: _Recording, fps: int, has_video: bool
) -> tuple[list[Array], list[tuple[float, float, str]], list[str], list[EpisodeCut]]:
    """Each episode's row times on the dataset's grid, kept where there is video; the
    episodes kept (first row, end, task); those skipped, said why; and those the video
    did not cover whole (more than a row period lost at either end)."""
    episodes = rec.episodes or [(rec.state_t[0], rec.state_t[-1], WHOLE_RECORDING_TASK)]
    skipped = list(rec.skipped)
    rows: list[Array] = []
    kept: list[tuple[float, float, str]] = []
    cuts: list[EpisodeCut] = []
    for number, (start, end, task) in enumerate(episodes):
        lo, hi = start, end
        if has_video:
            half = 0.5 / fps
            lo, hi = max(lo, rec.video_t[0] - half), min(hi, rec.video_t[-1] + half)
        n = math.floor((hi - lo) * fps + 1e-9) + 1 if hi >= lo else 0
        lost = (max(0.0, min(lo, end) - start), max(0.0, end - max(hi, start)))
        if n < 2 or max(lost) > 1.0 / fps:
            cuts.append(EpisodeCut(number, task, start, end, *lost, left_out=n < 2))
        if n < 2:
            skipped.append(f"'{task}' ({start:.3f}–{end:.3f} s): under two frames of data")
            continue
        # Rows start on the episode's first grid point inside the video.
        first = start + math.ceil((lo - start) * fps - 1e-9) / fps
        n = math.floor((hi - first) * fps + 1e-9) + 1
        rows.append(first + np.arange(n) / fps)
        kept.append((first, end, task))
    return rows, kept, skipped, cuts


def _features(rec: _Recording, layout: _Layout, state_period: float) -> dict[str, dict[str, Any]]:
    """The dataset's numeric features, each described as it is filled."""
    return {
        "observation.state": _feature(
            [len(layout.joint_names)],
            layout.joint_names,
            f"joints ({layout.units_text}, LeRobot's units): the last {layout.state_topic} "
            "at or before the row time",
        ),
        "observation.tool_pose": _feature(
            [len(layout.pose_names)],
            layout.pose_names,
            f"tool position (m) and row-major rotation in {layout.pose_frame}: the last "
            f"{layout.state_topic} at or before the row time",
        ),
        "observation.force": _feature(
            [len(layout.force_names)],
            layout.force_names,
            f"force (N) and torque (N·m), {layout.force_frame}: the mean of the "
            f"{layout.force_topic} samples in (t - 1/fps, t], else the last before",
        ),
        "action": _feature(
            [len(layout.joint_names)],
            layout.joint_names,
            f"commanded target joints ({layout.units_text}): the last accepted /commands "
            f"target{layout.each_named} at or before the row time (before any: the state's "
            "target)",
        ),
        "telerobot.age_ms": _feature(
            [3],
            AGE_NAMES,
            "how old the row's state, force and frame are (ms; force −1: none recorded"
            f"{OLDEST_ARM if rec.multi else ''}); "
            f"flagged stale above {1000 * STALE_STATE_PERIODS * state_period:.0f} ms "
            "(state) and one row period (force, frame)",
        ),
    }


def _columns(
    rec: _Recording,
    rows: list[Array],
    kept: list[tuple[float, float, str]],
    tasks: list[str],
    fps: int,
) -> tuple[dict[str, list[Any]], dict[str, list[npt.NDArray[Any]]]]:
    """Each episode's values of every feature (the arms side by side, in the columns'
    order) and of LeRobot's index columns; the ages are filled by the caller."""
    columns: dict[str, list[Any]] = {
        k: [] for k in ("observation.state", "observation.tool_pose", "observation.force")
    }
    columns["action"] = []
    columns["telerobot.age_ms"] = []
    index_cols: dict[str, list[npt.NDArray[Any]]] = {
        "timestamp": [],
        "frame_index": [],
        "episode_index": [],
        "index": [],
        "task_index": [],
    }
    # lerobot-rollout's DAgger column: true on the rows an operator drove, taking over
    # from the policy (CORRECTING). Only for recordings of a policy under supervision.
    supervised = any(mode != "off" for _, mode in rec.autonomy)
    if supervised:
        index_cols["intervention"] = []
    total = 0
    for e, (t, (_, _, task)) in enumerate(zip(rows, kept, strict=True)):
        n = len(t)
        if supervised:
            index_cols["intervention"].append(_corrected(rec.autonomy, t))
        state, pose, force, action = [], [], [], []
        for arm in rec.arms:
            units = arm.units
            state.append(units.to_lerobot(_held(arm.state_t, arm.joints, t)))
            pose.append(_held(arm.state_t, arm.pose, t))
            force.append(_interval_mean(arm.force_t, arm.force, t, 1.0 / fps))
            fallback = _held(arm.state_t, arm.targets, t)
            target = _held(arm.command_t, arm.command_target, t, before=fallback)
            action.append(units.to_lerobot(target))
        columns["observation.state"].append(np.hstack(state))
        columns["observation.tool_pose"].append(np.hstack(pose))
        columns["observation.force"].append(np.hstack(force))
        columns["action"].append(np.hstack(action))
        index_cols["timestamp"].append((np.arange(n) / fps).astype(np.float32))
        index_cols["frame_index"].append(np.arange(n, dtype=np.int64))
        index_cols["episode_index"].append(np.full(n, e, np.int64))
        index_cols["index"].append(np.arange(total, total + n, dtype=np.int64))
        index_cols["task_index"].append(np.full(n, tasks.index(task), np.int64))
        total += n
    return columns, index_cols


def _flag_stale(
    ages_by_episode: list[Array], state_period: float, fps: int, total: int, warnings: list[str]
) -> dict[str, int]:
    """How many rows have a state, force or frame older than its bound (said in
    ``warnings``); the rows themselves carry their ages (telerobot.age_ms)."""
    ages = np.concatenate(ages_by_episode)
    bounds = np.array([STALE_STATE_PERIODS * state_period, 1.0 / fps, 1.0 / fps]) * 1000 + 1e-3
    stale: dict[str, int] = {}
    for i, name in enumerate(AGE_NAMES):
        stale[name] = int(np.count_nonzero(ages[:, i] > bounds[i]))
        if stale[name]:
            warnings.append(
                f"{stale[name]} of {total} rows have a {name} older than {bounds[i]:.0f} ms "
                "(flagged in telerobot.age_ms)"
            )
    return stale


def _write_data(
    out: Path, columns: dict[str, list[Any]], index_cols: dict[str, list[npt.NDArray[Any]]]
) -> None:
    """data/chunk-000/file-000.parquet: every row."""
    table = pa.table(
        {
            **{k: _vector_column(np.concatenate(v)) for k, v in columns.items()},
            **{k: pa.array(np.concatenate(v)) for k, v in index_cols.items()},
        }
    )
    data_path = out / DATA_PATH.format(chunk_index=0, file_index=0)
    data_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, data_path, compression="snappy")


def _write_stats(
    out: Path,
    columns: dict[str, list[Any]],
    index_cols: dict[str, list[npt.NDArray[Any]]],
    histograms: dict[str, list[_ImageHistogram]],
    episodes: int,
    cameras: tuple[str, ...],
) -> list[dict[str, dict[str, Any]]]:
    """meta/stats.json (over the dataset); returns each episode's stats (for the
    episodes' table)."""
    episode_stats: list[dict[str, dict[str, Any]]] = []
    for e in range(episodes):
        s: dict[str, dict[str, Any]] = {}
        for k in columns:
            s[k] = _stats(columns[k][e], axis=0, keepdims=False)
        for k in index_cols:
            s[k] = _stats(index_cols[k][e], axis=0, keepdims=True)
        for cam in cameras:
            s[f"observation.images.{cam}"] = histograms[cam][e].stats()
        episode_stats.append(s)
    dataset_stats: dict[str, dict[str, Any]] = {}
    for k in columns:
        dataset_stats[k] = _stats(np.concatenate(columns[k]), axis=0, keepdims=False)
    for k in index_cols:
        dataset_stats[k] = _stats(np.concatenate(index_cols[k]), axis=0, keepdims=True)
    for cam in cameras:
        dataset_stats[f"observation.images.{cam}"] = _ImageHistogram.sum(histograms[cam]).stats()
    (out / "meta").mkdir(exist_ok=True)
    (out / "meta" / "stats.json").write_text(
        json.dumps({k: _tolist(v) for k, v in dataset_stats.items()}, indent=4)
    )
    return episode_stats


def _write_episodes(
    out: Path,
    rows: list[Array],
    kept: list[tuple[float, float, str]],
    fps: int,
    cameras: tuple[str, ...],
    episode_stats: list[dict[str, dict[str, Any]]],
) -> None:
    """meta/episodes/chunk-000/file-000.parquet: each episode's rows, videos and stats."""
    lengths = [len(t) for t in rows]
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(int)
    ep_cols: dict[str, Any] = {
        "episode_index": pa.array(range(len(kept)), pa.int64()),
        "tasks": pa.array([[task] for _, _, task in kept], pa.list_(pa.string())),
        "length": pa.array(lengths, pa.int64()),
        "data/chunk_index": pa.array([0] * len(kept), pa.int64()),
        "data/file_index": pa.array([0] * len(kept), pa.int64()),
        "dataset_from_index": pa.array(starts[:-1].tolist(), pa.int64()),
        "dataset_to_index": pa.array(starts[1:].tolist(), pa.int64()),
    }
    for cam in cameras:
        key = f"observation.images.{cam}"
        ep_cols[f"videos/{key}/chunk_index"] = pa.array([0] * len(kept), pa.int64())
        ep_cols[f"videos/{key}/file_index"] = pa.array([0] * len(kept), pa.int64())
        ep_cols[f"videos/{key}/from_timestamp"] = pa.array(
            (starts[:-1] / fps).tolist(), pa.float64()
        )
        ep_cols[f"videos/{key}/to_timestamp"] = pa.array((starts[1:] / fps).tolist(), pa.float64())
    for k in episode_stats[0]:
        for stat in episode_stats[0][k]:
            ep_cols[f"stats/{k}/{stat}"] = pa.array(
                [np.asarray(s[k][stat], np.float64).tolist() for s in episode_stats]
            )
    ep_cols["meta/episodes/chunk_index"] = pa.array([0] * len(kept), pa.int64())
    ep_cols["meta/episodes/file_index"] = pa.array([0] * len(kept), pa.int64())
    episodes_path = out / EPISODES_PATH.format(chunk_index=0, file_index=0)
    episodes_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.table(ep_cols), episodes_path, compression="snappy")


def _eyes(frame: av.VideoFrame) -> tuple[av.VideoFrame, av.VideoFrame]:
    """The side-by-side frame's two halves as frames to encode: split in the decoder's own
    YUV 4:2:0 where the halves' sizes allow, each plane's half copied straight into the
    new frame's plane (no conversion to RGB and back, no intermediate arrays: the
    export's largest cost after the encoder), else through RGB."""
    w, h = frame.width // 2, frame.height
    if frame.format.name == "yuv420p" and w % 2 == 0 and h % 2 == 0:
        halves = (av.VideoFrame(w, h, "yuv420p"), av.VideoFrame(w, h, "yuv420p"))
        for index, (src, (pw, ph)) in enumerate(
            zip(frame.planes, ((w, h), (w // 2, h // 2), (w // 2, h // 2)), strict=True)
        ):
            whole = np.frombuffer(memoryview(src), np.uint8).reshape(ph, src.line_size)
            for side, eye in enumerate(halves):
                dst = eye.planes[index]
                plane = np.frombuffer(memoryview(dst), np.uint8).reshape(ph, dst.line_size)
                plane[:, :pw] = whole[:, side * pw : (side + 1) * pw]
        return halves
    rgb = cast(npt.NDArray[np.uint8], frame.to_ndarray(format="rgb24"))
    return (
        av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb[:, :w]), format="rgb24"),
        av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb[:, w : 2 * w]), format="rgb24"),
    )


def _write_videos(
    out: Path,
    rec: _Recording,
    source: list[npt.NDArray[np.int64]],
    fps: int,
    histograms: dict[str, list[_ImageHistogram]],
    report: _Reporter,
) -> tuple[str, dict[str, Any]]:
    """One mp4 per camera holding every episode's frames back to back (frame ``i`` of the
    file is dataset row ``i``, at ``i/fps``; ``source``: each episode's rows' recorded
    frames); counts a sample of them into ``histograms`` for the image stats. The
    recording's frames are read from its file as they are needed, one in memory at a
    time."""
    wanted = np.concatenate(source)  # the source frame of each row, in row order
    episode_of_row = np.concatenate([np.full(len(s), e) for e, s in enumerate(source)])
    sample_every = [max(1, len(s) // MAX_STAT_IMAGES) for s in source]
    row_in_episode = np.concatenate([np.arange(len(s)) for s in source])
    name, options, info_extra = _pick_encoder()
    # SVT-AV1 logs its banner and settings (some 20 lines an encoder) unless told not to;
    # it reads this once, when it first logs. A caller's own SVT_LOG is kept.
    os.environ.setdefault("SVT_LOG", "1")
    decoder = av.CodecContext.create("h264", "r")
    containers: dict[str, Any] = {}
    streams: dict[str, Any] = {}
    row = 0
    width = height = 0

    to_rgb = VideoReformatter()  # one conversion context for every sampled image

    def rows_for(index: int, frame: av.VideoFrame) -> None:
        nonlocal row, width, height
        eyes = _eyes(frame)
        while row < len(wanted) and wanted[row] == index:
            if not containers:
                height, width = frame.height, frame.width // 2
                _open_videos(out, containers, streams, name, options, fps, width, height)
            for side, cam in enumerate(CAMERAS):
                eye = eyes[side]  # (the encoder takes its own reference: its pts is kept)
                eye.pts = row
                eye.time_base = Fraction(1, fps)
                for packet in streams[cam].encode(eye):
                    containers[cam].mux(packet)
                if row == 0:  # the first frame opened the encoder (and its threads)
                    _no_realtime_threads()
                e = int(episode_of_row[row])
                if row_in_episode[row] % sample_every[e] == 0:
                    rgb = cast(
                        npt.NDArray[np.uint8], to_rgb.reformat(eye, format="rgb24").to_ndarray()
                    )
                    histograms[cam][e].add(_downsample(rgb))
            row += 1
            report(LOAD_SHARE + (1 - LOAD_SHARE - FINISH_SHARE) * row / len(wanted))

    def access_units() -> Iterable[bytes | None]:
        for _, _, m in read(rec.path, [VIDEO_TOPIC], in_file_order=True):
            yield bytes(m["data"])
        yield None  # the end: the decoder gives what it holds

    try:
        index = 0
        for au in access_units():
            # Each message is one whole access unit: one packet, no parser needed.
            packet = av.Packet(au) if au is not None else None
            for frame in decoder.decode(packet):
                if row < len(wanted) and wanted[row] == index:
                    rows_for(index, frame)
                index += 1
            if row >= len(wanted):
                break
        if row < len(wanted):
            raise ExportError(
                f"the video decoded to {index} frames; the rows need frame {wanted[row]}"
            )
        for cam in CAMERAS:
            for packet in streams[cam].encode(None):
                containers[cam].mux(packet)
    finally:
        for container in containers.values():
            container.close()
        _no_realtime_threads()
    return name, _video_info(name, info_extra, fps, width, height)


def _open_videos(
    out: Path,
    containers: dict[str, Any],
    streams: dict[str, Any],
    name: str,
    options: dict[str, str],
    fps: int,
    width: int,
    height: int,
) -> None:
    """Each camera's mp4 opened for writing with encoder ``name`` (into ``containers``
    and ``streams`` as each opens: the caller closes whatever was opened)."""
    for cam in CAMERAS:
        path = out / VIDEO_PATH.format(
            video_key=f"observation.images.{cam}", chunk_index=0, file_index=0
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        container = av.open(str(path), "w")
        stream = cast(
            av.video.stream.VideoStream,
            container.add_stream(name, rate=fps, options=options),
        )
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.codec_context.gop_size = GOP
        stream.codec_context.time_base = Fraction(1, fps)
        containers[cam], streams[cam] = container, stream


def _video_info(
    name: str, info_extra: dict[str, Any], fps: int, width: int, height: int
) -> dict[str, Any]:
    """LeRobot's description of each camera's video (``features``' ``info``)."""
    return {
        "video.height": height,
        "video.width": width,
        "video.codec": "av1" if name == "libsvtav1" else "h264",
        "video.pix_fmt": "yuv420p",
        "video.fps": fps,
        "video.channels": 3,
        "video.g": GOP,
        **info_extra,
        "video.fast_decode": 0,
        "video.video_backend": "pyav",
        "video.extra_options": {},
        "has_audio": False,
        "is_depth_map": False,
    }
