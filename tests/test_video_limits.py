"""The media worker's limits, in-process with an injected clock (no sleeps): peers
that never connect expire, the number of peers is capped, keyframe requests are
shared and rate-limited, and a peer is closed or used only with its own secret."""

from __future__ import annotations

import asyncio

import pytest
from aiortc import RTCPeerConnection, RTCSessionDescription

from telerobot.drivers.clock import ManualClock
from telerobot.server.media.fanout import KEYFRAME_MIN_INTERVAL_S, TRACK_QUEUE, Broadcaster
from telerobot.server.media.pipeline import (
    PENDING_EXPIRY_S,
    NotYourPeer,
    VideoPipeline,
    VideoSettings,
    ViewerLimitReached,
)
from telerobot.server.services import Alignments
from tests.support.video import SMALL, Counter, camera, frame


# ---------------------------------------------------------------- keyframes
async def test_a_track_whose_peer_never_connects_forces_no_keyframe_and_queues_nothing() -> None:
    forced = Counter()
    b = Broadcaster(forced, ManualClock().now)
    tracks = [b.new_track() for _ in range(300)]  # 300 dangling server offers
    for i in range(3 * TRACK_QUEUE):
        b.publish(frame(keyframe=i % 4 == 0, seq=i))
    assert forced.n == 0  # before: one keyframe per new track, and one per queue overflow
    assert all(t.sent_frames == 0 and t.resyncs == 0 and not t.sending for t in tracks)
    assert b.sending == 0 and b.viewers == 300


async def test_many_keyframe_requests_within_the_interval_force_one_keyframe() -> None:
    clock = ManualClock()
    forced = Counter()
    b = Broadcaster(forced, clock.now)
    tracks = [b.new_track() for _ in range(5)]
    for t in tracks:
        t.start_sending()  # five peers connect at once: each asks for a keyframe
    for _ in range(50):
        tracks[0].keyframe_requested()  # and a decoder sends PLI after PLI
    assert forced.n == 1
    b.publish(frame(keyframe=True))
    assert all(t._queue for t in tracks)  # one keyframe answered all five
    # Asked again within the interval: deferred, not forgotten…
    tracks[1].keyframe_requested()
    await clock.advance(KEYFRAME_MIN_INTERVAL_S / 2)
    b.publish(frame(keyframe=False))
    assert forced.n == 1
    await clock.advance(KEYFRAME_MIN_INTERVAL_S / 2)
    b.publish(frame(keyframe=False))
    assert forced.n == 2  # …it goes out once the interval has passed
    b.publish(frame(keyframe=True))
    await clock.advance(10 * KEYFRAME_MIN_INTERVAL_S)
    b.publish(frame(keyframe=False))
    assert forced.n == 2  # answered: nobody waits, nothing more is forced


async def test_the_encoders_own_keyframe_answers_a_deferred_request() -> None:
    clock = ManualClock()
    forced = Counter()
    b = Broadcaster(forced, clock.now)
    t = b.new_track()
    t.start_sending()
    assert forced.n == 1
    b.publish(frame(keyframe=True))
    t.keyframe_requested()  # deferred (within the interval)
    b.publish(frame(keyframe=True))  # the periodic keyframe comes first
    await clock.advance(2 * KEYFRAME_MIN_INTERVAL_S)
    b.publish(frame(keyframe=False))
    assert forced.n == 1


# ---------------------------------------------------------------- peers: expiry and caps
async def test_peers_that_never_connect_expire_on_the_injected_clock() -> None:
    clock = ManualClock()
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=1_000_000), clock=clock)
    pipeline.start()
    try:
        first = (await pipeline.offer())["peer_id"]
        await clock.advance(PENDING_EXPIRY_S / 2)
        second = (await pipeline.offer())["peer_id"]
        assert set(pipeline.peers) == {first, second} and pipeline.pending == 2
        await clock.advance(PENDING_EXPIRY_S / 2 + 1.5)  # past the first's expiry only
        assert set(pipeline.peers) == {second}
        await clock.advance(PENDING_EXPIRY_S / 2)
        assert pipeline.peers == {} and pipeline.viewers == 0  # their tracks are gone too
        assert pipeline.stats()["keyframes_forced"] == 0 and pipeline.encoding.frames_encoded == 0
    finally:
        await pipeline.close()


async def test_pending_peers_are_capped_and_expiry_makes_room() -> None:
    clock = ManualClock()
    pipeline = VideoPipeline(camera(**SMALL), clock=clock, max_pending=2)  # not started
    await pipeline.offer()
    await pipeline.offer()
    with pytest.raises(ViewerLimitReached, match="2 viewers are connecting right now"):
        await pipeline.offer()
    with pytest.raises(ViewerLimitReached, match="connecting"):
        await pipeline.answer(await _offer_sdp(), "offer")
    assert len(pipeline.peers) == 2  # refused before any peer was made
    await clock.advance(PENDING_EXPIRY_S)
    await pipeline.offer()  # the two expired: room again
    assert len(pipeline.peers) == 1
    await pipeline.close()


