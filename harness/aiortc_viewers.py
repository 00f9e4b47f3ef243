"""aiortc peers that watch the stereo video as a browser does: asking for it with an
offer (``open_viewer``) or answering the server's offer (``open_server_offer_viewer``,
``answer_server_offer``: an observer behind the media server, or the operator's direct
path)."""

from __future__ import annotations

from typing import Any


async def open_viewer(base: str, timeout: float = 30.0) -> tuple[Any, Any]:
    """An aiortc peer that asks ``base`` for the stereo video (one POST, as a browser
    does): returns the peer connection and its video track once the track is up."""
    import asyncio

    import httpx
    from aiortc import RTCPeerConnection, RTCSessionDescription

    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    tracks: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", tracks.put_nowait)
    await pc.setLocalDescription(await pc.createOffer())
    async with httpx.AsyncClient(base_url=base, timeout=timeout) as http:
        r = await http.post(
            "api/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp, "type": "offer"}
        )
        if r.status_code != 200:
            await pc.close()
            raise RuntimeError(f"the server refused the offer: HTTP {r.status_code} {r.text}")
        await pc.setRemoteDescription(RTCSessionDescription(r.json()["sdp"], r.json()["type"]))
    return pc, await asyncio.wait_for(tracks.get(), timeout)


async def answer_server_offer(
    http: Any, pc: Any, layer: str | None = None, before_answer: Any = None
) -> dict[str, str]:
    """The server offers (``/webrtc/server-offer``, the media server's offer for an
    observer on a server with one), ``pc`` answers (``/webrtc/answer``); the peer's id
    and secret. ``before_answer(offer)`` runs once the offer is set and before the
    answer is made (the moment to open Janus's data channel). ``http``: an
    httpx.AsyncClient on the server (with the token for the operator's direct path)."""
    from aiortc import RTCSessionDescription

    params = {"layer": layer} if layer else None
    r = await http.post("api/v1/webrtc/server-offer", params=params, json={})
    if r.status_code != 200:
        raise RuntimeError(f"the server refused to offer: HTTP {r.status_code} {r.text[:300]}")
    offer = r.json()
    await pc.setRemoteDescription(RTCSessionDescription(offer["sdp"], offer["type"]))
    if before_answer is not None:
        before_answer(offer)
    await pc.setLocalDescription(await pc.createAnswer())
    peer = {"peer_id": offer["peer_id"], "peer_secret": offer["peer_secret"]}
    r = await http.post(
        "api/v1/webrtc/answer", json={"sdp": pc.localDescription.sdp, "type": "answer", **peer}
    )
    if r.status_code != 200:
        raise RuntimeError(f"the server refused the answer: HTTP {r.status_code} {r.text[:300]}")
    return peer


async def open_server_offer_viewer(
    base: str, token: str | None = None, timeout: float = 30.0
) -> tuple[Any, Any, dict[str, str]]:
    """An aiortc peer that takes the server's offer (``/webrtc/server-offer``, then
    ``/webrtc/answer``), as an observer does on a server with a media server (its offer
    is the media server's) or with ``token`` the operator's direct path. Returns the
    peer connection, its video track once up, and the peer's id and secret."""
    import asyncio

    import httpx
    from aiortc import RTCPeerConnection

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    pc = RTCPeerConnection()
    tracks: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", tracks.put_nowait)
    async with httpx.AsyncClient(base_url=base, timeout=timeout, headers=headers) as http:
        try:
            peer = await answer_server_offer(http, pc)
        except RuntimeError:
            await pc.close()
            raise
    return pc, await asyncio.wait_for(tracks.get(), timeout), peer
