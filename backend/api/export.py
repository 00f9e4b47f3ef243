"""A recording exported for robot learning (issue 14 part 4): its episodes as a LeRobot
v3.0 dataset (``backend.recording.lerobot``), written beside the recordings in
``<state folder>/exports/``. One export at a time, in its own process. A recording cut
short (a killed writer) is exported as far as it is valid; the one being written is
refused (409) until it stops."""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import threading
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Body
from pydantic import BaseModel, Field

from backend.api.deps import OperatorDep, SettingsDep
from backend.api.recordings import RecorderDep
from backend.recording.lerobot import ExportSummary, export_lerobot
from backend.security import state_dir
from drivers.base import TelerobotError

router = APIRouter(prefix="/recordings", tags=["recordings"])

_one_at_a_time = threading.Lock()  # exports are CPU-bound: a second one waits its turn


class ExportBusy(TelerobotError):
    code = "export_busy"
    http_status = 409


EXPORT_NICE = 10  # an export waits behind control, forces and live video


def _lower_priority() -> None:
    os.nice(EXPORT_NICE)


async def _export_in_own_process(path: Path, out: Path, fps: int | None) -> ExportSummary:
    """Decoding and encoding a recording's video takes seconds of CPU per recorded minute:
    in the server's process it would hold the GIL against the force stream and the event
    loop, so it runs in a process of its own at a lower priority (started fresh, so it
    shares nothing with the server's threads)."""
    with ProcessPoolExecutor(
        max_workers=1,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_lower_priority,
    ) as pool:
        return await asyncio.get_running_loop().run_in_executor(
            pool, export_lerobot, path, out, fps
        )


class LeRobotExportRequest(BaseModel):
    fps: int | None = Field(
        default=None, ge=1, le=120, description="rows per second (default: the video's rate)"
    )


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
    path = await asyncio.to_thread(recorder.path_of, recording_id)
    if not _one_at_a_time.acquire(blocking=False):
        raise ExportBusy("another export is running: try again when it has finished")
    try:
        stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        out = state_dir(settings) / "exports" / f"{path.stem}-lerobot-{stamp}"
        fps = request.fps if request is not None else None
        summary = await _export_in_own_process(path, out, fps)
    finally:
        _one_at_a_time.release()
    d = summary.as_dict()
    return LeRobotExport(path=d.pop("out_dir"), **d)
