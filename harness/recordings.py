"""Test recordings built by hand, following docs/recording.md to the letter (an MCAP file,
JSON channels, the video as ``foxglove.CompressedVideo`` with base64 Annex B H.264 access
units, side by side), so the exporters can be tested without a server.

Each video frame carries its own number in pixels: a row of 8 black/white blocks per
half (the binary number of the frame; the right half the complement), so a test can
tell which recorded frame an exported frame came from and which camera it shows.
"""

from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np
from mcap.writer import Writer

WALL0_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z: the wall clock at t = 0
MONO0 = 1000.0  # the server's monotonic clock at the start
BITS = 8


@dataclass
class Episode:
    start: float  # seconds after the recording starts
    end: float
    task: str
    success: bool | None = True


@dataclass
class Built:
    path: Path
    duration: float
    video_fps: int
    width: int  # of the side-by-side image
    height: int
    frame_times: list[float]  # capture time of each video frame (seconds after start)
    episodes: list[Episode]
    command_times: list[float] = field(default_factory=list)


def joints_at(t: float) -> list[float]:
    """The recorded joints: smooth, distinct per joint."""
    return [0.1 * (i + 1) * math.sin(0.5 * t + i) for i in range(6)]


def target_at(t: float) -> list[float]:
    """The target of the command sent at ``t``."""
    return [round(t, 3) + i for i in range(6)]


def force_at(t: float) -> list[float]:
    return [t, -t, 2.0 * t, 0.1, 0.2, 0.3]


def code_image(number: int, width: int, height: int) -> np.ndarray:
    """A side-by-side RGB image: each half shows ``number`` (left) and its complement
    (right) as 8 blocks, most significant first, white for 1."""
    img = np.full((height, width, 3), 128, np.uint8)
    half = width // 2
    for side, value in ((0, number), (1, (~number) & (2**BITS - 1))):
        block = half // BITS
        for b in range(BITS):
            bit = (value >> (BITS - 1 - b)) & 1
            x0 = side * half + b * block
            img[:, x0 : x0 + block] = 255 if bit else 0
    return img


