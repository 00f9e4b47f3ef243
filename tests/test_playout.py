"""Frames shown as soon as decoded (``media/playout.py``): the playout-delay header
extension at 0–0 ms is negotiated with a viewer that offers it and written into each
video packet, beside aiortc's own extensions; a viewer that does not offer it gets
none, and the setting turns it off."""

from __future__ import annotations

import asyncio
import struct
from typing import Any

import pytest
from aiortc import RTCPeerConnection, RTCSessionDescription
from aiortc.rtcrtpparameters import RTCRtpHeaderExtensionParameters, RTCRtpParameters
from aiortc.rtp import (
    HeaderExtensionsMap,
    RtcpSenderInfo,
    RtcpSrPacket,
    RtpPacket,
    unpack_header_extensions,
)

from telerobot.server.media import playout
from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from tests.support.video import SMALL, camera

MID, ABS_SEND_TIME, PLAYOUT = 1, 3, 5


def _packet(**extensions: Any) -> bytes:
    """An RTP packet as aiortc writes one (mid and abs-send-time where given)."""
    params = RTCRtpParameters(
        headerExtensions=[
            RTCRtpHeaderExtensionParameters(id=MID, uri="urn:ietf:params:rtp-hdrext:sdes:mid"),
            RTCRtpHeaderExtensionParameters(
                id=ABS_SEND_TIME, uri="http://www.webrtc.org/experiments/rtp-hdrext/abs-send-time"
            ),
        ]
    )
    ids = HeaderExtensionsMap()
    ids.configure(params)
    p = RtpPacket(payload_type=96, sequence_number=7, timestamp=90_000, ssrc=1234)
    p.payload = b"\x65" + bytes(range(200))
    for name, value in extensions.items():
        setattr(p.extensions, name, value)
    return p.serialize(ids)


def _elements(packet: bytes) -> dict[int, bytes]:
    if not packet[0] & 0x10:
        return {}
    at = 12 + 4 * (packet[0] & 0x0F)
    profile, words = struct.unpack_from("!HH", packet, at)
    return dict(unpack_header_extensions(profile, packet[at + 4 : at + 4 + 4 * words]))


@pytest.mark.parametrize(
    "extensions",
    [{}, {"mid": "0"}, {"mid": "0", "abs_send_time": 0x123456}, {"abs_send_time": 1}],
    ids=["none", "mid", "mid and abs-send-time", "abs-send-time"],
)
def test_the_element_joins_the_packet_and_the_rest_is_unchanged(extensions: dict[str, Any]) -> None:
    before = _packet(**extensions)
    after = playout.with_element(before, PLAYOUT, playout.ZERO)
    assert _elements(after) == {**_elements(before), PLAYOUT: playout.ZERO}
    assert RtpPacket.parse(after).payload == RtpPacket.parse(before).payload
    parsed = RtpPacket.parse(after)
    assert (parsed.sequence_number, parsed.timestamp, parsed.ssrc) == (7, 90_000, 1234)
    # Written twice it is there once (a resend passes through again)
    again = playout.with_element(after, PLAYOUT, b"\x00\x00\x05")
    assert _elements(again)[PLAYOUT] == b"\x00\x00\x05" and len(again) == len(after)


def test_a_packet_it_cannot_read_is_left_alone() -> None:
    two_byte = bytearray(_packet(mid="0"))
    struct.pack_into("!H", two_byte, 12, 0x1000)  # RFC 8285's two-byte profile
    assert playout.with_element(bytes(two_byte), PLAYOUT, playout.ZERO) == bytes(two_byte)
    assert playout.with_element(b"\x90\x60", PLAYOUT, playout.ZERO) == b"\x90\x60"  # cut short
    cut = _packet(mid="0")[:14]  # its extension header cut off
    assert playout.with_element(cut, PLAYOUT, playout.ZERO) == cut


async def _packets_received(
    pipeline: VideoPipeline, offer_it: bool
) -> tuple[dict[str, int], list[bytes]]:
    """A real WebRTC viewer (aiortc) receiving video from ``pipeline``: the header
    extensions it agreed on (uri: id), and the decrypted RTP packets it received."""
    from aiortc import rtcdtlstransport

    seen: list[bytes] = []
    parse = rtcdtlstransport.RtpPacket.parse

    def spy(data: bytes, extensions_map: Any = None) -> RtpPacket:
        seen.append(bytes(data))
        return parse(data, extensions_map or HeaderExtensionsMap())

    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    received: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", lambda track: received.put_nowait(track))
    await pc.setLocalDescription(await pc.createOffer())
    sdp = pc.localDescription.sdp
    if not offer_it:  # a viewer that does not know the extension
        sdp = "\r\n".join(line for line in sdp.split("\r\n") if playout.URI not in line)
    answer = await pipeline.answer(sdp, "offer")
    await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
    rtcdtlstransport.RtpPacket.parse = spy  # type: ignore[method-assign]
    try:
        track = await asyncio.wait_for(received.get(), 10)
        for _ in range(5):
            await asyncio.wait_for(track.recv(), 10)  # decoded: the packets are whole
    finally:
        rtcdtlstransport.RtpPacket.parse = parse  # type: ignore[method-assign]
    (transceiver,) = pc.getTransceivers()
    agreed = {x.uri: x.id for x in transceiver._headerExtensions}
    await pc.close()
    return agreed, seen


