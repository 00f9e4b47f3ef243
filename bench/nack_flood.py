"""A NACK flood from one tokenless viewer, and what it costs another viewer and the
server's encoder (issue 54; backend/media/resend_budget.py).

Starts ``telerobot serve`` with video (the simulation's stereo pair, the server's
default size unless ``--width``/``--height``), and two aiortc viewers without a token,
as any browser on the network could be: the **watcher** counts the frames it decodes;
the **flooder** asks, 200 times a second, for the 128 newest packets it has seen (an
RTCP NACK of 128 numbers), for ``--seconds``. The watcher's frame rate over a quiet
period of the same length before is the reference.

Reported (``--json``): ``other_viewer_fps_ratio`` (the watcher's frames a second during
the flood ÷ before), ``resend_amplification`` (the bytes the server resent to the
flooder, its own count, ÷ the bytes of NACKs it sent, RTCP's and SRTCP's overhead
counted; None from a server that does not count them), the server's
own counts for the flooder (its resend budget, what it refused), the encoder's
``capture_fps`` and forced key frames during the flood.

    python -m bench.nack_flood [--json] [--seconds 20] [--width 1280 --height 720]
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

import httpx
from aiortc import RTCPeerConnection, RTCSessionDescription
from aiortc.rtp import RtcpRtpfbPacket

from bench.common import emit, machine, parser
from harness.servers import serve_for_bench

NACKS_PER_S = 200
NUMBERS = 128
SRTCP_OVERHEAD = 14  # the SRTCP index (4) and its 10-byte authentication tag
TOKEN = "nack-flood-bench-operator"


class Viewer:
    """An aiortc viewer without a token: its frames counted as they are decoded."""

    def __init__(self, base: str) -> None:
        self.base = base
        self.pc = RTCPeerConnection()
        self.transceiver = self.pc.addTransceiver("video", direction="recvonly")
        self.frames: list[float] = []
        self.peer_id = ""
        self._task: asyncio.Task[None] | None = None

    async def start(self, http: httpx.AsyncClient) -> None:
        tracks: asyncio.Queue[Any] = asyncio.Queue()
        self.pc.on("track", tracks.put_nowait)
        await self.pc.setLocalDescription(await self.pc.createOffer())
        offer = {"sdp": self.pc.localDescription.sdp, "type": "offer"}
        r = await http.post(self.base + "api/v1/webrtc/offer", json=offer)
        r.raise_for_status()
        answer = r.json()
        self.peer_id = str(answer.get("peer_id", ""))
        await self.pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
        track = await asyncio.wait_for(tracks.get(), 30)
        await asyncio.wait_for(track.recv(), 30)
        self._task = asyncio.create_task(self._count(track))

    async def _count(self, track: Any) -> None:
        while True:
            await track.recv()
            self.frames.append(time.monotonic())

    def fps(self, t0: float, t1: float) -> float:
        return sum(t0 <= t < t1 for t in self.frames) / (t1 - t0)

    def newest(self) -> tuple[int, int] | None:
        """The media's SSRC and the newest sequence number this viewer has seen."""
        streams = self.transceiver.receiver._RTCRtpReceiver__remote_streams
        for ssrc, stats in streams.items():
            return ssrc, stats.max_seq
        return None

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        await self.pc.close()


async def _video_stats(http: httpx.AsyncClient, base: str) -> dict[str, Any]:
    r = await http.get(base + "api/v1/video", headers={"Authorization": f"Bearer {TOKEN}"})
    return dict(r.json().get("stats") or {})


async def flood(base: str, seconds: float) -> dict[str, Any]:
    async with httpx.AsyncClient(timeout=30) as http:
        watcher, flooder = Viewer(base), Viewer(base)
        await watcher.start(http)
        await flooder.start(http)
        quiet_t0 = time.monotonic()
        await asyncio.sleep(seconds)
        quiet_t1 = time.monotonic()
        before = await _video_stats(http, base)
        receiver = flooder.transceiver.receiver
        nack_bytes = nacks = 0
        t0 = time.monotonic()
        next_at = t0
        while time.monotonic() - t0 < seconds:
            newest = flooder.newest()
            if newest is not None:
                ssrc, seq = newest
                lost = sorted((seq - i) % 65536 for i in range(NUMBERS))
                packet = RtcpRtpfbPacket(fmt=1, ssrc=1, media_ssrc=ssrc, lost=lost)
                nack_bytes += len(bytes(packet)) + SRTCP_OVERHEAD
                nacks += 1
                await receiver._send_rtcp_nack(ssrc, lost)
            next_at += 1 / NACKS_PER_S
            await asyncio.sleep(max(0.0, next_at - time.monotonic()))
        t1 = time.monotonic()
        after = await _video_stats(http, base)
        await watcher.close()
        await flooder.close()
    resends = _resends(after, flooder.peer_id)
    # (a server without a resend budget does not count its resends: None)
    resent = (
        resends["bytes_resent"] - _resends(before, flooder.peer_id).get("bytes_resent", 0)
        if "bytes_resent" in resends
        else None
    )
    quiet_fps = watcher.fps(quiet_t0, quiet_t1)
    return {
        "other_viewer_fps_ratio": round(watcher.fps(t0, t1) / quiet_fps, 3) if quiet_fps else None,
        "other_viewer_fps": {"quiet": round(quiet_fps, 1), "flood": round(watcher.fps(t0, t1), 1)},
        "resend_amplification": None if resent is None else round(resent / max(1, nack_bytes), 2),
        "nacks_sent": nacks,
        "nack_bytes_per_s": round(nack_bytes / (t1 - t0)),
        "resent_bytes_per_s": None if resent is None else round(resent / (t1 - t0)),
        "flooder_resends": resends,
        "keyframes_forced": after.get("keyframes_forced", 0) - before.get("keyframes_forced", 0),
        "capture_fps": {"quiet": before.get("capture_fps"), "flood": after.get("capture_fps")},
    }


def _resends(stats: dict[str, Any], peer_id: str) -> dict[str, Any]:
    """The server's resend counts for one viewer (GET /api/v1/video, the operator's)."""
    for v in stats.get("viewers") or []:
        if v.get("peer_id") == peer_id:
            return dict((v.get("link") or {}).get("resends") or {})
    return {}


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument(
        "--seconds", type=float, default=20.0, help="the flood's length (and the quiet's)"
    )
    p.add_argument("--width", type=int, default=0, help="one eye's width (0: the server's default)")
    p.add_argument("--height", type=int, default=0)
    args = p.parse_args()
    figures = run(args.seconds, args.width, args.height)
    figures["machine"] = machine()
    emit({"nack_flood": figures}, args.json)


def run(seconds: float, width: int = 0, height: int = 0) -> dict[str, Any]:
    """The flood against a server of its own (also bench.abuse's ``nack_flood``)."""
    env = {"TELEROBOT_VIDEO": "true", "TELEROBOT_OPERATOR_TOKEN": TOKEN}
    if width and height:
        env |= {"TELEROBOT_VIDEO_WIDTH": str(width), "TELEROBOT_VIDEO_HEIGHT": str(height)}
    with serve_for_bench(env=env, ready=True) as (_, base):
        figures = asyncio.run(flood(base, seconds))
    return {**figures, "seconds": seconds, "video": f"{width}x{height}" if width else "default"}


if __name__ == "__main__":
    main()
