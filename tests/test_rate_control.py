"""The operator's own video stream (backend/media/rate_control.py): the rate's rules on
made-up receiver reports, an invariant over generated ones (Hypothesis), libx264
taking a new bitrate without a new encoder, and a real aiortc operator's viewer moved
to an encoder of its own whose size follows its rate while a watcher keeps the shared
layer."""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telerobot.drivers.base import StereoFrame
from telerobot.server.media.encoder import H264Encoder
from telerobot.server.media.layers import low_size
from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from telerobot.server.media.rate_control import (
    DECREASE,
    INCREASE,
    MIN_BPS,
    RESEND_SHARE,
    SHARE_AGAIN_S,
    START_BPS,
    STARTUP_INCREASE,
    RateControl,
)
from tests.support.video import SMALL, camera, frames_of, viewer_of
from tests.test_layers import Link

MAX = 2_000_000
FULL_PIXELS, LOW_PIXELS = 2 * 1280 * 720, 2 * 640 * 360  # (each needs 1.66, 0.41 Mbit/s)


def control() -> RateControl:
    """One already at the configured rate (past its start-up: the rules below)."""
    return RateControl(MAX, FULL_PIXELS, LOW_PIXELS, 30.0, start_bps=MAX)


def test_a_clean_link_keeps_the_configured_rate_and_a_stale_report_counts_once() -> None:
    rc, link = control(), Link()
    for t in range(10):
        rc.update(link.report(), None, float(t))
    assert rc.target_bps == MAX and rc.size == "full" and rc.every == 1
    link.report(lost=0.5)
    assert rc.update(link, None, 10.0)
    cut = rc.target_bps
    assert not rc.update(link, None, 11.0)  # the same report again: nothing
    assert rc.target_bps == cut == MAX * 0.75


def test_heavy_loss_cuts_random_loss_holds_and_a_clean_second_grows() -> None:
    rc, link = control(), Link()
    rc.update(link.report(lost=0.2), None, 0.0)
    assert rc.target_bps == MAX * 0.9 and "20% lost" in rc.why
    # 5 % lost (a lossy, uncongested link: FEC's to repair) holds the rate…
    for t in range(1, 5):
        rc.update(link.report(lost=0.05, rtt_s=0.19), None, float(t))
    assert rc.target_bps == MAX * 0.9
    # …NACK-counted loss too (a receiver report hides what was resent)
    rc.update(link.report(lost=0.0, rtt_s=0.19), 0.05, 5.0)
    assert rc.target_bps == MAX * 0.9
    rc.update(link.report(lost=0.0), 0.0, 6.0)
    assert rc.target_bps == min(MAX, MAX * 0.9 * INCREASE)


def test_a_queue_in_two_reports_in_a_row_cuts_the_rate() -> None:
    rc, link = control(), Link()
    rc.update(link.report(rtt_s=0.1), None, 0.0)
    rc.update(link.report(rtt_s=0.4), None, 1.0)  # one late report: a hiccup
    assert rc.target_bps == MAX
    rc.update(link.report(rtt_s=0.45), None, 2.0)
    assert rc.target_bps == MAX * DECREASE and "queue" in rc.why


def test_the_receivers_estimate_leads_the_rate_down_only_once_it_has_fallen() -> None:
    rc, link = control(), Link()
    # Chromium's estimate starts low and climbs: no reason to cut
    for t, bps in enumerate((70_000, 120_000, 200_000)):
        rc.update(link.report(bps=bps, rtt_s=0.3), None, float(t))
    assert rc.target_bps == MAX
    for t, bps in enumerate((1_500_000, 1_800_000), start=3):
        rc.update(link.report(bps=bps, rtt_s=0.3), None, float(t))
    # A fallen estimate with the round trip flat (a jittery link: `bad`'s Chromium said
    # 0.05 Mbit/s of 2) holds the rate…
    for t in range(5, 15):
        rc.update(link.report(bps=100_000, rtt_s=0.3 + 0.06 * (t % 2)), None, float(t))
    assert rc.target_bps == MAX
    # …and one with the round trip beginning to grow leads it down
    rc.update(link.report(bps=100_000, rtt_s=0.4), None, 15.0)  # fell once: not yet
    assert rc.target_bps == MAX
    rc.update(link.report(bps=100_000, rtt_s=0.4), None, 16.0)  # twice: a step toward it
    assert rc.target_bps == MAX * DECREASE and "estimate fell" in rc.why
    for t in range(17, 21):  # a step a report while the queue grows
        rc.update(link.report(bps=100_000, rtt_s=0.4 + 0.02 * (t - 16)), None, float(t))
    assert rc.target_bps == pytest.approx(MAX * DECREASE**5)


