"""Liveness and version."""

from __future__ import annotations

import os
from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter
from pydantic import BaseModel, Field

from telerobot.tuning import scheduling

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str
    version: str
    realtime: bool = Field(
        description="every 1 kHz thread (force sensors, the priority channel) runs realtime"
        " (SCHED_FIFO); false: ordinary scheduling, forces may jitter under video"
        " (docs/running.md, Realtime)"
    )
    scheduling: dict[str, str] = Field(
        description="what each 1 kHz thread got, by name, as the kernel applied it:"
        " 'realtime (SCHED_FIFO n)', 'short slices (0.1 ms)' or 'ordinary'"
    )
    niceness: int = Field(description="the server process's niceness (lower: ahead)")


def _version() -> str:
    try:
        return version("telerobot")
    except PackageNotFoundError:
        return "unknown"


@router.get("/health")
async def health() -> Health:
    got = scheduling()
    return Health(
        status="ok",
        version=_version(),
        realtime=bool(got) and all(v.startswith("realtime") for v in got.values()),
        scheduling=got,
        niceness=os.getpriority(os.PRIO_PROCESS, 0),
    )
