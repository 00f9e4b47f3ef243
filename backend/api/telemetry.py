"""Inter-arrival and latency statistics of every stream."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from pydantic import BaseModel, Field

from telerobot.server.api.deps import HubDep, MediaOrNoneDep, OperatorOrNot, TelemetryDep
from telerobot.server.api.video import video_stats

router = APIRouter(prefix="/telemetry", tags=["telemetry"])


class StreamSummary(BaseModel):
    name: str
    unit: str
    count: int
    window: int
    mean: float | None
    p50: float | None
    p99: float | None
    max: float | None
    histogram_edges: list[float]
    histogram_counts: list[int]


class ConnectionView(BaseModel):
    client_id: str | None = Field(description="shown to the operator only")
    operator: bool
    every_force_sample: bool
    forces_lost: int


class TelemetryView(BaseModel):
    streams: list[StreamSummary]
    connections: list[ConnectionView]
    # capture fps, encode ms, frame/keyframe sizes, viewers (their peer ids: operator only)
    video: dict[str, Any] | None = None


def _num(x: float) -> float | None:
    return None if x != x else x  # NaN (no data yet) is not JSON


@router.get("")
async def telemetry(
    stats: TelemetryDep, hub: HubDep, media: MediaOrNoneDep, operator: OperatorOrNot
) -> TelemetryView:
    streams = [
        StreamSummary(
            name=s.name,
            unit=s.unit,
            count=s.count,
            window=s.window,
            mean=_num(s.mean),
            p50=_num(s.p50),
            p99=_num(s.p99),
            max=_num(s.max),
            histogram_edges=s.histogram_edges,
            histogram_counts=s.histogram_counts,
        )
        for s in stats.summaries()
    ]
    conns = [
        ConnectionView(
            client_id=c.client_id if operator else None,
            operator=c.operator,
            every_force_sample=c.every_force_sample,
            forces_lost=c.outbox.forces_lost,
        )
        for c in hub.connections.values()
    ]
    # Video peers' ids only to the operator: a peer id is what closing a viewer names.
    video = (
        await video_stats(media, peer_ids=operator) if media is not None and media.alive else None
    )
    return TelemetryView(streams=streams, connections=conns, video=video)