async def test_viewers_in_all_are_capped() -> None:
    pipeline = VideoPipeline(camera(**SMALL), clock=ManualClock(), max_viewers=3, max_pending=3)
    ids = [(await pipeline.offer())["peer_id"] for _ in range(3)]
    with pytest.raises(ViewerLimitReached, match="all 3 viewer places are taken"):
        await pipeline.offer()
    await pipeline.close_peer(ids[0])
    await pipeline.offer()
    assert len(pipeline.peers) == 3
    await pipeline.close()


async def _offer_sdp() -> str:
    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    await pc.setLocalDescription(await pc.createOffer())
    sdp: str = pc.localDescription.sdp
    await pc.close()
    return sdp


async def test_a_connected_viewer_never_expires_and_asks_for_its_keyframe_on_connecting() -> None:
    clock = ManualClock()
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=1_000_000), clock=clock)
    pipeline.start()
    pc = RTCPeerConnection()
    try:
        dangling = await pipeline.offer()  # never answered
        assert pipeline.stats()["keyframes_forced"] == 0
        pc.addTransceiver("video", direction="recvonly")
        tracks: asyncio.Queue[object] = asyncio.Queue()
        pc.on("track", tracks.put_nowait)
        await pc.setLocalDescription(await pc.createOffer())
        answer = await pipeline.answer(pc.localDescription.sdp, "offer")
        await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
        track = await asyncio.wait_for(tracks.get(), 10)
        await asyncio.wait_for(track.recv(), 10)  # type: ignore[attr-defined]
        assert pipeline.stats()["keyframes_forced"] >= 1  # asked once it was sending
        await clock.advance(6 * PENDING_EXPIRY_S)
        assert set(pipeline.peers) == {answer["peer_id"]}  # the dangling one expired
        assert dangling["peer_id"] not in pipeline.peers
        await asyncio.wait_for(track.recv(), 10)  # type: ignore[attr-defined]  # still watching
    finally:
        await pc.close()
        await pipeline.close()


# ---------------------------------------------------------------- peers: secrets
async def test_only_the_peers_own_secret_closes_answers_or_claims_it() -> None:
    pipeline = VideoPipeline(camera(**SMALL), clock=ManualClock())
    mine = await pipeline.offer()
    pid, secret = mine["peer_id"], mine["peer_secret"]
    assert len(secret) >= 20
    for wrong in (None, "", "x" * len(secret), secret[:-1], "é"):
        with pytest.raises(NotYourPeer):
            await pipeline.close_own_peer(pid, wrong)
        with pytest.raises(NotYourPeer):
            await pipeline.accept(pid, "v=0", "answer", wrong)
        with pytest.raises(NotYourPeer):
            pipeline.claim_viewer(pid, wrong, "alice")
    assert pid in pipeline.peers
    pipeline.claim_viewer(pid, secret, "alice")
    pipeline.claim_viewer(pid, secret, "alice")
    with pytest.raises(NotYourPeer, match="viewer 'alice' only"):
        pipeline.claim_viewer(pid, secret, "bob")  # one viewer name per peer
    with pytest.raises(NotYourPeer, match="no live peer"):
        pipeline.claim_viewer("gone", secret, "alice")
    await pipeline.close_own_peer("gone", None)  # a gone peer: nothing to do, no error
    await pipeline.close_own_peer(pid, secret)
    assert pipeline.peers == {}
    await pipeline.close()


async def test_the_stats_name_peers_only_when_asked() -> None:
    pipeline = VideoPipeline(camera(**SMALL), clock=ManualClock())
    pid = (await pipeline.offer())["peer_id"]
    public = pipeline.stats()
    assert len(public["viewers"]) == 1 and pid not in repr(public)
    assert public["viewer_count"] == 1 and public["pending"] == 1
    assert pipeline.stats(peer_ids=True)["viewers"][0]["peer_id"] == pid
    await pipeline.close()


def test_saved_alignments_are_capped_newest_kept() -> None:
    saved = Alignments(limit=3)
    for i in range(10):
        saved.remember(f"viewer-{i}", (i, 0))
    assert len(saved) == 3 and saved.get("viewer-6") is None and saved.get("viewer-7") == (7, 0)
    saved.remember("viewer-7", (70, 0))  # rewritten: newest again
    saved.remember("viewer-10", (10, 0))
    assert saved.get("viewer-8") is None  # the oldest written went
    assert saved.get("viewer-7") == (70, 0) and saved.get("viewer-9") == (9, 0)
