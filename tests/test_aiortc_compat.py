"""aiortc's internals behind one adapter (backend/media/aiortc_compat.py): the installed
aiortc has every internal the video uses, in the range pyproject.toml pins; one that
moved is refused at start, named; the payload cut for FEC is one sender's, not the
process's."""

from __future__ import annotations

import asyncio
import re
import tomllib
from importlib.metadata import version
from pathlib import Path
from typing import Any

import pytest
from aiortc import RTCPeerConnection, RTCRtpSender, RTCSessionDescription
from aiortc.codecs import h264
from packaging.specifiers import SpecifierSet

from harness import wan_receiver
from telerobot.server.media import aiortc_compat
from telerobot.server.media.fec import MEDIA_PAYLOAD_MAX
from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from tests.support.video import SMALL, camera, frames_of, viewer_of

ROOT = Path(__file__).resolve().parents[1]


def test_the_installed_aiortc_has_every_internal_in_the_pinned_range() -> None:
    aiortc_compat.check()
    pinned = [
        d for d in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
        if d.startswith("aiortc")
    ]  # fmt: skip
    assert pinned == [f"aiortc{aiortc_compat.TESTED}"]
    assert version("aiortc") in SpecifierSet(aiortc_compat.TESTED)


def test_an_internal_that_moved_is_refused_at_start_by_name(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    made = RTCRtpSender.__init__

    def renamed(self: Any, *args: Any, **kwargs: Any) -> None:
        made(self, *args, **kwargs)
        self._RTCRtpSender__history = self.__dict__.pop("_RTCRtpSender__rtp_history")

    monkeypatch.setattr(RTCRtpSender, "__init__", renamed)
    with pytest.raises(
        aiortc_compat.AiortcIncompatible, match=r"RTCRtpSender\._RTCRtpSender__rtp_history"
    ):
        aiortc_compat.check()
    with pytest.raises(
        aiortc_compat.AiortcIncompatible, match=re.escape(f"aiortc{aiortc_compat.TESTED}")
    ):
        VideoPipeline(camera(**SMALL), VideoSettings())  # the video does not start


async def test_the_payload_cut_for_fec_is_the_protected_sender_s_alone() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=4_000_000, fec="on"))
    pipeline.start()
    wan_receiver.allow()
    pc = RTCPeerConnection()
    sizes: list[int] = []
    try:
        transceiver = pc.addTransceiver("video", direction="recvonly")
        got: asyncio.Queue[Any] = asyncio.Queue()
        pc.on("track", got.put_nowait)
        await pc.setLocalDescription(await pc.createOffer())
        answer = await pipeline.answer(pc.localDescription.sdp, "offer")
        transport = transceiver.receiver.transport
        wan_receiver.attach(transport)  # RED and FEC undone before aiortc sees them
        handle = transport._handle_rtp_data

        async def measured(data: bytes, arrival_time_ms: int) -> None:
            sizes.append(len(data))
            await handle(data, arrival_time_ms)

        transport._handle_rtp_data = measured
        await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
        track = await asyncio.wait_for(got.get(), 10)
        for _ in range(10):  # a key frame's packets among them: full ones
            await asyncio.wait_for(track.recv(), 10)
    finally:
        await pc.close()
        await pipeline.close()
    # Each media packet's payload cut to MEDIA_PAYLOAD_MAX: with its RTP header, the
    # extensions, RED's byte and SRTP's tag, well under aiortc's 1300-byte payloads
    assert max(sizes) <= MEDIA_PAYLOAD_MAX + 60, max(sizes)
    assert h264.PACKET_MAX == 1300  # the process's constant as aiortc has it


def test_a_connected_viewers_sockets_are_marked_as_video_on_the_servers_loop() -> None:
    """On uvloop (the server's loop) a transport's socket is a PseudoSocket, not a
    socket.socket: the marking was skipped for every viewer, said in the log each time.
    The viewer's sockets are found through the adapter and marked CS1 on either loop."""
    import socket

    import uvloop

    from telerobot.protocol.netprio import DSCP_CS1

    async def watch() -> list[int]:
        pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=1_000_000))
        pipeline.start()
        try:
            pc, track, peer_id = await viewer_of(pipeline)
            await frames_of(track, 1, SMALL["width"])  # connected: marked by now
            socks = aiortc_compat.peer_sockets(pipeline.peers[peer_id].pc)
            marks = [
                s.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_TCLASS)
                if s.family == socket.AF_INET6
                else s.getsockopt(socket.IPPROTO_IP, socket.IP_TOS)
                for s in socks
            ]
            await pc.close()
            return marks
        finally:
            await pipeline.close()

    for run in (asyncio.run, uvloop.run):
        marks = run(watch())
        assert marks and set(marks) == {DSCP_CS1}, (run, marks)