@pytest.mark.parametrize(
    ("setting", "offer_it", "expected"),
    [(True, True, True), (True, False, False), (False, True, False)],
    ids=["offered and on", "not offered", "turned off"],
)
async def test_each_video_packet_asks_the_viewer_to_show_its_frame_at_once(
    setting: bool, offer_it: bool, expected: bool
) -> None:
    pipeline = VideoPipeline(
        camera(**SMALL), VideoSettings(bitrate=2_000_000, zero_playout_delay=setting)
    )
    pipeline.start()
    try:
        agreed, packets = await _packets_received(pipeline, offer_it)
    finally:
        await pipeline.close()
    assert len(packets) >= 5  # RTP only: RTCP does not pass the spy
    if not offer_it:
        assert playout.URI not in agreed
    if expected:
        assert all(_elements(p)[agreed[playout.URI]] == playout.ZERO for p in packets)
    else:  # aiortc's own extensions only
        others = {i for uri, i in agreed.items() if uri != playout.URI}
        assert all(set(_elements(p)) <= others for p in packets)


async def test_the_transport_s_rtcp_passes_unchanged() -> None:
    # Sender reports take the same path as RTP; written into, the viewer could not read
    # them and no round trip was measured.
    sent: list[bytes] = []

    async def send(data: bytes) -> None:
        sent.append(data)

    sr = bytes(
        RtcpSrPacket(
            ssrc=1234,
            sender_info=RtcpSenderInfo(
                ntp_timestamp=1, rtp_timestamp=2, packet_count=3, octet_count=4
            ),
        )
    )
    wrapper = playout.PlayoutDelayStamp(send, PLAYOUT)
    await wrapper(sr)
    await wrapper(_packet(mid="0"))
    assert sent[0] == sr and _elements(sent[1])[PLAYOUT] == playout.ZERO


# ---------------------------------------------------------------- the adaptive delay
def test_the_element_says_the_delay_in_10_ms_steps() -> None:
    assert playout.element(0, 0) == playout.ZERO
    assert playout.read_element(playout.element(250, 250)) == (250, 250)
    assert playout.read_element(playout.element(241, 241)) == (250, 250)  # rounded up
    assert playout.read_element(playout.element(300, 100)) == (300, 300)  # max ≥ min


def test_the_delay_grows_with_a_repair_holds_while_they_go_on_and_shrinks_back() -> None:
    p = playout.AdaptivePlayout()
    assert p.current(0.0) == 0  # a clean link: frames shown at once
    p.repair(1.0, 0.3)  # a repair that takes 300 ms
    assert p.current(1.0) == 240  # less the two frame intervals a late frame may be
    p.repair(5.0, 0.1)  # a shorter one later: the longer one still counts
    assert p.current(5.0) == 240
    p.repair(20.0, 0.2)  # 19 s later: only the newer need holds…
    assert p.current(20.0) == 140
    assert p.current(30.0) == 140  # held HOLD_S after it…
    assert p.current(31.0) == 90  # …then shrinking at 50 ms a second
    assert p.current(40.0) == 0
    # A repair longer than the cap freezes the picture whatever the delay: not waited
    # for (holding every frame would add the lag and keep the freeze)
    p.repair(41.0, 5.0)
    assert p.current(41.0) == 0 and p.too_slow == 1
    p.repair(42.0, playout.MAX_DELAY_MS / 1000 + playout.TOLERANCE_S)  # at the cap: waited
    assert p.current(42.0) == playout.MAX_DELAY_MS
    # A little past the cap (bad: repairs of 0.45–0.55 s against 0.5): the cap's worth is
    # waited, and what is left of the stop is too short to be a freeze
    q = playout.AdaptivePlayout()
    q.repair(0.0, (playout.MAX_DELAY_MS + playout.SHORT_STOP_MS - 10) / 1000 + playout.TOLERANCE_S)
    assert (q.current(0.0), q.too_slow) == (playout.MAX_DELAY_MS, 0)
    q.repair(1.0, (playout.MAX_DELAY_MS + playout.SHORT_STOP_MS + 10) / 1000 + playout.TOLERANCE_S)
    assert q.too_slow == 1


def test_an_operator_s_cap_bounds_the_delay_and_what_is_waited_for() -> None:
    p = playout.AdaptivePlayout(max_ms=150)
    p.repair(0.0, 0.4)  # 333 ms more than a late frame may be: beyond 150 + 100
    assert (p.current(0.0), p.too_slow) == (0, 1)
    p.repair(0.5, 0.3)  # 233: a stop of 83 ms left after 150, no freeze: the cap waited
    assert (p.current(0.5), p.too_slow) == (150, 1)
    p = playout.AdaptivePlayout(max_ms=150)
    p.repair(1.0, 0.2)  # 133 ms: waited for
    assert p.current(1.0) == 140


async def test_the_stamp_writes_the_delay_it_is_given() -> None:
    sent: list[bytes] = []

    async def send(data: bytes) -> None:
        sent.append(data)

    delay = [0]
    stamp = playout.PlayoutDelayStamp(send, PLAYOUT, lambda: delay[0])
    await stamp(_packet(mid="0"))
    delay[0] = 320
    await stamp(_packet(mid="0"))
    assert [playout.read_element(_elements(p)[PLAYOUT]) for p in sent] == [(0, 0), (320, 320)]
