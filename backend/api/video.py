"""Stereo video over WebRTC: signalling (one POST), status and telemetry, and the
per-viewer alignment of the right image against the left (the thesis's keyboard
adjustment; applied by each viewer, since all share one encoded stream).

Each peer belongs to the viewer that opened it: its offer's reply carries a
``peer_secret``, needed to answer a server offer, to close the peer (header
``X-Peer-Secret``; the operator token closes any) and to save that viewer's alignment.
Peer ids are listed only to the operator.

With a media server (``--media-server janus``) observers watch through it: their
``/webrtc/server-offer`` is the media server's offer (peer ids ``relay-…``), answered,
closed and secured the same way, and ``/webrtc/offer`` (the browser offering) tells them
to use the server's offer instead. The operator (its token) keeps the direct path.
``GET /video`` says which path the caller gets (``path``).
"""

from __future__ import annotations

import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Header, Path, Query, Request, Response
from pydantic import BaseModel, Field

from telerobot.drivers.base import TelerobotError
from telerobot.server.api.deps import (
    AlignmentsDep,
    MediaDep,
    MediaOrNoneDep,
    MediaServerDep,
    OperatorOrNot,
    SettingsDep,
)
from telerobot.server.api.requests import StrictRequest
from telerobot.server.media import rpc
from telerobot.server.media.media_server import MediaServerSupervisor
from telerobot.server.media.pipeline import NotYourPeer
from telerobot.server.media.relay import RELAY_PREFIX
from telerobot.server.media.supervisor import MediaRequestFailed, MediaSupervisor, MediaUnavailable

router = APIRouter(tags=["video"])

SECRET_MAX = 64  # a peer secret is 22 characters; anything longer is not one
# The name in the TURN credentials a page gets ("<expiry>:telerobot-viewer" in its log).
VIEWER_TURN_NAME = "telerobot-viewer"


class SessionDescription(StrictRequest):
    sdp: str = Field(max_length=100_000)
    type: str = Field(description="'offer' (to /webrtc/offer) or 'answer' (to /webrtc/answer)")


LAYER_DOC = (
    "the video layer: 'auto' follows this viewer's link (full while it carries it, the low"
    " 2×640×360 one when it does not); 'full' or 'low' pin it (the calibration page pins"
    " 'full': it measures pixels)"
)


class Offer(SessionDescription):
    layer: Literal["auto", "full", "low"] = Field("auto", description=LAYER_DOC)


class PeerDescription(BaseModel):
    peer_id: str
    peer_secret: str = Field(
        description="this viewer's proof that the peer is its own: keep it; send it to close"
        " the peer (header X-Peer-Secret) and to save the alignment"
    )
    sdp: str
    type: str


class Answer(SessionDescription):
    peer_id: str = Field(max_length=64)
    peer_secret: str = Field("", max_length=SECRET_MAX, description="from the server's offer")


class Alignment(StrictRequest):
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
    playout_max_ms: int = Field(
        500,
        description="the most a frame is held to wait for a repair on a lossy link; a"
        " repair that takes longer is not waited for (TELEROBOT_VIDEO_PLAYOUT_MAX_MS)",
    )
    layout: str = "side-by-side: left eye in the left half"
    stats: dict[str, Any] | None
    error: str | None = Field(None, description="why there are no stats right now")
    path: Literal["direct", "relay"] = Field(
        "direct",
        description="how this caller's video comes: 'direct' from the robot's server, or"
        " 'relay' through the media server (negotiate with /webrtc/server-offer then)",
    )
    media_server: dict[str, Any] | None = Field(
        None,
        description="the media server's state (kind, state, restarts), if there is one; to"
        " the operator also where it is (url, pid, managed, last_error)",
    )


class UseServerOffer(TelerobotError):
    code = "use_server_offer"
    http_status = 409


def relayed(media_server: MediaServerSupervisor | None, operator: bool) -> bool:
    """Whether this caller watches through the media server (observers, when there is one)."""
    return media_server is not None and not operator


class IceServerEntry(BaseModel):
    """One entry of RTCConfiguration.iceServers."""

    urls: list[str]
    username: str | None = None
    credential: str | None = None


class IceConfiguration(BaseModel):
    ice_servers: list[IceServerEntry] = Field(
        description="for RTCConfiguration.iceServers; TURN credentials minted for this request"
    )
    ice_transport_policy: Literal["all", "relay"] = Field(
        description="for RTCConfiguration.iceTransportPolicy: 'relay' sends video only"
        " through TURN (the server's own peer is relay-only then too)"
    )
    expires_at: int | None = Field(
        None,
        description="unix time after which the minted TURN credentials open no new"
        " allocation: fetch this again for each new peer connection",
    )


PeerSecret = Annotated[str | None, Header(max_length=SECRET_MAX)]


async def video_stats(media: MediaSupervisor, peer_ids: bool) -> dict[str, Any]:
    """The worker's figures; peer ids only for the operator (``peer_ids``)."""
    stats: dict[str, Any] = (await media.request(rpc.Stats(peer_ids), timeout=5))["stats"]
    return stats


@router.get("/video/ice")
async def ice_configuration(settings: SettingsDep, response: Response) -> IceConfiguration:
    """The STUN/TURN servers for this page's RTCPeerConnection, and whether it must be
    relay-only. TURN credentials are time-limited (coturn's ``use-auth-secret``): minted
    for each request, never cached; the shared secret stays on the server."""
    ice = settings.ice_config
    now = time.time()
    response.headers["Cache-Control"] = "no-store"
    return IceConfiguration(
        ice_servers=[
            IceServerEntry(urls=list(s.urls), username=s.username, credential=s.credential)
            for s in ice.ice_servers(VIEWER_TURN_NAME, now)
        ],
        ice_transport_policy=ice.transport_policy,
        expires_at=ice.expires_at(now),
    )