def read_code(half_image: np.ndarray) -> int:
    """The number in one half (see ``code_image``)."""
    width = half_image.shape[1]
    block = width // BITS
    value = 0
    for b in range(BITS):
        patch = half_image[:, b * block + block // 4 : b * block + 3 * block // 4]
        value = (value << 1) | int(patch.mean() > 128)
    return value


def _schema(writer: Writer, name: str) -> int:
    return writer.register_schema(
        name=name, encoding="jsonschema", data=json.dumps({"type": "object"}).encode()
    )


def build(
    path: Path,
    *,
    duration: float = 4.0,
    episodes: list[Episode] | None = None,
    video_fps: int = 20,
    width: int = 256,
    height: int = 64,
    state_hz: float = 50.0,
    force_hz: float = 1000.0,
    jitter: float = 0.0,
    command_every: float = 0.25,
    settings: dict[str, Any] | None = None,
    autonomy: list[tuple[float, str]] | None = None,
    video_from: float = 0.0,
) -> Built:
    """Write a recording of ``duration`` seconds: state at ``state_hz``, force at
    ``force_hz``, an accepted ``move_joints`` every ``command_every`` s (and a refused one
    between, which must not count), the episodes' start/label/end events, and video at
    ``video_fps`` (capture times jittered by up to ``jitter`` of a frame), and the
    server's ``settings`` first if given (as a recording starts with them), and the
    supervised autonomy's changes ``(t, mode)`` if given. The video starts ``video_from``
    s into the recording (a worker that came up late)."""
    if episodes is None:
        episodes = [Episode(0.5, 1.7, "pick the block"), Episode(2.2, 3.6, "place the block")]
    rng = np.random.default_rng(7)
    messages: list[tuple[float, str, dict[str, Any]]] = []  # (t after start, topic, payload)

    if settings is not None:
        messages.append((0.0, "/settings", settings))
    n_state = int(duration * state_hz)
    for i in range(n_state):
        t = i / state_hz
        q = joints_at(t)
        messages.append(
            (
                t,
                "/robot/state",
                {
                    "t": MONO0 + t,
                    "status": "ready",
                    "joints": q,
                    "target_joints": q,
                    "position": [t, 2 * t, 3 * t],
                    "rotation": [1, 0, 0, 0, 1, 0, 0, 0, 1],
                },
            )
        )
    for i in range(int(duration * force_hz)):
        t = (i + 0.5) / force_hz  # (never on a row's boundary)
        messages.append(
            (
                t,
                "/force",
                {"t": MONO0 + t, "seq": i, "sensor_time": t, "values": force_at(t)},
            )
        )
    command_times = []
    k = 1
    while k * command_every < duration:
        t = k * command_every
        command_times.append(t)
        messages.append(
            (
                t,
                "/commands",
                {
                    "t": MONO0 + t,
                    "source": "rest",
                    "client_id": "c1",
                    "client": "test",
                    "kind": "move_joints",
                    "args": {},
                    "accepted": True,
                    "reason": "",
                    "code": "",
                    "target_joints": target_at(t),
                    "lease_holder": "c1",
                },
            )
        )
        tr = t + command_every / 2  # refused: never the action
        messages.append(
            (
                tr,
                "/commands",
                {
                    "t": MONO0 + tr,
                    "source": "rest",
                    "client_id": "c2",
                    "client": "intruder",
                    "kind": "move_joints",
                    "args": {},
                    "accepted": False,
                    "reason": "no lease",
                    "code": "not_allowed",
                    "target_joints": None,
                    "lease_holder": "c1",
                },
            )
        )
        k += 1
    for n, ep in enumerate(episodes):
        base = {"episode": n, "notes": ""}
        messages.append(
            (ep.start, "/episodes", {**base, "t": MONO0 + ep.start, "event": "start", "task": ""})
        )
        messages.append(
            (
                ep.end,
                "/episodes",
                {**base, "t": MONO0 + ep.end, "event": "end", "task": "", "success": None},
            )
        )
        lt = ep.end + 0.05
        messages.append(
            (
                lt,
                "/episodes",
                {**base, "t": MONO0 + lt, "event": "label", "task": ep.task, "success": ep.success},
            )
        )

    for t, mode in autonomy or []:
        messages.append((t, "/autonomy", {"t": MONO0 + t, "mode": mode, "cause": "test"}))

    # The video: H.264 Annex B access units, as the server's encoder makes them.
    frame_times = []
    enc = av.CodecContext.create("libx264", "w")
    enc.width, enc.height, enc.pix_fmt = width, height, "yuv420p"
    enc.time_base = Fraction(1, video_fps)
    enc.options = {"preset": "ultrafast", "tune": "zerolatency", "annexb": "1", "crf": "18"}
    enc.gop_size = 30
    enc.max_b_frames = 0
    n_frames = int((duration - video_from) * video_fps)
    for i in range(n_frames):
        t = video_from + i / video_fps
        t += rng.uniform(-jitter, jitter) / video_fps if jitter else 0.0
        t = max(0.0, t)
        frame_times.append(t)
        frame = av.VideoFrame.from_ndarray(code_image(i % 2**BITS, width, height), format="rgb24")
        frame.pts = i
        for packet in enc.encode(frame.reformat(format="yuv420p")):
            messages.append((t, "/video/stereo", _video(t, bytes(packet))))
    for packet in enc.encode(None):
        t = frame_times[-1]
        messages.append((t, "/video/stereo", _video(t, bytes(packet))))

    messages.sort(key=lambda m: m[0])
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="telerobot tests")
        names = {
            "/robot/state": "telerobot.RobotState",
            "/force": "telerobot.Force",
            "/commands": "telerobot.Command",
            "/episodes": "telerobot.Episode",
            "/video/stereo": "foxglove.CompressedVideo",
            "/settings": "telerobot.Settings",
            "/autonomy": "telerobot.Autonomy",
        }
        channels = {
            topic: writer.register_channel(
                topic=topic, message_encoding="json", schema_id=_schema(writer, name)
            )
            for topic, name in names.items()
        }
        for seq, (t, topic, payload) in enumerate(messages):
            log_ns = WALL0_NS + round(t * 1e9) + 300_000  # logged 0.3 ms after
            writer.add_message(
                channels[topic],
                log_time=log_ns,
                data=json.dumps(payload).encode(),
                publish_time=log_ns,
                sequence=seq,
            )
        writer.add_metadata("telerobot", {"name": path.stem, "started": "", "stopped": ""})
        writer.finish()
    return Built(path, duration, video_fps, width, height, frame_times, episodes, command_times)


