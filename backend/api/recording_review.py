"""A recording played back (the review page, web/review.html): its video as an
MP4 (the recorded H.264 remuxed, no re-encode) that a ``<video>`` element plays and
seeks natively, and its other channels as JSON on one timeline, decimated to a bounded
size (``telerobot.server.recording.timeline``).

Both are heavy to make (every message of the file read) and are **made once and
kept** beside the recordings (``.review/``), by a job in a process of its own
(``telerobot.server.recording.readjobs``): a client without the token may read them (the
review's ``<video>`` cannot send a token, and observers review too), but a loop of
reads costs the server one job, not one per request, and within its address's budget.
A file cut short (a killed writer) is read as far as it is valid; the recording being
written is refused (409) until it stops."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from telerobot.server.api.recordings import ReaderDep, RecorderDep, charge_sent
from telerobot.server.recording.library import RangeRefused
from telerobot.server.recording.timeline import MAX_POINTS, MAX_RANGE_S, REVIEW_TOPICS

router = APIRouter(prefix="/recordings", tags=["recordings"])


@router.get(
    "/{recording_id}/video.mp4",
    response_class=FileResponse,
    responses={200: {"content": {"video/mp4": {}}}},
)
async def recording_video(
    recording_id: str, recorder: RecorderDep, reader: ReaderDep, request: Request
) -> FileResponse:
    """The recorded stereo video (side by side) as an MP4: time 0 is the first frame's
    capture time (``video_start`` in the timeline). Seekable (HTTP ranges)."""
    mp4 = await recorder.library.mp4(recording_id, peer=reader.peer, privileged=reader.privileged)
    charge_sent(recorder, reader, mp4, request.headers.get("range"))
    return FileResponse(mp4, media_type="video/mp4")


class Timeline(BaseModel):
    start: float = Field(description="wall clock s of the first message: the timeline's 0")
    duration: float = Field(description="s from the first message to the last")
    video_start: float | None = Field(
        description="timeline s of the MP4's time 0 (the first frame's capture), if video"
    )
    complete: bool = Field(
        description="the file has its summary (else it was read as far as it is valid)"
    )
    counts: dict[str, int] = Field(description="messages per topic read from the file")
    stride: dict[str, int] = Field(description="every how many messages a series keeps")
    topics: dict[str, list[dict[str, Any]]] = Field(
        description="per topic, its messages (decimated) with `time` (timeline s) added:"
        " those logged in [range_start, range_end)"
    )
    range_start: float = Field(0.0, description="timeline s: the first time this answer holds")
    range_end: float = Field(
        description="timeline s: the messages logged before this (the whole: the duration,"
        " its last message included)"
    )


@router.get("/{recording_id}/timeline", response_model=Timeline)
async def recording_timeline(
    recording_id: str,
    recorder: RecorderDep,
    reader: ReaderDep,
    topics: Annotated[list[str] | None, Query(max_length=len(REVIEW_TOPICS))] = None,
    max_points: Annotated[int, Query(ge=10, le=MAX_POINTS)] = 4000,
    start_s: Annotated[
        float | None,
        Query(ge=0, le=MAX_RANGE_S, description="a piece: from this timeline s (none: 0)"),
    ] = None,
    end_s: Annotated[
        float | None,
        Query(
            gt=0,
            le=MAX_RANGE_S,
            description="a piece: up to this timeline s, not included (none: to the end)",
        ),
    ] = None,
) -> FileResponse:
    """The recording's channels on one timeline (s from its first message): forces and
    states decimated to ``max_points`` each, events (commands, safety, episodes,
    calibration) as they are, up to 5000 each. With ``start_s``/``end_s``, a piece of
    it: the messages logged in that range, kept as the whole timeline keeps them (the
    same ``max_points`` asked of every piece of a partition: the pieces end to end are
    the whole). Each piece is made once and kept; on a file with its summary it reads
    only the part of the file it needs."""
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise RangeRefused(f"end_s ({end_s:g}) must be after start_s ({start_s:g})")
    asked = set(topics or REVIEW_TOPICS)
    wanted = [t for t in REVIEW_TOPICS if t in asked]
    out = await recorder.library.timeline(
        recording_id,
        wanted,
        max_points,
        start_s=start_s,
        end_s=end_s,
        peer=reader.peer,
        privileged=reader.privileged,
    )
    charge_sent(recorder, reader, out)
    return FileResponse(out, media_type="application/json")
