"""Recordings (docs/recording.md): start, stop, list, metadata, download,
delete, and episodes while recording. Changing anything needs the operator token.

Reading is open to every client, within a budget per address (``ReaderDep``; the
operator's token lifts it), and never parses a file on the event loop (the e-stop's):
the list is a page of the recordings' index (``telerobot.server.recording.index``), and what
must be parsed is parsed once, in a process of its own (``telerobot.server.recording.readjobs``).
The recording being written is refused (409) by every read that would parse it."""

from __future__ import annotations

import asyncio
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, Field

from telerobot.server.api.deps import DecisionDep, OperatorDep, ServicesDep
from telerobot.server.api.requests import StrictRequest
from telerobot.server.recording.library import DEFAULT_PAGE, MAX_PAGE
from telerobot.server.recording.recorder import MAX_NAME, MAX_TEXT, Recorder
from telerobot.server.security import bearer

router = APIRouter(prefix="/recordings", tags=["recordings"])


def _recorder(s: ServicesDep) -> Recorder:
    return s.recorder


RecorderDep = Annotated[Recorder, Depends(_recorder)]


@dataclass(frozen=True)
class Reader:
    peer: str  # the client's address: its budget
    privileged: bool  # it sent the operator token: no budget, never turned away as busy


def _reader(request: Request, recorder: RecorderDep, decision: DecisionDep) -> Reader:
    """Who reads, charged one read of its address's budget (429 past it). The token is
    looked at, not required (and not declared: the edge would then demand it)."""
    privileged = decision.clients.check_token(bearer(request.headers.get("authorization")))
    peer = request.client.host if request.client is not None else ""
    if not privileged:
        recorder.library.budgets.read(peer)
    return Reader(peer, privileged)


ReaderDep = Annotated[Reader, Depends(_reader)]

RANGE = re.compile(r"bytes=(\d*)-(\d*)$")


def charge_sent(recorder: Recorder, reader: Reader, path: Path, range_: str | None = None) -> None:
    """What the answer sends (the whole file, or the range asked for), charged to a
    tokenless reader's address: a loop of reads of a kept file costs bytes a second."""
    if reader.privileged:
        return
    size = path.stat().st_size
    sent = size
    found = RANGE.match((range_ or "").strip())
    if found and (found.group(1) or found.group(2)):
        first, last = found.group(1), found.group(2)
        if first:
            end = int(last) + 1 if last else size
            sent = max(0, min(end, size) - int(first))
        else:  # the last N bytes
            sent = min(int(last), size)
    recorder.library.budgets.sent(reader.peer, sent)


class StartRecording(StrictRequest):
    name: str = Field("recording", min_length=1, max_length=MAX_NAME)


class EpisodeStart(StrictRequest):
    task: str = Field("", max_length=MAX_TEXT)


class EpisodeEnd(StrictRequest):
    success: bool | None = None
    notes: str | None = Field(None, max_length=MAX_TEXT)


class EpisodeLabel(StrictRequest):
    task: str | None = Field(None, max_length=MAX_TEXT)
    success: bool | None = None
    notes: str | None = Field(None, max_length=MAX_TEXT)


class Episode(BaseModel):
    episode: int
    task: str
    started: float = Field(description="server clock (s)")
    ended: float | None
    success: bool | None
    notes: str


class ActiveRecording(BaseModel):
    recording: bool
    name: str | None = None
    file: str | None = None
    started: str | None = Field(None, description="UTC, ISO 8601")
    elapsed_s: float | None = None
    bytes: int | None = None
    messages: int | None = None
    queued: int | None = None
    dropped: dict[str, int] = {}
    episodes: list[Episode] = []