def test_with_congestion_seen_the_rate_goes_to_what_the_receiver_gets_at_once() -> None:
    # A new peer at the configured rate on a narrow link: 14 % lost, and the receiver
    # (still climbing from its start) says it gets 0.6 Mbit/s
    rc, link = RateControl(8_000_000, FULL_PIXELS, LOW_PIXELS, 30.0, start_bps=8_000_000), Link()
    rc.update(link.report(lost=0.14, bps=600_000), None, 0.0)
    assert rc.target_bps == 600_000 and "the receiver gets 0.60 Mbit/s" in rc.why
    assert rc.needs_own_stream(0.0)


def test_a_new_peer_carries_on_from_the_last_rate() -> None:
    rc = control()
    rc.carry_on_from(500_000, "the previous peer's")
    assert rc.target_bps == 500_000 and rc.size == "low" and rc.needs_own_stream(0.0)
    rc.carry_on_from(10**9, "the previous peer's")
    assert rc.target_bps == MAX and not rc.needs_own_stream(0.0)


def test_it_grows_by_the_second_however_often_the_receiver_reports() -> None:
    # Chromium's NACKs and REMBs each carry a receiver report: ten a second grow the
    # rate as one a second does.
    (often, a), (once, b) = (control(), Link()), (control(), Link())
    often.update(a.report(lost=0.8), None, 0.0)  # cut below the top
    once.update(b.report(lost=0.8), None, 0.0)
    for i in range(31):
        often.update(a.report(), None, 1.0 + i / 10)
    for t in (1.0, 2.0, 3.0, 4.0):
        once.update(b.report(), None, t)
    assert often.target_bps == pytest.approx(once.target_bps)
    assert once.target_bps == pytest.approx(MAX * 0.6 * INCREASE**4)


def test_one_cut_a_round_trip_however_often_the_receiver_reports() -> None:
    rc, link = control(), Link()
    for i in range(10):  # a second of reports losing 20 %, the round trip 0.3 s
        rc.update(link.report(lost=0.2, rtt_s=0.3), None, i / 10)
    assert rc.cuts == 2 and rc.target_bps == pytest.approx(MAX * 0.9 * 0.9)


def test_a_reports_loss_is_that_of_the_last_second() -> None:
    # Ten reports a second, each of a few packets: one lost of four (25 %) is a 2.5 %
    # second, no cut; a second of them losing 25 % each is.
    rc, link = control(), Link()
    for i in range(10):
        rc.update(link.report(lost=0.25 if i == 5 else 0.0), None, i / 10)
    assert rc.target_bps == MAX
    for i in range(10, 20):
        rc.update(link.report(lost=0.25), None, i / 10)
    assert rc.target_bps < MAX and "lost" in rc.why