@router.post("/webrtc/offer")
async def offer(
    body: Offer, media: MediaDep, media_server: MediaServerDep, operator: OperatorOrNot
) -> PeerDescription:
    """Send the browser's offer (with a recvonly video transceiver); get the answer.
    ICE candidates are in the SDP (no trickle). Keep ``peer_secret``. (An observer on a
    server with a media server gets 409 ``use_server_offer``.)"""
    if relayed(media_server, operator):
        raise UseServerOffer(
            "observers watch through this server's media server, which makes the offer:"
            " POST /api/v1/webrtc/server-offer, then /api/v1/webrtc/answer"
        )
    reply = await media.request(rpc.Answer(body.sdp, body.type, body.layer, operator))
    return PeerDescription(**{k: reply[k] for k in ("peer_id", "peer_secret", "sdp", "type")})


@router.post("/webrtc/server-offer")
async def server_offer(
    request: Request,
    media: MediaDep,
    media_server: MediaServerDep,
    operator: OperatorOrNot,
    layer: Annotated[
        Literal["auto", "full", "low"], Query(description="as for /webrtc/offer")
    ] = "auto",
) -> PeerDescription:
    """For browsers that need the server to offer: answer it with /webrtc/answer (with
    the ``peer_secret``) within a few seconds, or the offer is dropped. An observer on a
    server with a media server gets the media server's offer (the full layer)."""
    if relayed(media_server, operator):
        # Each address gets a share of the media server's offers and viewers, 429
        # relay_busy beyond it (backend/media/relay.py): one address cannot take them all.
        address = request.client.host if request.client else ""
        reply = await media.request(rpc.RelayOffer(address))
    else:
        reply = await media.request(rpc.Offer(layer, operator))
    return PeerDescription(**{k: reply[k] for k in ("peer_id", "peer_secret", "sdp", "type")})


@router.post("/webrtc/answer")
async def answer(body: Answer, media: MediaDep) -> dict[str, str]:
    if body.peer_id.startswith(RELAY_PREFIX):
        await media.request(rpc.RelayAccept(body.peer_id, body.peer_secret, body.sdp))
        return {"peer_id": body.peer_id}
    await media.request(rpc.Accept(body.peer_id, body.sdp, body.type, body.peer_secret))
    return {"peer_id": body.peer_id}


@router.post("/webrtc/{peer_id}/alive")
async def peer_alive(
    peer_id: Annotated[str, Path(max_length=64)],
    media: MediaDep,
    x_peer_secret: PeerSecret = None,
) -> dict[str, str]:
    """This page still watches (header ``X-Peer-Secret``): a peer through the media
    server is dropped after ``media_server_viewer_timeout_s`` (45 s) without it (the
    page says so every 15 s). A direct peer needs none: its loss is noticed by ICE."""
    if peer_id.startswith(RELAY_PREFIX):
        await media.request(rpc.RelayAlive(peer_id, x_peer_secret))
    return {"peer_id": peer_id}


@router.delete("/webrtc/{peer_id}")
async def close_peer(
    peer_id: Annotated[str, Path(max_length=64)],
    media: MediaDep,
    operator: OperatorOrNot,
    x_peer_secret: PeerSecret = None,
) -> dict[str, str]:
    """Close your own peer (header ``X-Peer-Secret``), or any (the operator token)."""
    close = rpc.RelayClose if peer_id.startswith(RELAY_PREFIX) else rpc.ClosePeer
    await media.request(close(peer_id, x_peer_secret, operator))
    return {"peer_id": peer_id}


@router.get("/video")
async def video_status(
    media: MediaOrNoneDep,
    settings: SettingsDep,
    operator: OperatorOrNot,
    media_server: MediaServerDep,
) -> VideoStatus:
    stats, error = None, None
    if media is not None and media.alive:
        # The worker can die between the check and the answer (it is then restarted):
        # the status still answers, and says so.
        try:
            stats = await video_stats(media, peer_ids=operator)
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
        playout_max_ms=settings.video_playout_max_ms,
        stats=stats,
        error=error,
        path="relay" if relayed(media_server, operator) else "direct",
        media_server=media_server.status(operator) if media_server is not None else None,
    )


@router.get("/video/alignment")
async def get_alignment(
    saved: AlignmentsDep,
    settings: SettingsDep,
    viewer: Annotated[str, Query(max_length=64)] = "",
) -> Alignment:
    """The viewer's shift of the right image, or the server's default."""
    shift = saved.get(viewer)
    if shift is not None:
        return Alignment(dx=shift[0], dy=shift[1])
    return Alignment(dx=settings.alignment_px[0], dy=settings.alignment_px[1])


@router.put("/video/alignment")
async def put_alignment(
    body: Alignment,
    media: MediaDep,
    saved: AlignmentsDep,
    viewer: Annotated[str, Query(min_length=1, max_length=64)],
    x_peer_id: Annotated[str | None, Header(max_length=64)] = None,
    x_peer_secret: PeerSecret = None,
) -> Alignment:
    """Save this viewer's shift: with the ``X-Peer-Id`` and ``X-Peer-Secret`` of its
    live video peer (each peer saves one viewer name)."""
    if not x_peer_id or not x_peer_secret:
        raise NotYourPeer(
            "saving an alignment needs this page's video connection: send the headers"
            " X-Peer-Id and X-Peer-Secret with the peer_id and peer_secret of its offer"
        )
    await media.request(rpc.ClaimViewer(x_peer_id, x_peer_secret, viewer))
    saved.remember(viewer, (body.dx, body.dy))
    return body