class RecordingEntry(BaseModel):
    file: str
    name: str
    bytes: int
    duration_s: float | None
    episodes: list[Episode] = Field(
        description="the first 50, task and notes cut to 80 characters (episode_count: all)"
    )
    episode_count: int = Field(description="episodes in the recording")
    complete: bool = Field(description="has its summary (else: telerobot recording recover)")
    stop_reason: str
    active: bool
    robot_model: str | None = Field(
        None,
        description="the arm model it was recorded with (the settings' robot_model: puma560,"
        " so101); null: not known (recorded before the list said it, or a foreign file)."
        " A task repeats only this server's model's recordings",
    )


class RecordingDetail(RecordingEntry):
    counts: dict[str, int] = Field(description="messages per topic")
    metadata: dict[str, str] = Field(
        description="the recording's telerobot metadata, each value cut to 500 characters"
        " (its episodes are in `episodes`)"
    )


def _active(recorder: Recorder) -> ActiveRecording:
    status = recorder.status()
    if status is None:
        return ActiveRecording(recording=False)
    return ActiveRecording(recording=True, **status)


@router.get(
    "",
    response_model=list[RecordingEntry],
    responses={200: {"headers": {"X-Total-Count": {"description": "recordings in all"}}}},
)
async def list_recordings(
    recorder: RecorderDep,
    reader: ReaderDep,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = DEFAULT_PAGE,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> Response:
    """The newest recordings first, a page at a time (``X-Total-Count``: how many
    there are), from the recordings' index. Without the token, a page up to a second old."""
    body, total = await recorder.library.listing_json(
        limit, offset, peer=reader.peer, privileged=reader.privileged
    )
    return Response(body, media_type="application/json", headers={"X-Total-Count": str(total)})


@router.post("")
async def start_recording(
    body: StartRecording, recorder: RecorderDep, _op: OperatorDep
) -> ActiveRecording:
    recorder.start(body.name)
    return _active(recorder)


@router.get("/active")
async def active_recording(recorder: RecorderDep) -> ActiveRecording:
    return _active(recorder)


@router.post("/active/stop")
async def stop_recording(recorder: RecorderDep, _op: OperatorDep) -> RecordingEntry:
    path = await recorder.stop()
    return RecordingEntry(**await recorder.library.entry(path.name, peer="", privileged=True))


@router.post("/active/episodes")
async def start_episode(body: EpisodeStart, recorder: RecorderDep, _op: OperatorDep) -> Episode:
    return Episode(**vars(await recorder.episode_start_with_video(body.task)))


@router.post("/active/episodes/end")
async def end_episode(body: EpisodeEnd, recorder: RecorderDep, _op: OperatorDep) -> Episode:
    return Episode(**vars(recorder.episode_end(body.success, body.notes)))


@router.patch("/active/episodes/{episode}")
async def label_episode(
    episode: int, body: EpisodeLabel, recorder: RecorderDep, _op: OperatorDep
) -> Episode:
    ep = recorder.label(episode, task=body.task, success=body.success, notes=body.notes)
    return Episode(**vars(ep))


@router.get("/{file}/metadata")
async def recording_metadata(
    file: str, recorder: RecorderDep, reader: ReaderDep
) -> RecordingDetail:
    """Its list entry with its topics' message counts and its metadata (from the
    index; the recording being written: what is known so far)."""
    entry: dict[str, Any] = await recorder.library.entry(
        file, peer=reader.peer, privileged=reader.privileged
    )
    return RecordingDetail(**entry)


@router.get("/{file}/download", response_class=FileResponse)
async def download_recording(
    file: str, recorder: RecorderDep, reader: ReaderDep, request: Request
) -> FileResponse:
    """The MCAP file as it is (streamed); not the one being written (409: it grows
    under the download and has no summary yet)."""
    path = await asyncio.to_thread(recorder.path_of, file)
    charge_sent(recorder, reader, path, request.headers.get("range"))
    return FileResponse(path, media_type="application/octet-stream", filename=path.name)


@router.delete("/{file}")
async def delete_recording(file: str, recorder: RecorderDep, _op: OperatorDep) -> None:
    """Refused for the recording being made."""
    await asyncio.to_thread(recorder.delete, file)
