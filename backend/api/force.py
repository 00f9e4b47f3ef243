"""The force sensor: settings, start/stop, tare, latest sample. Samples stream at
full rate on /ws; this is for scripts and status."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field

from telerobot.drivers.base import FORCE_CHANNELS, ForceSensor
from telerobot.server.api.deps import ForceDep, OperatorDep, PriorityDep
from telerobot.server.api.requests import StrictRequest

router = APIRouter(prefix="/force", tags=["force"])


class Sample(BaseModel):
    seq: int
    time: float
    values: list[float] = Field(description=" ".join(FORCE_CHANNELS) + " (N, N·m), sensor frame")


class ForceState(BaseModel):
    driver: str
    running: bool
    rate_hz: float
    threshold: float
    filter_cutoff_hz: float | None
    latest: Sample | None
    counters: dict[str, int] = Field(
        default_factory=dict, description="driver counters (received, lost, bad packets…)"
    )
    error: str | None = Field(None, description="what is wrong with the sensor now, if anything")


class ForceUpdate(StrictRequest):
    rate_hz: float | None = None
    threshold: float | None = None
    filter_cutoff_hz: float | None = Field(None, description="null turns the filter off")


def _state(sensor: ForceSensor) -> ForceState:
    s = sensor.latest
    return ForceState(
        driver=sensor.name,
        running=sensor.running,
        rate_hz=sensor.rate_hz,
        threshold=sensor.threshold,
        filter_cutoff_hz=sensor.filter_cutoff_hz,
        latest=None if s is None else Sample(seq=s.seq, time=s.time, values=list(s.values)),
        counters=dict(sensor.counters),
        error=sensor.error,
    )


class ChannelState(BaseModel):
    port: int = Field(description="TCP port of the priority channel (docs/protocol.md)")
    clients: int
    samples_sent: int
    forces_dropped: int = Field(description="samples dropped for clients that fell behind")
    limits: dict[str, int] = Field(
        default_factory=dict,
        description="what the channel refused: connections refused or shed, HELLO timeouts,"
        " clients over the message rate, oversized messages, accept errors, thread restarts",
    )


@router.get("/channel")
async def channel(priority: PriorityDep) -> ChannelState:
    """Where the priority channel listens: forces at full rate, commands, for the
    master-arm bridge (`telerobot master`)."""
    return ChannelState(
        port=priority.port,
        clients=sum(c.session is not None for c in list(priority.clients)),
        samples_sent=priority.samples_sent,
        forces_dropped=sum(c.forces_dropped for c in list(priority.clients)),
        limits=priority.stats(),
    )


@router.get("")
async def force_state(sensor: ForceDep) -> ForceState:
    return _state(sensor)


@router.put("")
async def update_force(body: ForceUpdate, sensor: ForceDep, _op: OperatorDep) -> ForceState:
    if body.rate_hz is not None:
        sensor.rate_hz = body.rate_hz
    if body.threshold is not None:
        sensor.threshold = body.threshold
    if "filter_cutoff_hz" in body.model_fields_set:
        sensor.filter_cutoff_hz = body.filter_cutoff_hz
    return _state(sensor)


@router.post("/start")
async def start(sensor: ForceDep, _op: OperatorDep) -> ForceState:
    sensor.start()
    return _state(sensor)


@router.post("/stop")
async def stop(sensor: ForceDep, _op: OperatorDep) -> ForceState:
    sensor.stop()
    return _state(sensor)


@router.post("/tare")
async def tare(sensor: ForceDep, _op: OperatorDep) -> ForceState:
    """The next reading becomes zero."""
    sensor.tare()
    return _state(sensor)
