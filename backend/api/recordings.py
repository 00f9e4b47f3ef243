"""Recordings (issue 14, docs/recording.md): start, stop, list, metadata, download,
delete, and episodes while recording. Reading is open to every client; changing
anything needs the operator token."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from backend.api.deps import OperatorDep, ServicesDep
from backend.api.requests import StrictRequest
from backend.recording.recorder import MAX_NAME, MAX_TEXT, Recorder, RecordingNotFound

router = APIRouter(prefix="/recordings", tags=["recordings"])


def _recorder(s: ServicesDep) -> Recorder:
    return s.recorder


RecorderDep = Annotated[Recorder, Depends(_recorder)]


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
    episodes: list[Episode]
    complete: bool = Field(description="has its summary (else: telerobot recording recover)")
    stop_reason: str
    active: bool


class RecordingDetail(RecordingEntry):
    counts: dict[str, int] = Field(description="messages per topic")
    metadata: dict[str, str]


def _active(recorder: Recorder) -> ActiveRecording:
    status = recorder.status()
    if status is None:
        return ActiveRecording(recording=False)
    return ActiveRecording(recording=True, **status)


@router.get("")
async def list_recordings(recorder: RecorderDep) -> list[RecordingEntry]:
    """The newest recordings first (at most the recorder's ``max_listed``)."""
    return [RecordingEntry(**e) for e in recorder.listing()]


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
    return RecordingEntry(**_entry(recorder, path.name))


@router.post("/active/episodes")
async def start_episode(body: EpisodeStart, recorder: RecorderDep, _op: OperatorDep) -> Episode:
    return Episode(**vars(recorder.episode_start(body.task)))


@router.post("/active/episodes/end")
async def end_episode(body: EpisodeEnd, recorder: RecorderDep, _op: OperatorDep) -> Episode:
    return Episode(**vars(recorder.episode_end(body.success, body.notes)))


@router.patch("/active/episodes/{episode}")
async def label_episode(
    episode: int, body: EpisodeLabel, recorder: RecorderDep, _op: OperatorDep
) -> Episode:
    ep = recorder.label(episode, task=body.task, success=body.success, notes=body.notes)
    return Episode(**vars(ep))


def _entry(recorder: Recorder, file: str) -> dict[str, Any]:
    for e in recorder.listing():
        if e["file"] == file:
            return e
    raise RecordingNotFound(f"no recording {file!r}")


@router.get("/{file}/metadata")
async def recording_metadata(file: str, recorder: RecorderDep) -> RecordingDetail:
    from backend.recording.reader import summary

    entry = _entry(recorder, file)
    counts: dict[str, int] = {}
    meta: dict[str, str] = {}
    if entry["complete"]:
        counts, meta = summary(recorder.path_of(file))
    return RecordingDetail(**entry, counts=counts, metadata=meta)


@router.get("/{file}/download", response_class=FileResponse)
async def download_recording(file: str, recorder: RecorderDep) -> FileResponse:
    """The MCAP file as it is (streamed)."""
    return FileResponse(
        recorder.path_of(file), media_type="application/octet-stream", filename=file
    )


@router.delete("/{file}")
async def delete_recording(file: str, recorder: RecorderDep, _op: OperatorDep) -> None:
    """Refused for the recording being made."""
    recorder.delete(file)
