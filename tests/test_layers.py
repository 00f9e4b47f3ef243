"""Two video layers and the choice between them: the choice with an
injected clock, a viewer's track moving between layers on a keyframe without a gap,
and real aiortc viewers getting the low layer's smaller picture from a second, shared
encoder. The same on emulated links: tests/test_layers_netem.py."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

import pytest

from telerobot.drivers.clock import ManualClock
from telerobot.server.media.fanout import Broadcaster
from telerobot.server.media.layers import (
    ESTIMATE_GRACE_S,
    FAILED_PROBE_S,
    MAX_UP_HOLD_S,
    UP_HOLD_S,
    LayerChoice,
    RateMeter,
    low_size,
)
from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from tests.support.video import SMALL, Counter, camera, frame, frames_of, viewer_of


@dataclass
class Link:
    estimated_bps: int | None = None
    fraction_lost: float | None = None
    rtt_s: float | None = None
    reports: int = 0

    def report(self, lost: float = 0.0, rtt_s: float = 0.05, bps: int | None = None) -> Link:
        self.fraction_lost, self.rtt_s, self.reports = lost, rtt_s, self.reports + 1
        if bps is not None:
            self.estimated_bps = bps
        return self


FULL = 3_000_000  # the full layer's measured rate, bits/s


# ---------------------------------------------------------------- the choice
def test_a_clean_link_keeps_the_full_layer() -> None:
    c, link = LayerChoice(), Link()
    for t in range(60):
        assert c.decide(link.report(0.01, 0.05, 8_000_000), FULL, float(t)) == "full"
    assert c.switches == 0


def bad_reports(c: LayerChoice, link: Link, t: float, **report: float) -> str:
    """Two fresh reports in a row (a second apart) with ``report``: the layer after."""
    c.decide(link.report(**report), FULL, t)  # type: ignore[arg-type]
    return c.decide(link.report(**report), FULL, t + 1.0)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("report", "why"),
    [
        ({"lost": 0.08}, "8% lost"),
        ({"bps": 2_000_000}, "estimate 2.00 Mbit/s below the full layer's 3.00"),
        ({"rtt_s": 0.05 + 0.3}, "round trip 350 ms (a queue: it was 50)"),
    ],
)
def test_the_full_layer_is_left_on_two_reports_saying_the_link_cannot_carry_it(
    report: dict[str, float], why: str
) -> None:
    c, link = LayerChoice(), Link()
    c.decide(link.report(0.0, 0.05, 8_000_000), FULL, 0.0)
    assert c.decide(link.report(**report), FULL, 1.0) == "full"  # type: ignore[arg-type]
    assert c.decide(link.report(**report), FULL, 2.0) == "low"  # type: ignore[arg-type]
    assert c.why == why and c.switches == 1


def test_one_bad_report_between_good_ones_is_a_hiccup() -> None:
    c, link = LayerChoice(), Link()
    for t in range(20):  # every other report a late RTCP packet or a lossy second
        bad = t % 2 == 1
        link.report(0.2 if bad else 0.0, 0.6 if bad else 0.05)
        assert c.decide(link, FULL, float(t)) == "full"


def test_an_old_loss_report_is_not_counted_twice() -> None:
    c, link = LayerChoice(), Link()
    link.report(0.06)
    assert c.decide(link, FULL, 0.0) == "full"  # one report: not yet
    # The same report seen again is not fresh; a second one with 6 % is.
    assert c.decide(link, FULL, 1.0) == "full"
    assert c.decide(link, FULL, 2.0) == "full"
    assert c.decide(link.report(0.06), FULL, 3.0) == "low"


def test_up_again_only_after_a_clean_hold_and_a_failed_try_doubles_the_wait() -> None:
    c, link = LayerChoice(), Link()
    assert bad_reports(c, link, 0.0, lost=0.10) == "low"
    t = down_at = 1.0
    while c.layer == "low":  # clean reports every second
        t += 1.0
        c.decide(link.report(0.0), FULL, t)
    assert t - down_at == UP_HOLD_S
    # The try fails within FAILED_PROBE_S: back down, and the next wait is twice as long.
    assert bad_reports(c, link, t + 1.0, lost=0.10) == "low"
    t = down_at = t + 2.0
    while c.layer == "low":
        t += 1.0
        c.decide(link.report(0.0), FULL, t)
    assert t - down_at == 2 * UP_HOLD_S
    # A lossy report on the low layer restarts the wait.
    assert bad_reports(c, link, t + 1, lost=0.10) == "low"
    t += 2.0
    c.decide(link.report(0.10), FULL, t)
    assert c.decide(link.report(0.0), FULL, t + UP_HOLD_S) == "low"  # hold still 2×
    assert c.switches == 5


def test_the_wait_after_failed_tries_stops_doubling_at_its_ceiling() -> None:
    c, link = LayerChoice(), Link()
    t = 0.0
    holds = []
    for _ in range(8):  # down, wait clean, try, fail at once: eight times
        assert bad_reports(c, link, t, lost=0.10) == "low"
        t += 1.0
        down_at = t
        while c.layer == "low":
            t += 1.0
            c.decide(link.report(0.0), FULL, t)
        holds.append(t - down_at)
        t += 1.0
    assert holds[:4] == [UP_HOLD_S, 2 * UP_HOLD_S, 4 * UP_HOLD_S, MAX_UP_HOLD_S]
    assert holds[4:] == [MAX_UP_HOLD_S] * 4  # never longer than the ceiling


def test_the_rate_meter_keeps_a_bounded_window() -> None:
    m = RateMeter(window_s=2.0, capacity=512)
    for i in range(10_000):  # 100 frames a second (both layers at 30 fps are 60)
        m.add(10_000, i / 100)
    assert m.bps(100.0) == pytest.approx(1_000_000, rel=0.02)
    for i in range(100_000):  # far denser than any encoder: the oldest fall off…
        m.add(1_000, 100 + i / 1000)
    assert len(m._samples) == 512
    assert m.bps(200.0) is None  # …and it says nothing rather than a wrong rate


def test_a_low_estimate_that_is_still_climbing_is_no_reason_to_go_down() -> None:
    # Chromium's estimate starts near 70 kbit/s and climbs ~8 %/s on a link with room.
    c, link, bps = LayerChoice(), Link(), 70_000.0
    for t in range(30):
        assert c.decide(link.report(0.0, bps=int(bps)), FULL, float(t)) == "full"
        bps *= 1.08
    # A congested estimator cuts its estimate: that is a reason.
    assert bad_reports(c, link, 30.0, lost=0.0, bps=int(bps * 0.7)) == "low"


def test_after_going_up_an_estimate_sized_by_the_low_layer_is_given_time_to_grow() -> None:
    c, link = LayerChoice(), Link()
    bad_reports(c, link, 0.0, lost=0.10, bps=1_500_000)
    c.decide(link.report(0.0, bps=1_500_000), FULL, 1.0 + UP_HOLD_S)
    assert c.layer == "full"
    up = 1.0 + UP_HOLD_S
    # Still the low layer's estimate, even falling: no reason within the grace…
    c.decide(link.report(0.0, bps=1_800_000), FULL, up + 1)
    assert bad_reports(c, link, up + 2, lost=0.0, bps=1_500_000) == "full"
    # …but past it, a falling estimate below the full rate is.
    t = up + ESTIMATE_GRACE_S
    assert bad_reports(c, link, t, lost=0.0, bps=1_400_000) == "low"
    assert t - up >= FAILED_PROBE_S  # not counted as a failed try: the wait stays
    assert c.up_hold_s == UP_HOLD_S


def test_the_rate_meter_measures_a_window_and_says_none_before() -> None:
    m = RateMeter(window_s=2.0)
    assert m.bps(0.0) is None
    for i in range(90):  # 30 frames/s of 10 kbit
        m.add(10_000, i / 30)
    assert m.bps(3.0) == pytest.approx(300_000, rel=0.05)
    assert m.bps(10.0) is None  # nothing lately


def test_the_low_layer_is_half_each_way_in_even_pixels() -> None:
    assert low_size(1280, 720) == (640, 360)
    assert low_size(640, 360) == (320, 180)
    w, h = low_size(642, 362, 0.5)  # 321 × 181: odd, which 4:2:0 cannot take
    assert w % 2 == 0 == h % 2 and abs(w - 321) == 1 and abs(h - 181) == 1


# ---------------------------------------------------------------- moving a track
async def test_a_track_moves_on_the_new_layers_keyframe_without_a_gap() -> None:
    clock = ManualClock()
    full_asked, low_asked = Counter(), Counter()
    full, low = Broadcaster(full_asked, clock.now), Broadcaster(low_asked, clock.now)
    t = full.new_track()
    t.start_sending()
    full.publish(frame(True, 0))
    t.move_to(low)
    assert low_asked.n == 1 and low.sending == 1 and full.viewers == 1 and low.viewers == 0
    # Until the low layer's keyframe the full layer's frames go on; low's P-frames are not taken.
    full.publish(frame(False, 1))
    low.publish(frame(False, 1))
    assert [f.seq for f in t._queue] == [0, 1] and t.source is full
    full.publish(frame(False, 2))
    low.publish(frame(True, 2))  # the switch: the full layer's copy of frame 2 is dropped
    assert t.source is low and t.joining is None and t.switches == 1
    assert [(f.seq, f.keyframe) for f in t._queue] == [(2, True)]
    assert t not in full.tracks and full.sending == 0  # the full layer may stop encoding
    full.publish(frame(True, 3))
    assert len(t._queue) == 1  # not from the layer it left
    # Moving back before the other layer's keyframe cancels the move.
    t.move_to(full)
    t.move_to(low)
    assert t.joining is None and t not in full.tracks
    t.stop()
    assert not low.tracks and not full.tracks


# ---------------------------------------------------------------- real viewers
async def test_viewers_on_two_layers_get_two_sizes_from_two_shared_encoders() -> None:
    cam = camera(**SMALL)
    pipeline = VideoPipeline(cam, VideoSettings(bitrate=2_000_000, low_bitrate=400_000))
    pipeline.start()
    try:
        (pa, ta, ida), (pb, tb, idb) = await asyncio.gather(
            viewer_of(pipeline, "full"), viewer_of(pipeline, "low")
        )
        full_frames, low_frames = await asyncio.gather(
            frames_of(ta, 10, cam.width), frames_of(tb, 10, cam.width)
        )
        assert {(w, h) for w, h, _ in full_frames} == {(cam.width, cam.height)}
        assert {(w, h) for w, h, _ in low_frames} == {low_size(cam.width, cam.height)}
        # Real capture times, this machine's clock (a sanity bound, not a latency: that
        # is bench.video's).
        assert all(0 <= age < 30.0 for *_, age in full_frames + low_frames)
        stats = pipeline.stats(peer_ids=True)
        assert set(pipeline.encoding.encoders) == {("H264", "full"), ("H264", "low")}
        layers = {v["peer_id"]: v["layer"] for v in stats["viewers"]}
        assert layers == {ida: "full", idb: "low"}
        assert stats["layers"]["low"]["width"] == cam.width // 2
        assert stats["layers"]["low"]["viewers"] == 1 and stats["layers"]["full"]["viewers"] == 1
        # The full-layer viewer is moved down (as its link would): its next frames are
        # the low layer's, counted as one switch; the low encoder stays one encoder.
        peer = pipeline.peers[ida]
        pipeline.set_layer(peer, "low")
        seen = await frames_of(ta, 40, cam.width)
        assert seen[-1][:2] == low_size(cam.width, cam.height)
        sizes = [s[:2] for s in seen]
        assert sizes == sorted(sizes, reverse=True)  # one change, never back
        assert peer.track.switches == 1 and pipeline.stats()["layers"]["full"]["viewers"] == 0
        await asyncio.gather(pa.close(), pb.close())
    finally:
        await pipeline.close()


async def test_the_low_layer_is_not_encoded_while_nobody_takes_it() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=1_000_000))
    pipeline.start()
    try:
        pc, track, _ = await viewer_of(pipeline, "auto")
        await frames_of(track, 5, SMALL["width"])
        assert set(pipeline.encoding.encoders) == {("H264", "full")}  # never made
        assert pipeline.stats()["layers"]["low"]["kbps"] is None
        await pc.close()
    finally:
        await pipeline.close()


async def test_a_nack_for_a_packet_no_longer_kept_asks_for_a_key_frame() -> None:
    """After a cut, a receiver asks for packets older than the sender's history: they
    cannot be resent, so a key frame is sent instead of leaving it to wait."""
    from types import SimpleNamespace

    from aiortc.rtp import RTCP_RTPFB_NACK, RTP_HISTORY_SIZE, RtcpRtpfbPacket

    from telerobot.server.media.viewer_link import KEYFRAME_AGAIN_S, ViewerLink, follow_link

    asked: list[int] = []
    handled: list[object] = []

    async def handle(packet: object) -> None:  # aiortc's own handler (resends what it has)
        handled.append(packet)

    sender = SimpleNamespace(_ssrc=7, _handle_rtcp_packet=handle)
    kept = {seq % RTP_HISTORY_SIZE: SimpleNamespace(sequence_number=seq) for seq in range(500, 628)}
    sender._RTCRtpSender__rtp_history = kept
    sender._send_keyframe = lambda: asked.append(1)
    link = ViewerLink()
    follow_link(sender, link)  # type: ignore[arg-type]
    await sender._handle_rtcp_packet(
        RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[600, 601])
    )
    assert (len(handled), asked, link.nacks_unservable) == (1, [], 0)  # resendable
    await sender._handle_rtcp_packet(
        RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[300, 301, 627])
    )
    assert (asked, link.nacks_unservable) == ([1], 2)  # 300 and 301 are gone
    # …and 627, which could be, is not resent: the key frame replaces it too
    assert (len(handled), link.resends_spared) == (1, 1)
    assert link.as_dict(0.0)["nacks_unservable"] == 2
    # The receiver asks again for the same gap: the key frame asked for (it goes out
    # after packet 627) replaces those packets, so nothing more is asked.
    await sender._handle_rtcp_packet(
        RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[300, 301])
    )
    assert (asked, link.nacks_superseded) == ([1], 2)

    # Later packets lost and gone too (sent after it): a key frame again.
    def history(first: int) -> dict[int, object]:
        return {
            seq % RTP_HISTORY_SIZE: SimpleNamespace(sequence_number=seq % 65536)
            for seq in range(first, first + 128)
        }

    sender._RTCRtpSender__rtp_history = history(2000)
    lost_later = RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[1500])
    await sender._handle_rtcp_packet(lost_later)
    # (not at once: a viewer's NACKs ask for a key frame every KEYFRAME_AGAIN_S at most)
    assert (asked, link.nacks_unservable, link.keyframe_covers_through) == ([1], 3, 627)
    link.keyframe_covers_at -= KEYFRAME_AGAIN_S
    await sender._handle_rtcp_packet(lost_later)
    assert (asked, link.nacks_unservable, link.keyframe_covers_through) == ([1, 1], 4, 2127)
    # Numbers never sent (ahead of the newest, or far behind it): no resend, no key frame
    before = len(handled)
    await sender._handle_rtcp_packet(
        RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[2200, 40000])
    )
    assert (asked, len(handled), link.nacks_never_sent) == ([1, 1], before, 2)
    # Across the wrap: a key frame asked when 65460 was the newest sent covers 65400 and
    # 65450, NACKed once the stream is at 65500…91
    link.keyframe_covers_through = 65460
    sender._RTCRtpSender__rtp_history = history(65500)
    await sender._handle_rtcp_packet(
        RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[65400, 65450])
    )
    assert (asked, link.nacks_superseded) == ([1, 1], 4)
    # That key frame went out long ago: the same gap asked for again is not covered by
    # it any more (a 16-bit number far back reads as newer half the time): a new one
    link.keyframe_covers_at -= 60.0
    await sender._handle_rtcp_packet(
        RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=1, media_ssrc=7, lost=[65400])
    )
    assert (asked, link.nacks_unservable) == ([1, 1, 1], 5)