def test_a_new_peer_starts_low_and_a_clean_link_brings_it_to_the_top_in_seconds() -> None:
    """Nothing is known of a new peer's link: it starts at START_BPS, not at the
    configured 8 Mbit/s (which, sent into `bad`'s 2 Mbit/s and its deep queue, held the
    forces and commands behind it); clean reports grow it fast until the top, where it
    shares the full layer at once (no second encode held on a LAN)."""
    rc, link = RateControl(8_000_000, FULL_PIXELS, LOW_PIXELS, 30.0), Link()
    assert rc.target_bps == START_BPS and rc.needs_own_stream(0.0)
    t = 0
    while rc.target_bps < 8_000_000:
        t += 1
        rc.update(link.report(rtt_s=0.01), None, float(t))
        assert "starting up" in rc.why or rc.target_bps == 8_000_000
    assert t <= 6 and not rc.needs_own_stream(float(t))
    # A small max: it starts there (nothing to grow into)
    small = RateControl(600_000, FULL_PIXELS, LOW_PIXELS, 30.0)
    assert small.target_bps == 600_000 and not small.needs_own_stream(0.0)


def test_the_start_up_ends_at_the_first_congestion_and_random_loss_holds_it() -> None:
    rc, link = RateControl(8_000_000, FULL_PIXELS, LOW_PIXELS, 30.0), Link()
    # `bad`'s 5 % random loss: neither growth nor a cut (FEC's to repair)
    for t in range(5):
        rc.update(link.report(lost=0.05, rtt_s=0.3), None, float(t))
    assert rc.target_bps == START_BPS
    rc.update(link.report(lost=0.2, rtt_s=0.3), None, 5.0)  # congestion: a cut
    assert rc.target_bps == START_BPS * 0.9 and not rc.starting
    rc.update(link.report(rtt_s=0.3), None, 6.0)
    assert rc.target_bps == pytest.approx(START_BPS * 0.9 * INCREASE)
    assert STARTUP_INCREASE > INCREASE


def test_size_and_frame_rate_follow_the_rate_with_a_margin_to_come_back() -> None:
    # 8 Mbit/s configured: the bits a pixel decide (at 2 Mbit/s the shares would)
    rc, link = RateControl(8_000_000, FULL_PIXELS, LOW_PIXELS, 30.0, start_bps=8_000_000), Link()
    clock = iter(range(1000))

    def until(done: Callable[[], bool], lost: float) -> None:
        for _ in range(100):
            rc.update(link.report(lost=lost), None, float(next(clock)))
            if done():
                return

    until(lambda: rc.size == "low", 0.3)
    # below 0.03 bits a pixel of the full size at 30 fps
    assert rc.target_bps < 0.03 * FULL_PIXELS * 30 and rc.every == 1
    until(lambda: rc.every == 2, 0.3)
    assert rc.size == "low" and rc.as_dict()["fps"] == 15.0
    assert rc.target_bps >= MIN_BPS
    # Back up only with UP_MARGIN to spare: the first clean second is not enough
    rc.update(link.report(), None, float(next(clock)))
    assert rc.every == 2
    until(lambda: rc.size == "full", 0.0)
    assert rc.every == 1 and rc.target_bps >= 1.3 * 0.03 * FULL_PIXELS * 30


def test_at_the_configured_rate_it_is_the_full_size_and_rate_whatever_the_pixels() -> None:
    # 2 Mbit/s for 2×1280×720 is below 0.03 bits a pixel: still full, as the shared layer
    rc, link = control(), Link()
    rc.update(link.report(), None, 0.0)
    assert rc.target_bps == MAX and rc.size == "full" and rc.every == 1


def test_fec_and_resends_come_out_of_the_rate() -> None:
    rc = control()
    assert rc.media_bps(0.0) == round(MAX * (1 - RESEND_SHARE))
    assert rc.media_bps(0.3) == round(MAX * (1 - RESEND_SHARE) / 1.3)


reports = st.lists(
    st.tuples(
        st.floats(0.0, 1.0),  # fraction lost
        st.one_of(st.none(), st.floats(0.0, 1.0)),  # NACK-counted loss
        st.one_of(st.none(), st.floats(0.001, 3.0)),  # round trip
        st.one_of(st.none(), st.integers(0, 20_000_000)),  # the receiver's estimate
        st.booleans(),  # a fresh report (else the last one seen again)
    ),
    max_size=60,
)