def _video(t: float, data: bytes) -> dict[str, Any]:
    ns = WALL0_NS + round(t * 1e9)
    return {
        "timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
        "frame_id": "stereo",
        "format": "h264",
        "data": base64.b64encode(data).decode("ascii"),
    }


def build_listed(
    path: Path,
    *,
    name: str,
    duration: float = 1.0,
    episodes: list[dict[str, Any]] | None = None,
    state_hz: float = 50.0,
    stop_reason: str = "stopped by the operator",
    episode_events: bool = True,
) -> Path:
    """A small recording as ``GET /api/v1/recordings`` sees one, made fast (no video):
    states at ``state_hz``, each episode's start/end/label events, and the metadata the
    server writes when it closes a recording (recorder.py's ``_metadata``: name, times,
    ``duration_s``, ``stop_reason``, the episodes as JSON). ``episodes``: the recorder's
    episode records (``listed_episodes`` makes them); ``episode_events`` False writes them
    in the metadata only (all the listing reads: 10,000 long labels stay one copy). For
    benches that need hundreds."""
    episodes = episodes or []
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="telerobot bench")
        state = writer.register_channel(
            topic="/robot/state",
            message_encoding="json",
            schema_id=_schema(writer, "telerobot.RobotState"),
        )
        events = writer.register_channel(
            topic="/episodes",
            message_encoding="json",
            schema_id=_schema(writer, "telerobot.Episode"),
        )
        for i in range(int(duration * state_hz)):
            t = i / state_hz
            ns = WALL0_NS + round(t * 1e9)
            q = joints_at(t)
            payload = {"t": MONO0 + t, "status": "ready", "joints": q, "target_joints": q}
            writer.add_message(
                state, log_time=ns, data=json.dumps(payload).encode(), publish_time=ns, sequence=i
            )
        for ep in episodes if episode_events else []:
            for event, t in (("start", ep["started"]), ("end", ep["ended"])):
                ns = WALL0_NS + round((t - MONO0) * 1e9)
                payload = {**ep, "event": event, "t": t}
                writer.add_message(
                    events, log_time=ns, data=json.dumps(payload).encode(), publish_time=ns
                )
        writer.add_metadata(
            "telerobot",
            {
                "name": name,
                "started": "2026-01-01T00:00:00+00:00",
                "stopped": "2026-01-01T00:00:01+00:00",
                "duration_s": f"{duration:.3f}",
                "stop_reason": stop_reason,
                "episodes": json.dumps(episodes),
            },
        )
        writer.finish()
    return path


def listed_episodes(count: int, label_chars: int, duration: float = 1.0) -> list[dict[str, Any]]:
    """``count`` episode records as the recorder keeps them (``EpisodeInfo``), spread
    over ``duration`` s, each task label ``label_chars`` characters long."""
    step = duration / max(count, 1)
    return [
        {
            "episode": n,
            "task": (f"episode {n} " + "x" * label_chars)[:label_chars],
            "started": MONO0 + n * step,
            "ended": MONO0 + (n + 0.5) * step,
            "success": True,
            "notes": "",
        }
        for n in range(count)
    ]
