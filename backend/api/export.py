"""A recording exported for robot learning: its episodes as a LeRobot
v3.0 dataset (``telerobot.server.recording.lerobot``), written beside the recordings in
``<state folder>/exports/``. One export at a time, in its own process; how far it has
got is ``GET …/export/lerobot`` (and said in the 409 a second export gets). A recording
cut short (a killed writer) is exported as far as it is valid; the one being written is
refused (409) until it stops."""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Body
from pydantic import BaseModel, Field

from telerobot.drivers.base import TelerobotError
from telerobot.server.api.deps import OperatorDep, SettingsDep
from telerobot.server.api.recordings import ReaderDep, RecorderDep
from telerobot.server.recording.lerobot import ExportSummary, export_lerobot
from telerobot.server.security import state_dir
from telerobot.tuning import yield_cpu

router = APIRouter(prefix="/recordings", tags=["recordings"])

_one_at_a_time = threading.Lock()  # exports are CPU-bound: a second one waits its turn


class ExportBusy(TelerobotError):
    code = "export_busy"
    http_status = 409


EXPORT_NICE = 10  # an export waits behind control, forces and live video


@dataclass
class _Running:
    """The export under way: its recording, since when, and how far it has got (a double
    in shared memory that the export's process writes, 0 … 1)."""

    recording: str
    started: float  # time.monotonic()
    progress: Any  # multiprocessing RawValue("d")

    def said(self) -> str:
        return f"{self.recording}, {self.progress.value:.0%} after {self.elapsed_s():.0f} s"

    def elapsed_s(self) -> float:
        return time.monotonic() - self.started


_running: _Running | None = None  # set while _one_at_a_time is held
_progress_here: Any = None  # in the export's process: where it says how far it has got


def _lower_priority(progress: Any = None) -> None:
    global _progress_here
    yield_cpu(EXPORT_NICE)
    _progress_here = progress


def _tell_progress(fraction: float) -> None:
    _progress_here.value = fraction


def _export_reporting(
    path: Path, out: Path, fps: int | None, allow_repeated_frames: bool
) -> ExportSummary:
    """The export, in its own process, telling the server how far it has got."""
    return export_lerobot(
        path,
        out,
        fps,
        allow_repeated_frames=allow_repeated_frames,
        progress=_tell_progress if _progress_here is not None else None,
    )


async def _export_in_own_process(
    path: Path, out: Path, fps: int | None, allow_repeated_frames: bool, progress: Any
) -> ExportSummary:
    """Decoding and encoding a recording's video takes seconds of CPU per recorded minute:
    in the server's process it would hold the GIL against the force stream and the event
    loop, so it runs in a process of its own at a lower priority (started fresh, so it
    shares nothing with the server's threads). ``progress``: a RawValue of the spawn
    context, handed to the process as it starts."""
    with ProcessPoolExecutor(
        max_workers=1,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_lower_priority,
        initargs=(progress,),
    ) as pool:
        return await asyncio.get_running_loop().run_in_executor(
            pool, _export_reporting, path, out, fps, allow_repeated_frames
        )


class LeRobotExportRequest(BaseModel):
    fps: int | None = Field(
        default=None,
        ge=1,
        le=120,
        description="rows per second (default: the configured video rate; for a recording "
        "without its settings, the video's real rate)",
    )
    allow_repeated_frames: bool = Field(
        default=False,
        description="export at an fps above the recorded video's rate (else 422: rows "
        "would repeat its frames)",
    )


class EpisodeCutView(BaseModel):
    episode: int = Field(description="its number among the recording's episodes, from 0")
    task: str
    start_s: float
    end_s: float
    lost_start_s: float = Field(description="seconds of it before the video's first frame")
    lost_end_s: float = Field(description="seconds of it after the video's last frame")
    left_out: bool = Field(description="under two frames of it had video: not exported")


class LeRobotExport(BaseModel):
    path: str = Field(description="the dataset's folder on the server")
    episodes: int
    frames: int
    fps: int
    tasks: list[str]
    whole_recording: bool = Field(description="no episodes were recorded: the whole one is one")
    video_codec: str | None
    recorded_s: float
    export_s: float
    skipped: list[str]
    video_fps: float | None = Field(
        description="the recorded video's real rate: its frames over its span (None: no video)"
    )
    repeated_frames: int = Field(description="rows showing the same frame as the row before")
    warnings: list[str]
    stale_rows: dict[str, int] = Field(
        description="rows whose state, force or frame was older than its bound "
        "(`telerobot.age_ms` in the dataset)"
    )
    episodes_cut: list[EpisodeCutView] = Field(
        description="episodes the recorded video did not cover whole: exported shorter "
        "(seconds lost at each end) or left out; each also said in `warnings`"
    )


class LeRobotExportProgress(BaseModel):
    running: bool = Field(description="this recording is being exported")
    progress: float | None = Field(description="the fraction done, 0 … 1")
    elapsed_s: float | None


@router.get("/{recording_id}/export/lerobot")
async def export_progress_lerobot(
    recording_id: str, recorder: RecorderDep, _reader: ReaderDep
) -> LeRobotExportProgress:
    """How far the export of this recording has got (``running`` false when none is)."""
    path = await asyncio.to_thread(recorder.path_of, recording_id)
    running = _running
    if running is None or running.recording != path.name:
        return LeRobotExportProgress(running=False, progress=None, elapsed_s=None)
    return LeRobotExportProgress(
        running=True, progress=running.progress.value, elapsed_s=running.elapsed_s()
    )


@router.post("/{recording_id}/export/lerobot")
async def export_recording_lerobot(
    recording_id: str,
    settings: SettingsDep,
    recorder: RecorderDep,
    _token: OperatorDep,
    request: Annotated[LeRobotExportRequest | None, Body()] = None,
) -> LeRobotExport:
    """Export the recording's episodes as a LeRobot v3.0 dataset into a new folder under
    ``<state folder>/exports/`` (409 while another export runs)."""
    global _running
    path = await asyncio.to_thread(recorder.path_of, recording_id)
    if not _one_at_a_time.acquire(blocking=False):
        running = _running
        doing = f" ({running.said()})" if running is not None else ""
        raise ExportBusy(f"another export is running{doing}: try again when it has finished")
    try:
        stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        out = state_dir(settings) / "exports" / f"{path.stem}-lerobot-{stamp}"
        request = request or LeRobotExportRequest()
        progress = multiprocessing.get_context("spawn").RawValue("d", 0.0)
        _running = _Running(path.name, time.monotonic(), progress)
        summary = await _export_in_own_process(
            path, out, request.fps, request.allow_repeated_frames, progress
        )
    finally:
        _running = None
        _one_at_a_time.release()
    d = summary.as_dict()
    return LeRobotExport(path=d.pop("out_dir"), **d)
