"""A viewer's resends have a budget (backend/media/resend_budget.py): bytes a second tied
to its layer's rate, each packet at most once a round trip, numbers never sent ignored;
and a real viewer flooding NACKs gets no more than that while another watches on."""

from __future__ import annotations

import asyncio
import contextlib
import math
from typing import Any

from aiortc import RTCPeerConnection, RTCSessionDescription
from aiortc.mediastreams import MediaStreamError
from hypothesis import given
from hypothesis import strategies as st

from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from telerobot.server.media.resend_budget import (
    FLOOR_BPS,
    REMEMBERED,
    ResendBudget,
)
from telerobot.server.media.viewer_link import KEYFRAME_AGAIN_S, newest_sent
from tests.support.video import SMALL, camera


def test_a_second_of_budget_is_a_share_of_the_layer_s_rate_refilled_over_time() -> None:
    budget = ResendBudget(lambda: 2_000_000, share=0.5, burst_s=0.5)
    assert budget.bytes_per_s() == 125_000
    sent = sum(budget.allow(i, 1000, 0.1, 0.0) for i in range(200))
    assert sent == 62  # half a second's budget at once (62.5 packets of 1000 bytes)
    assert budget.counts.over_budget == 138
    assert budget.allow(1000, 1000, 0.1, 0.001) is False  # 125 bytes back: not enough
    assert budget.allow(1001, 1000, 0.1, 0.01) is True  # 1250 bytes back


def test_a_packet_is_resent_at_most_once_a_round_trip() -> None:
    budget = ResendBudget(lambda: 2_000_000)
    assert budget.allow(7, 1000, 0.2, 10.0)
    assert not budget.allow(7, 1000, 0.2, 10.1)  # asked again within the round trip
    assert budget.counts.too_soon == 1
    assert budget.allow(7, 1000, 0.2, 10.21)
    assert budget.allow(("fec", 7), 20, 0.2, 10.21)  # an FEC number is another packet


def test_an_unknown_rate_has_a_floor_and_the_table_of_resends_a_limit() -> None:
    budget = ResendBudget(lambda: None, share=1.0, burst_s=1000.0)
    assert budget.bytes_per_s() == FLOOR_BPS / 8
    for i in range(REMEMBERED + 500):
        assert budget.allow(i, 1, None, 0.0)
    assert len(budget._last) == REMEMBERED


@given(
    asks=st.lists(
        st.tuples(st.integers(0, 300), st.integers(1, 1500), st.floats(0.0, 0.05)),
        max_size=400,
    ),
    rate=st.integers(0, 20_000_000),
)
def test_whatever_is_asked_the_bytes_resent_stay_within_the_budget(
    asks: list[tuple[int, int, float]], rate: int
) -> None:
    budget = ResendBudget(lambda: rate)
    now = 0.0
    for seq, size, dt in asks:
        now += dt
        budget.allow(seq, size, 0.05, now)
    per_s = budget.bytes_per_s()
    assert budget.counts.bytes_resent <= per_s * budget.burst_s + per_s * now + 1e-6


# ---------------------------------------------------------------- real viewers
async def _viewer(pipeline: VideoPipeline) -> tuple[RTCPeerConnection, Any, Any]:
    pc = RTCPeerConnection()
    transceiver = pc.addTransceiver("video", direction="recvonly")
    got: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", got.put_nowait)
    await pc.setLocalDescription(await pc.createOffer())
    answer = await pipeline.answer(pc.localDescription.sdp, "offer")
    await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
    track = await asyncio.wait_for(got.get(), 10)
    await asyncio.wait_for(track.recv(), 10)
    return pc, transceiver.receiver, track


async def test_a_viewer_flooding_nacks_gets_its_budget_and_the_other_watches_on() -> None:
    """One viewer asks 200 times a second for the 128 newest packets, and for numbers
    never sent: it is resent no more than its budget, key frames are forced for it
    seldom, and the other viewer keeps receiving frames. (How many frames a second the other
    keeps is bench.abuse's nack_flood.)"""
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=2_000_000, fec="off"))
    pipeline.start()
    pcs = []
    try:
        flooder_pc, flooder, _ = await _viewer(pipeline)
        pcs.append(flooder_pc)
        watcher_pc, _, watched = await _viewer(pipeline)
        pcs.append(watcher_pc)
        peer = next(iter(pipeline.peers.values()))  # the flooder's, made first
        sender = peer.pc.getTransceivers()[0].sender
        keyframes = pipeline.stats()["keyframes_forced"]
        frames = 0

        async def watch() -> None:
            nonlocal frames
            with contextlib.suppress(MediaStreamError):
                while True:
                    await watched.recv()
                    frames += 1

        watching = asyncio.create_task(watch())
        seconds, t0 = 2.0, asyncio.get_running_loop().time()
        while asyncio.get_running_loop().time() - t0 < seconds:
            newest = newest_sent(sender._RTCRtpSender__rtp_history)
            assert newest is not None
            lost = sorted((newest - i) % 65536 for i in range(128))
            await flooder._send_rtcp_nack(sender._ssrc, lost)
            await flooder._send_rtcp_nack(
                sender._ssrc, sorted((newest + 5000 + i) % 65536 for i in range(128))
            )
            await asyncio.sleep(0.005)
        watching.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watching
        budget = peer.link.budget
        assert budget is not None
        elapsed = asyncio.get_running_loop().time() - t0
        per_s = budget.bytes_per_s()
        assert budget.counts.over_budget > 0  # it asked for more…
        # …and got no more than its budget (the rate may have moved during the run)
        assert budget.counts.bytes_resent <= 1.5 * per_s * (budget.burst_s + elapsed)
        assert peer.link.nacks_never_sent > 0
        # (its NACKs of the oldest packets kept, gone by the time they come, ask for a
        # key frame every KEYFRAME_AGAIN_S at most; those of numbers never sent, none)
        forced = pipeline.stats()["keyframes_forced"] - keyframes
        assert forced <= math.ceil(elapsed / KEYFRAME_AGAIN_S), forced
        assert frames > 0
    finally:
        for pc in pcs:
            await pc.close()
        await pipeline.close()
