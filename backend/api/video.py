"""Stereo video over WebRTC: signalling (one POST), status and telemetry, and the
per-viewer alignment of the right image against the left (the thesis's keyboard
adjustment; applied by each viewer, since all share one encoded stream)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from pydantic import BaseModel, Field

from backend.api.deps import SettingsDep
from backend.media.supervisor import MediaRequestFailed, MediaSupervisor, MediaUnavailable

router = APIRouter(tags=["video"])


class SessionDescription(BaseModel):
    sdp: str = Field(max_length=100_000)
    type: str = Field(description="'offer' (to /webrtc/offer) or 'answer' (to /webrtc/answer)")


class PeerDescription(BaseModel):
    peer_id: str
    sdp: str
    type: str


class Answer(SessionDescription):
    peer_id: str


class Alignment(BaseModel):
    dx: int = Field(0, ge=-400, le=400, description="pixels the right image moves right")
    dy: int = Field(0, ge=-400, le=400, description="pixels the right image moves down")


class VideoStatus(BaseModel):
    enabled: bool
    worker_alive: bool
    worker_restarts: int
    width: int
    height: int
    fps: float
    bitrate: int
    layout: str = "side-by-side: left eye in the left half"
    stats: dict[str, Any] | None
    error: str | None = Field(None, description="why there are no stats right now")


def media_supervisor(request: Request) -> MediaSupervisor:
    media: MediaSupervisor | None = request.app.state.media
    if media is None:
        raise MediaUnavailable("video is turned off on this server (setting video = false)")
    return media


@router.post("/webrtc/offer")
async def offer(body: SessionDescription, request: Request) -> PeerDescription:
    """Send the browser's offer (with a recvonly video transceiver); get the answer.
    ICE candidates are in the SDP (no trickle)."""
    reply = await media_supervisor(request).request("answer", sdp=body.sdp, type=body.type)
    return PeerDescription(peer_id=reply["peer_id"], sdp=reply["sdp"], type=reply["type"])


@router.post("/webrtc/server-offer")
async def server_offer(request: Request) -> PeerDescription:
    """For browsers that need the server to offer: answer it with /webrtc/answer."""
    reply = await media_supervisor(request).request("offer")
    return PeerDescription(peer_id=reply["peer_id"], sdp=reply["sdp"], type=reply["type"])


@router.post("/webrtc/answer")
async def answer(body: Answer, request: Request) -> dict[str, str]:
    await media_supervisor(request).request(
        "accept", peer_id=body.peer_id, sdp=body.sdp, type=body.type
    )
    return {"peer_id": body.peer_id}


@router.delete("/webrtc/{peer_id}")
async def close_peer(peer_id: str, request: Request) -> dict[str, str]:
    await media_supervisor(request).request("close_peer", peer_id=peer_id)
    return {"peer_id": peer_id}


@router.get("/video")
async def video_status(request: Request, settings: SettingsDep) -> VideoStatus:
    media: MediaSupervisor | None = request.app.state.media
    stats, error = None, None
    if media is not None and media.alive:
        # The worker can die between the check and the answer (it is then restarted):
        # the status still answers, and says so.
        try:
            stats = (await media.request("stats", timeout=5))["stats"]
        except (MediaUnavailable, MediaRequestFailed, OSError) as exc:
            error = str(exc) or type(exc).__name__
    return VideoStatus(
        enabled=media is not None,
        worker_alive=media is not None and media.alive,
        worker_restarts=media.restarts if media else 0,
        width=settings.video_width,
        height=settings.video_height,
        fps=settings.video_fps,
        bitrate=settings.video_bitrate,
        stats=stats,
        error=error,
    )


@router.get("/video/alignment")
async def get_alignment(
    request: Request, settings: SettingsDep, viewer: Annotated[str, Query(max_length=64)] = ""
) -> Alignment:
    """The viewer's shift of the right image, or the server's default."""
    saved: dict[str, Alignment] = request.app.state.alignments
    return saved.get(viewer) or Alignment(dx=settings.alignment_px[0], dy=settings.alignment_px[1])


@router.put("/video/alignment")
async def put_alignment(
    body: Alignment, request: Request, viewer: Annotated[str, Query(min_length=1, max_length=64)]
) -> Alignment:
    request.app.state.alignments[viewer] = body
    return body