@settings(max_examples=200, deadline=None)
@given(reports, st.sampled_from((START_BPS, MAX)))
def test_the_rate_stays_in_bounds_and_never_grows_on_heavy_loss(seq: list, start: int) -> None:  # type: ignore[type-arg]
    """From a new peer's start (START_BPS) or from the top."""
    rc, link = RateControl(MAX, FULL_PIXELS, LOW_PIXELS, 30.0, start_bps=start), Link()
    for t, (lost, nacked, rtt, bps, fresh) in enumerate(seq):
        before = rc.target_bps
        if fresh:
            link.fraction_lost, link.rtt_s, link.estimated_bps = lost, rtt, bps
            link.reports += 1
        rc.update(link, nacked, float(t))
        assert MIN_BPS <= rc.target_bps <= MAX
        if not fresh:
            assert rc.target_bps == before
        elif max(lost, nacked or 0.0) > 0.1:
            assert rc.target_bps <= before
        assert rc.size in ("full", "low") and rc.every in (1, 2)
        # below the configured rate it always has its own stream; at it, full size and rate
        assert rc.needs_own_stream(float(t)) or rc.target_bps == MAX
        assert rc.target_bps < MAX or (rc.size, rc.every) == ("full", 1)
        assert MIN_BPS // 2 <= rc.media_bps(0.35) <= MAX


def test_libx264_takes_a_new_bitrate_without_a_new_encoder() -> None:
    enc = H264Encoder(640, 180, 30, 2_000_000)
    noise = np.random.default_rng(0).integers(0, 255, (180, 640, 3), dtype=np.uint8)

    def bits_per_s(frames: range) -> float:
        size = 0
        for i in frames:
            f = StereoFrame(i, float(Fraction(i, 30)), np.roll(noise, 7 * i, axis=1))
            size += sum(e.size for e in enc.encode(f))
        return size * 8 / (len(frames) / 30)

    before = bits_per_s(range(0, 60))
    enc.set_bitrate(400_000)
    after = bits_per_s(range(60, 120))
    assert after < before / 2, (before, after)
    enc.set_bitrate(10**9)  # never above what it was opened with (its VBV cap)
    assert enc._new_bitrate == 2_000_000


def a_second_later(rate: RateControl) -> None:
    """As if a second had passed since its last report (the pipeline's clock is real):
    it grows by a second's worth, and may cut again."""
    if rate.last_report_at is not None:
        rate.last_report_at -= 1.0
    rate.last_cut_at -= 1.0
    rate.window = deque(((t - 1.0, lost) for t, lost in rate.window), maxlen=rate.window.maxlen)


