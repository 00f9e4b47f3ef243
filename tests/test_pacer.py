"""The video pacer (backend/media/pacer.py): a frame's packets spread at 2.5× the
layer's rate, RTCP at once, abs-send-time stamped when a packet really leaves. An
injected clock: no sleeping."""

from __future__ import annotations

import asyncio
import itertools

import pytest
from aiortc.rtcrtpparameters import RTCRtpHeaderExtensionParameters, RTCRtpParameters
from aiortc.rtp import HeaderExtensionsMap, RtpPacket

from telerobot.server.media.pacer import (
    MIN_RATE_BPS,
    PACING_FACTOR,
    Pacer,
    abs_send_time_offset,
)

ABS = "http://www.webrtc.org/experiments/rtp-hdrext/abs-send-time"
MID = "urn:ietf:params:rtp-hdrext:sdes:mid"


def extension_map(abs_id: int = 3) -> HeaderExtensionsMap:
    m = HeaderExtensionsMap()
    m.configure(
        RTCRtpParameters(
            headerExtensions=[
                RTCRtpHeaderExtensionParameters(id=1, uri=MID),
                RTCRtpHeaderExtensionParameters(id=abs_id, uri=ABS),
            ]
        )
    )
    return m


def rtp(size: int = 1200, abs_send_time: int | None = 0x123456, seq: int = 1) -> bytes:
    p = RtpPacket(payload_type=96, sequence_number=seq, timestamp=90_000)
    p.ssrc = 1234
    p.payload = bytes(size)
    p.extensions.mid = "0"
    if abs_send_time is not None:
        p.extensions.abs_send_time = abs_send_time
    return p.serialize(extension_map())


RTCP_RR = bytes([0x80, 201, 0, 1, 0, 0, 4, 210])  # an empty receiver report


class FakeTime:
    def __init__(self) -> None:
        self.t = 0.0

    def clock(self) -> float:
        return self.t

    async def sleep(self, s: float) -> None:
        await asyncio.sleep(0)  # others run meanwhile, as in a real wait
        self.t += s


def test_abs_send_time_is_found_and_rewritten_where_aiortc_wrote_it() -> None:
    data = rtp()
    at = abs_send_time_offset(data, 3)
    assert at is not None and data[at : at + 3] == bytes.fromhex("123456")
    pacer = Pacer(lambda b: asyncio.sleep(0), lambda: None, 3, ntp=lambda: 0xABCDEF << 14)
    stamped = pacer.stamp(data)
    parsed = RtpPacket.parse(stamped, extension_map())
    assert parsed.extensions.abs_send_time == 0xABCDEF
    assert parsed.extensions.mid == "0" and parsed.payload == bytes(1200)
    assert len(stamped) == len(data)


def test_packets_without_it_are_left_alone() -> None:
    assert abs_send_time_offset(rtp(abs_send_time=None), 3) is None
    assert abs_send_time_offset(rtp(), 7) is None  # another id was negotiated
    assert abs_send_time_offset(b"\x90" + bytes(11), 3) is None  # extension bit, no room
    two_byte = bytearray(rtp())
    two_byte[12:14] = b"\x10\x00"  # RFC 8285 two-byte headers
    assert abs_send_time_offset(bytes(two_byte), 3) is None
    pacer = Pacer(lambda b: asyncio.sleep(0), lambda: None, None)
    assert pacer.stamp(rtp()) == rtp()


def paced_burst(packets: int, layer_bps: float) -> tuple[Pacer, list[tuple[float, bytes]]]:
    """``packets`` RTP packets of 1250 B handed over at once, with an RTCP report among
    them: when each left (fake time)."""
    ft = FakeTime()
    sent: list[tuple[float, bytes]] = []

    async def send(data: bytes) -> None:
        sent.append((ft.t, data))

    pacer = Pacer(send, lambda: layer_bps, 3, clock=ft.clock, sleep=ft.sleep)

    async def burst() -> None:
        for i in range(packets):
            await pacer(rtp(1238, seq=i))  # handed over: the sender never waits
            if i == 2:
                await pacer(RTCP_RR)
        assert pacer.queued >= packets - 3  # (the drain has not run yet)
        await pacer.drained()
        pacer.close()

    asyncio.run(burst())
    return pacer, sent


