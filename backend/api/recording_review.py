"""A recording played back (issue 14's review page, web/review.html): its video as an
MP4 (the recorded H.264 remuxed, no re-encode; made once and kept beside the
recordings) that a ``<video>`` element plays and seeks natively, and its other channels
as JSON on one timeline, decimated to a bounded size."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from backend.api.deps import SettingsDep
from backend.recording.reader import read, summary
from backend.recording.video import VIDEO_TOPIC, NoVideo, remux_mp4
from backend.security import state_dir
from backend.settings import Settings
from drivers.base import TelerobotError

router = APIRouter(prefix="/recordings", tags=["recordings"])

RECORDING_ID = re.compile(r"^[A-Za-z0-9_-]{1,160}(\.mcap)?$")  # the file name, .mcap optional
MAX_POINTS = 20_000  # per decimated series (force, state): a page plots this many at most
MAX_EVENTS = 5_000  # commands, safety changes, episodes: the first this many
REVIEW_TOPICS = ("/force", "/robot/state", "/commands", "/safety", "/episodes", "/calibration")


class RecordingNotFound(TelerobotError):
    code = "recording_not_found"
    http_status = 404


class RecordingHasNoVideo(TelerobotError):
    code = "recording_no_video"
    http_status = 404


def recording_path(settings: Settings, recording_id: str) -> Path:
    if not RECORDING_ID.match(recording_id):
        raise RecordingNotFound(f"no recording {recording_id!r}: ids are its file names")
    stem = recording_id.removesuffix(".mcap")
    path = state_dir(settings) / "recordings" / f"{stem}.mcap"
    if not path.is_file():
        raise RecordingNotFound(
            f"no recording {recording_id!r} (GET /api/v1/recordings lists them)"
        )
    return path


def _mp4(path: Path) -> Path:
    cache = path.parent / ".review"
    cache.mkdir(exist_ok=True)
    mp4 = cache / f"{path.stem}.mp4"
    if not mp4.is_file() or mp4.stat().st_mtime < path.stat().st_mtime:
        try:
            remux_mp4(path, mp4)
        except NoVideo as exc:
            raise RecordingHasNoVideo(str(exc)) from None
    return mp4


@router.get(
    "/{recording_id}/video.mp4",
    response_class=FileResponse,
    responses={200: {"content": {"video/mp4": {}}}},
)
async def recording_video(recording_id: str, settings: SettingsDep) -> FileResponse:
    """The recorded stereo video (side by side) as an MP4: time 0 is the first frame's
    capture time (``video_start`` in the timeline). Seekable (HTTP ranges)."""
    mp4 = await run_in_threadpool(_mp4, recording_path(settings, recording_id))
    return FileResponse(mp4, media_type="video/mp4")


class Timeline(BaseModel):
    start: float = Field(description="wall clock s of the first message: the timeline's 0")
    duration: float = Field(description="s from the first message to the last")
    video_start: float | None = Field(
        description="timeline s of the MP4's time 0 (the first frame's capture), if video"
    )
    counts: dict[str, int] = Field(description="messages per topic in the file")
    stride: dict[str, int] = Field(description="every how many messages a series keeps")
    topics: dict[str, list[dict[str, Any]]] = Field(
        description="per topic, its messages (decimated) with `time` (timeline s) added"
    )


def _timeline(path: Path, topics: list[str], max_points: int) -> Timeline:
    try:
        counts, _meta = summary(path)
    except (ValueError, OSError):
        counts = {}
    stride = {
        t: max(1, math.ceil(counts.get(t, 0) / max_points))
        for t in topics
        if t in ("/force", "/robot/state")
    }
    out: dict[str, list[dict[str, Any]]] = {t: [] for t in topics}
    seen: dict[str, int] = dict.fromkeys(topics, 0)
    first_ns: int | None = None
    last_ns = 0
    video_start: float | None = None
    for topic, log_ns, m in read(path):  # every topic: the timeline starts at the first
        if first_ns is None:
            first_ns = log_ns
        last_ns = max(last_ns, log_ns)
        if topic == VIDEO_TOPIC:
            if video_start is None:
                ts = m.get("timestamp") or {}
                video_start = ts.get("sec", 0) + ts.get("nsec", 0) / 1e9
            continue
        if topic not in out:
            continue
        i = seen[topic]
        seen[topic] = i + 1
        if i % stride.get(topic, 1) or (topic not in stride and i >= MAX_EVENTS):
            continue
        out[topic].append({**m, "time": (log_ns - first_ns) / 1e9})
    start = (first_ns or 0) / 1e9
    return Timeline(
        start=start,
        duration=(last_ns - (first_ns or 0)) / 1e9,
        video_start=None if video_start is None else video_start - start,
        counts=counts,
        stride=stride,
        topics=out,
    )


@router.get("/{recording_id}/timeline")
async def recording_timeline(
    recording_id: str,
    settings: SettingsDep,
    topics: Annotated[list[str] | None, Query(max_length=len(REVIEW_TOPICS))] = None,
    max_points: Annotated[int, Query(ge=10, le=MAX_POINTS)] = 4000,
) -> Timeline:
    """The recording's channels on one timeline (s from its first message): forces and
    states decimated to ``max_points`` each, events (commands, safety, episodes,
    calibration) as they are, up to 5000 each."""
    wanted = [t for t in (topics or REVIEW_TOPICS) if t in REVIEW_TOPICS]
    path = recording_path(settings, recording_id)
    return await run_in_threadpool(_timeline, path, wanted, max_points)