async def test_the_operators_viewer_gets_its_own_stream_and_its_size_follows_its_rate() -> None:
    cam = camera(**SMALL)
    pipeline = VideoPipeline(cam, VideoSettings(bitrate=1_000_000))
    pipeline.start()
    try:
        (po, to, ido), (pw, tw, idw) = await asyncio.gather(
            viewer_of(pipeline, "auto", operator=True), viewer_of(pipeline, "auto")
        )
        await asyncio.gather(frames_of(to, 3, cam.width), frames_of(tw, 3, cam.width))
        pipeline.adapt_layers()
        operator = pipeline.peers[ido]
        assert operator.rate is not None and pipeline.peers[idw].rate is None
        # A clean link: the operator shares the full layer (the same stream, one encode)
        link = operator.link
        for _ in range(3):
            link.fraction_lost, link.reports = 0.0, link.reports + 1
            pipeline.adapt_operator_rate()
        assert set(pipeline.encoding.encoders) == {("H264", "full")}
        rate = next(v for v in pipeline.stats(peer_ids=True)["viewers"] if v["peer_id"] == ido)
        assert rate["layer"] == "full" and rate["rate"]["kbps"] == 1000, rate
        # Its link loses half its packets, report after report: it gets its own encoder,
        # whose rate falls to the low size (a new encoder, a key frame) while the
        # watcher's picture stays full.
        for _ in range(100):
            link.fraction_lost, link.reports = 0.5, link.reports + 1
            a_second_later(operator.rate)
            pipeline.adapt_operator_rate()
            if operator.rate.size == "low":
                break
        assert operator.rate.target_bps < 1_000_000
        seen = await frames_of(to, 30, cam.width)
        assert seen[-1][:2] == low_size(cam.width, cam.height)
        stats = pipeline.stats(peer_ids=True)
        layers = {v["peer_id"]: v["layer"] for v in stats["viewers"]}
        assert layers == {ido: "operator", idw: "full"}
        assert set(pipeline.encoding.encoders) == {("H264", "full"), ("H264", "operator")}
        watcher = await frames_of(tw, 5, cam.width)
        assert {(w, h) for w, h, _ in watcher} == {(cam.width, cam.height)}
        # Clean again up to the configured rate, and held there: shared again
        for _ in range(100):
            link.fraction_lost, link.reports = 0.0, link.reports + 1
            a_second_later(operator.rate)
            pipeline.adapt_operator_rate()
            if operator.rate.at_max_since is not None:
                break
        operator.rate.at_max_since -= SHARE_AGAIN_S  # (as if it had held that long)
        link.reports += 1
        pipeline.adapt_operator_rate()
        seen = await frames_of(to, 30, cam.width)
        assert seen[-1][:2] == (cam.width, cam.height)
        assert pipeline._layer_of(operator) == "full"
        # The operator's viewer leaves: the watcher is untouched, the stream not encoded
        await po.close()
        await pipeline.close_peer(ido)
        assert pipeline.encoding.operator_rate is None
        await frames_of(tw, 3, cam.width)
        await pw.close()
    finally:
        await pipeline.close()


async def test_with_the_setting_off_the_operator_shares_the_layers() -> None:
    pipeline = VideoPipeline(
        camera(**SMALL), VideoSettings(bitrate=1_000_000, operator_encoder=False)
    )
    pipeline.start()
    try:
        pc, track, pid = await viewer_of(pipeline, "auto", operator=True)
        await frames_of(track, 3, SMALL["width"])
        pipeline.adapt_layers()
        assert pipeline.peers[pid].rate is None
        assert set(pipeline.encoding.encoders) == {("H264", "full")}
        await pc.close()
    finally:
        await pipeline.close()


async def test_the_operators_next_peer_starts_from_the_last_ones_rate() -> None:
    """A page re-negotiates its video after a stall: its new peer, on the same link,
    starts from the rate the last one had come down to, not from the configured one."""
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=1_000_000))
    pipeline.start()
    try:
        pc, track, first = await viewer_of(pipeline, operator=True)
        await frames_of(track, 2, SMALL["width"])
        pipeline.adapt_layers()
        link = pipeline.peers[first].link
        link.fraction_lost, link.reports = 0.5, link.reports + 1
        pipeline.adapt_operator_rate()
        came_down = pipeline.peers[first].rate.target_bps  # type: ignore[union-attr]
        assert came_down < 1_000_000
        await pc.close()
        await pipeline.close_peer(first)
        pc, track, second = await viewer_of(pipeline, operator=True)
        await frames_of(track, 2, SMALL["width"])
        pipeline.adapt_layers()
        assert pipeline.peers[second].rate.target_bps == came_down  # type: ignore[union-attr]
        await pc.close()
    finally:
        await pipeline.close()


def test_a_flood_of_reports_keeps_at_most_a_hundred_in_the_loss_window() -> None:
    # A receiver's reports are a client's to send: a thousand in a second are held to
    # the newest hundred, and the rate still follows their loss.
    rc, link = control(), Link()
    for i in range(1000):
        rc.update(link.report(lost=0.5 if i >= 900 else 0.0), None, i / 1000)
    assert len(rc.window) == 100 and all(lost == 0.5 for _, lost in rc.window)
    assert rc.target_bps < MAX and "lost" in rc.why