def test_a_frame_leaves_at_the_pacing_rate_and_rtcp_goes_at_once() -> None:
    size = len(rtp(1238))
    pacer, sent = paced_burst(16, 800_000.0)  # 20 kB at 2 Mbit/s = 250 kB/s: 80 ms
    assert pacer.rate() == PACING_FACTOR * 800_000.0
    assert [t for t, d in sent if d == RTCP_RR] == [0.0]  # not behind the frame
    times = [t for t, d in sent if d != RTCP_RR]
    assert len(times) == 16
    assert times[-1] == pytest.approx(16 * size / 250_000, rel=0.15)
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) <= 1.1 * size / 250_000
    assert pacer.paced >= 12 and pacer.waited_s > 0


def test_a_long_queue_drains_within_its_bound() -> None:
    # 250 kB (a huge key frame) at a 250 kB/s pacing rate would take 1 s: the rate rises
    # with the queue, so it is out in ~0.1 × ln(10) + 0.1 s.
    _, sent = paced_burst(200, 800_000.0)
    times = [t for t, d in sent if d != RTCP_RR]
    assert len(times) == 200 and 0.2 < times[-1] < 0.45, times[-1]


def test_a_small_stream_is_paced_no_slower_than_the_floor_and_unknown_not_at_all() -> None:
    assert Pacer(lambda b: asyncio.sleep(0), lambda: 10_000.0).rate() == MIN_RATE_BPS
    ft = FakeTime()
    sent: list[float] = []

    async def send(data: bytes) -> None:
        sent.append(ft.t)

    pacer = Pacer(send, lambda: None, 3, clock=ft.clock, sleep=ft.sleep)

    async def burst() -> None:
        for i in range(20):
            await pacer(rtp(seq=i))
        assert pacer.queued == 0  # sent at once, not queued

    asyncio.run(burst())
    assert sent == [0.0] * 20 and pacer.paced == 0


def test_a_viewer_whose_link_loses_much_is_not_paced() -> None:
    from types import SimpleNamespace

    from telerobot.server.media.layers import RateMeter
    from telerobot.server.media.pipeline import PACE_MAX_LOSS, VideoPipeline
    from telerobot.server.media.viewer_link import ViewerLink

    meter = RateMeter()
    for i in range(21):
        meter.add(40_000, i * 0.1)  # 400 kbit/s
    pipeline = SimpleNamespace(
        encoding=SimpleNamespace(layer_rate={"full": meter}),
        _layer_of=lambda peer: "full",
        clock=SimpleNamespace(now=lambda: 2.0),
    )
    pipeline._layer_rate_bps = lambda p: VideoPipeline._layer_rate_bps(pipeline, p)  # type: ignore[arg-type]
    peer = SimpleNamespace(link=ViewerLink())
    bps = VideoPipeline._layer_bps(pipeline, peer)  # type: ignore[arg-type]
    assert bps == pytest.approx(400_000, rel=0.1)  # no report yet: paced
    peer.link.fraction_lost = PACE_MAX_LOSS / 2
    assert VideoPipeline._layer_bps(pipeline, peer) == bps  # type: ignore[arg-type]
    peer.link.fraction_lost = PACE_MAX_LOSS
    assert VideoPipeline._layer_bps(pipeline, peer) is None  # type: ignore[arg-type]


def test_a_queue_the_transport_does_not_drain_is_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    import telerobot.server.media.pacer as pacer_module

    monkeypatch.setattr(pacer_module, "MAX_QUEUE_PACKETS", 8)
    sent: list[bytes] = []
    stuck = asyncio.Event()

    async def send(data: bytes) -> None:
        sent.append(data)
        if int.from_bytes(data[2:4], "big") == 0:
            await stuck.wait()  # the first packet never finishes going out

    async def run() -> tuple[int, int]:
        pacer = Pacer(send, lambda: 800_000.0, 3)
        for i in range(20):
            await pacer(rtp(seq=i))
            await asyncio.sleep(0)
        queued, went = pacer.queued, len(sent)
        pacer.close()
        return queued, went

    queued, went = asyncio.run(asyncio.wait_for(run(), 10))
    assert queued <= 8  # never more than the bound…
    assert queued + went == 20  # …the rest went at once (out of order, not lost)
    assert went >= 20 - 8 - 1
