"""Forward error correction for the video (backend/media/fec.py): the ULPFEC codec, the
sender in front of a viewer's transport (RED, FEC packets, the sequence numbers'
mapping for NACKs and resends), the protection that follows the loss, and a real
aiortc viewer that recovers the packets a lossy link took for good."""

from __future__ import annotations

import asyncio
import logging
import random
from types import SimpleNamespace
from typing import Any, ClassVar

import pytest
from aiortc import RTCPeerConnection, RTCSessionDescription
from aiortc.rtp import RTCP_RTPFB_NACK, RtcpRtpfbPacket

from harness import wan_receiver
from telerobot.server.media import fec, playout, viewer_link
from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from telerobot.server.media.viewer_link import Protection, ViewerLink, follow_link
from tests.support.video import SMALL, camera

MEDIA_PT, RED_PT, ULPFEC_PT = 102, 121, 122


def _rtp(seq: int, ts: int, payload: bytes, marker: bool = False, ext: bool = False) -> bytes:
    head = bytes([0x90 if ext else 0x80, (0x80 if marker else 0) | MEDIA_PT])
    head += (seq & 0xFFFF).to_bytes(2, "big") + ts.to_bytes(4, "big") + b"\x11\x22\x33\x44"
    if ext:  # one element (id 1, 1 byte) and padding to a word
        head += b"\xbe\xde\x00\x01" + bytes([0x10, 7, 0, 0])
    return head + payload


def _stream(n: int, first_seq: int = 65530, seed: int = 1) -> list[bytes]:
    """``n`` media packets, three to a frame, of any size, some with an extension."""
    rng = random.Random(seed)
    return [
        _rtp(first_seq + i, 1000 + 3000 * (i // 3), rng.randbytes(rng.randrange(1, 1200)),
             marker=i % 3 == 2, ext=i % 2 == 0)
        for i in range(n)
    ]  # fmt: skip


# ---------------------------------------------------------------- the codec
@pytest.mark.parametrize("count", [1, 2, 16, 17, 48], ids=lambda n: f"{n} packets")
def test_one_fec_packet_rebuilds_any_one_packet_it_covers(count: int) -> None:
    packets = _stream(count)  # sequence numbers wrap past 65535 on the way
    payload = fec.ulpfec_payload(packets)
    assert bool(payload[0] & 0x40) == (count > fec.SHORT_MASK)  # the long mask past 16
    parsed = fec.FecPacket.parse(payload, packets[0][8:12])
    assert parsed.protected == tuple(fec.seq_of(p) for p in packets)
    for lost in range(count):
        others = packets[:lost] + packets[lost + 1 :]
        assert fec.recover(parsed, others, fec.seq_of(packets[lost])) == packets[lost]


def test_fec_refuses_a_span_it_cannot_name() -> None:
    with pytest.raises(ValueError, match="within 48"):
        fec.ulpfec_payload(_stream(49))
    with pytest.raises(ValueError, match="at least one"):
        fec.ulpfec_payload([])


def test_red_carries_the_media_packet_unchanged() -> None:
    for packet in _stream(4):
        red = fec.red_wrap(packet, RED_PT)
        assert red[1] & 0x7F == RED_PT and red[1] & 0x80 == packet[1] & 0x80  # the marker kept
        assert len(red) == len(packet) + 1
        assert fec.red_unwrap(red) == packet


# ---------------------------------------------------------------- the sender
class Wire:
    """What a FecSender sends, and a receiver at the other end."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    async def __call__(self, data: bytes) -> None:
        self.sent.append(data)


async def test_no_loss_no_fec_the_packets_leave_as_they_came() -> None:
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.0)
    packets = _stream(30)
    for p in packets:
        await sender(p)
    assert wire.sent == packets  # byte for byte: a clean link's video does not change
    assert sender.counts.as_dict()["overhead"] == 0.0


async def test_with_protection_each_group_gets_fec_and_numbers_stay_in_order() -> None:
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.25)
    packets = _stream(24)
    for p in packets:
        await sender(p)
    seqs = [fec.seq_of(p) for p in wire.sent]
    assert seqs == [(65530 + i) & 0xFFFF for i in range(len(wire.sent))]  # no gap, no repeat
    kinds = ["fec" if fec.red_unwrap(p)[1] & 0x7F == ULPFEC_PT else "media" for p in wire.sent]
    assert kinds.count("media") == 24 and kinds.count("fec") == sender.counts.fec_packets > 0
    # Two frames of three (MIN_GROUP 4 reached at the second's end): 6 media, then FEC
    assert kinds[:8] == ["media"] * 6 + ["fec"] * 2
    assert 0 < sender.counts.as_dict()["overhead"] < 0.5


async def test_nacks_and_resends_are_mapped_between_aiortc_s_numbers_and_the_wire_s() -> None:
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.25)
    packets = _stream(12, first_seq=100)
    for p in packets:
        await sender(p)
    # On the wire: 100-105 media, 106-107 FEC, 108-113 media, 114-115 FEC
    media, fec_seqs = sender.nacked([101, 106, 109, 999])
    assert media == [101, 107] and fec_seqs == [106]  # 109 on the wire is aiortc's 107
    assert sender.to_sent(107) == 109
    # aiortc resends its 107: it leaves as the wire's 109, as plain media
    await sender(packets[7])
    assert fec.seq_of(wire.sent[-1]) == 109 and wire.sent[-1][1] & 0x7F == MEDIA_PT
    await sender.pad_fec(fec_seqs)  # the FEC packet's number filled with padding
    pad = wire.sent[-1]
    assert fec.seq_of(pad) == 106 and pad[0] & 0x20 and pad[1] & 0x7F == MEDIA_PT
    assert pad[4:12] == wire.sent[5][4:12] and pad[-1] == len(pad) - 12  # all padding
    assert sender.counts.fec_padded == 1


async def test_the_receiver_rebuilds_what_the_link_lost() -> None:
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.25)
    packets = _stream(48, first_seq=0)
    for p in packets:
        await sender(p)
    receiver = fec.FecReceiver(RED_PT, ULPFEC_PT)
    got: dict[int, bytes] = {}
    media_at = [i for i, p in enumerate(wire.sent) if fec.red_unwrap(p)[1] & 0x7F == MEDIA_PT]
    lost = set(media_at[1::5])  # one in five media packets: one per interleaved group
    for i, data in enumerate(wire.sent):
        if i in lost:
            continue
        for out in receiver.receive(data):
            assert out[1] & 0x7F == MEDIA_PT  # FEC reaches aiortc as (empty) media
            if len(out) > 12 + 8 or not (out[0] & 0x10):
                got.setdefault(fec.seq_of(out), out)
    by_seq = {fec.seq_of(p): p for p in wire.sent}
    for i in media_at:
        seq = fec.seq_of(wire.sent[i])
        assert got[seq] == fec.red_unwrap(by_seq[seq])
    assert receiver.counts.recovered == len(lost)


@pytest.mark.parametrize(
    ("loss", "on", "share"),
    [(None, False, 0.0), (0.0, False, 0.0), (0.003, False, 0.0), (0.003, True, 0.112),
     (0.02, False, 0.18), (0.2, True, fec.MAX_SHARE)],
    ids=["unknown", "clean", "below on", "above off (on)", "mobile", "most"],
)  # fmt: skip
def test_protection_follows_the_loss_with_a_margin_either_way(
    loss: float | None, on: bool, share: float
) -> None:
    assert fec.protection_share(loss, on) == pytest.approx(share)


async def test_a_nack_reaches_aiortc_in_its_own_numbers_and_counts_the_loss() -> None:
    handled: list[Any] = []
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.25)
    for p in _stream(12, first_seq=100):
        await sender(p)

    class Sender:
        _ssrc = 1
        # (what aiortc keeps to resend: the media sent, by its own numbers)
        _RTCRtpSender__rtp_history: ClassVar[dict[int, Any]] = {
            s % 128: SimpleNamespace(sequence_number=s, payload=bytes(100)) for s in range(90, 120)
        }

        async def _handle_rtcp_packet(self, packet: Any) -> None:
            handled.append(packet)

    link, repairs = ViewerLink(), []
    aiortc_sender: Any = Sender()
    follow_link(aiortc_sender, link, lambda: sender, lambda: repairs.append(1))
    nack = RtcpRtpfbPacket(fmt=RTCP_RTPFB_NACK, ssrc=2, media_ssrc=1, lost=[101, 106, 109])
    await aiortc_sender._handle_rtcp_packet(nack)
    await aiortc_sender._handle_rtcp_packet(nack)  # asked again: counted once
    assert handled[0].lost == [101, 107] and link.nacked == 2 and len(repairs) == 2
    assert sender.counts.fec_padded == 2  # the FEC packet 106, each time


# ---------------------------------------------------------------- a real viewer
class _PicturesLost(logging.Handler):
    """What a packet lost for good costs an aiortc viewer once it shows a picture:
    a frame its decoder refuses (logged by aiortc's receiver) or a gap its jitter
    buffer gives up on (it asks for a key frame). Either is a key frame asked for."""

    def __init__(self, receiver: Any) -> None:
        super().__init__(logging.WARNING)
        self.showing = False
        self.failed_decodes = 0
        self.gaps_skipped = 0
        buffer = receiver._RTCRtpReceiver__jitter_buffer
        add = buffer.add

        def counted(packet: Any) -> Any:
            pli, frame = add(packet)
            self.gaps_skipped += bool(pli and self.showing)
            return pli, frame

        buffer.add = counted

    def emit(self, record: logging.LogRecord) -> None:
        self.failed_decodes += self.showing and "failed to decode" in record.getMessage()

    @property
    def count(self) -> int:
        return self.failed_decodes + self.gaps_skipped


async def _watch(pipeline: VideoPipeline, frames: int) -> tuple[wan_receiver.Received, int]:
    """An aiortc viewer with the FEC receiver: decodes ``frames`` frames after its
    first; how many pictures it lost meanwhile (``_PicturesLost``). Not the server's
    count of forced key frames: a viewer whose first packet was lost (``drop_every``
    counts sequence numbers from a random start) or came before its keys starts in
    the middle of a frame, fails to decode until a key frame, and asks again for one
    while it works through that backlog; the server grants the last ask up to
    KEYFRAME_MIN_INTERVAL_S later, after the first picture on a busy machine."""
    wan_receiver.allow()
    pc = RTCPeerConnection()
    transceiver = pc.addTransceiver("video", direction="recvonly")
    lost = _PicturesLost(transceiver.receiver)
    aiortc_log = logging.getLogger("aiortc.rtcrtpreceiver")
    aiortc_log.addHandler(lost)
    got: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", got.put_nowait)
    await pc.setLocalDescription(await pc.createOffer())
    assert "red/90000" in pc.localDescription.sdp and "ulpfec/90000" in pc.localDescription.sdp
    answer = await pipeline.answer(pc.localDescription.sdp, "offer")
    assert "red/90000" in answer["sdp"] and "ulpfec/90000" in answer["sdp"]
    received = wan_receiver.attach(transceiver.receiver.transport)
    await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
    try:
        track = await asyncio.wait_for(got.get(), 10)
        # (aiortc decodes in order: every frame before the first picture, the failed
        # ones of a start mid-frame among them, has been tried by now)
        await asyncio.wait_for(track.recv(), 10)
        lost.showing = True
        for _ in range(frames):
            await asyncio.wait_for(track.recv(), 10)
        return received, lost.count
    finally:
        aiortc_log.removeHandler(lost)
        await pc.close()


async def test_a_viewer_decodes_through_lost_packets_that_only_fec_brings_back() -> None:
    # Every 25th packet lost for good (its resends too): without FEC each would cost a
    # key frame; with it, each is rebuilt and the picture goes on. (An FEC packet
    # covers packets at most 24 apart: two of these are never in the same one.)
    settings = VideoSettings(bitrate=2_000_000, fec="on", drop_every=25)
    pipeline = VideoPipeline(camera(**SMALL), settings)
    pipeline.start()
    try:
        received, pictures_lost = await _watch(pipeline, 60)
        viewer = pipeline.stats()["viewers"][0]
    finally:
        await pipeline.close()
    assert viewer["fec"]["dropped_on_purpose"] > 0 and viewer["fec"]["fec_packets"] > 0
    assert received.fec.counts.recovered > 0
    assert pictures_lost == 0


async def test_on_a_clean_link_auto_sends_no_fec() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=2_000_000))
    pipeline.start()
    try:
        received, _ = await _watch(pipeline, 10)
        viewer = pipeline.stats()["viewers"][0]
    finally:
        await pipeline.close()
    assert viewer["fec"]["fec_packets"] == 0 and viewer["fec"]["share"] == 0.0
    assert received.fec.counts.red == 0 and viewer["playout_delay_ms"] == 0


def test_a_bad_fec_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="fec must be one of"):
        VideoPipeline(camera(**SMALL), VideoSettings(fec="sometimes"))


async def test_a_nack_s_round_trip_is_read_from_the_packet_that_showed_the_gap() -> None:
    now = [0.0]
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.0, clock=lambda: now[0])
    for i, p in enumerate(_stream(6, first_seq=10)):
        now[0] = 0.01 * i
        await sender(p)
    now[0] = 0.3
    # 12 lost: the receiver saw the gap when 13 came (sent at 0.03)
    assert sender.feedback_s([12]) == pytest.approx(0.27)
    assert sender.feedback_s([12]) is None  # asked again: says nothing of the link
    assert sender.feedback_s([15]) is None  # nothing sent after it yet


def test_the_link_s_queue_is_the_nacks_round_trip_above_their_floor() -> None:
    link = ViewerLink()
    assert link.queued_s(0.0) is None and link.repair_s(0.0) is None
    link.rtt_s = 0.25
    assert link.repair_s(0.0) == 0.25  # the reports' round trip until a NACK says more
    for t, rtt in enumerate([0.26, 0.25, 0.27]):
        link.nack_rtt(rtt, float(t))
    # (the floor, 0.25 at 1 s, has drifted up 10 ms by 2 s: a link's delay may grow)
    assert link.queued_s(2.0) == pytest.approx(0.0)
    for t in range(3, 20):
        link.nack_rtt(0.6, float(t))  # a queue builds: 0.35 s more
    assert link.queued_s(19.0) == pytest.approx(0.6 - (0.26 + 0.01 * 17))
    assert link.repair_s(19.0) == pytest.approx(0.6)
    # A clean link sends no NACK: after a while they say nothing of it any more
    assert link.queued_s(19.0 + 11) is None and link.repair_s(30.0) == 0.25


def test_protection_follows_the_nacks_loss_and_pauses_while_the_link_queues() -> None:
    """The per-viewer policy alone, on a made-up clock: a second at a time."""
    link, protection = ViewerLink(), Protection()
    sent = 0
    now = 1000.0

    def second(packets: int, nacked: int, mode: str = "auto") -> float:
        nonlocal sent, now
        sent += packets
        link.nacked += nacked
        now += 1.0
        protection.judge(sent, link, mode, now)
        return protection.fec_share

    assert second(100, 0) == 0.0  # clean: no FEC
    assert second(100, 2) == 0.0  # two seconds known: not yet (FEC_AFTER_S)
    # the packets NACKed over those sent, the window's: 4 of 300
    assert second(100, 2) == pytest.approx(fec.protection_share(4 / 300, False))
    # A cut (every packet of a second NACKed) is left out: FEC cannot help it
    assert second(100, 100) == pytest.approx(fec.protection_share(4 / 300, True))
    assert protection.loss == pytest.approx(4 / 300)
    for t in range(4):  # the NACKs come back later and later: a queue on the link
        link.nack_rtt(0.25 + 0.1 * t, now + t - 4)
    # Right after a cut that is its backlog (resends, the forces held up): not judged
    assert second(100, 2) > 0.0 and second(100, 2) > 0.0 and protection.fec_paused == 0
    protection.cut_at = -1e9  # (the cut long past)
    assert second(100, 2) > 0.0  # one second of it could be a cut's backlog…
    assert second(100, 2) == 0.0 and protection.fec_paused == 1  # …two are a queue
    for _ in range(16):  # the queue drains once the FEC's bytes stop…
        link.nack_rtt(0.25, now)
    assert link.queued_s(now) == pytest.approx(0.0, abs=0.05)
    assert second(100, 2) == 0.0  # …but protection stays paused FEC_PAUSE_S
    now += viewer_link.FEC_PAUSE_S
    assert second(100, 2) > 0.0
    assert second(0, 0) > 0.0  # nothing sent this second: nothing judged
    assert second(100, 0, mode="on") == fec.MAX_SHARE  # "on": the most, whatever the loss


def test_sparse_random_loss_turns_protection_on() -> None:
    """1 % random loss at ~90 packets a second: most seconds NACK nothing. The median of
    each second's share said 0 and FEC stayed off on bench.wan's `wan`; the window's
    packets NACKed over those sent say 1 %."""
    link, protection = ViewerLink(), Protection()
    sent, now = 0, 0.0
    for nacked in (0, 2, 0, 0, 3, 0, 2, 0, 0, 3):  # the last five seconds: 5 of 450
        sent, now = sent + 90, now + 1.0
        link.nacked += nacked
        protection.judge(sent, link, "auto", now)
    assert protection.loss == pytest.approx(5 / 450)
    assert protection.fec_share > 0.0


def test_the_pipeline_judges_each_connected_viewer_on_its_clock() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings())  # "auto"; not started
    counts = fec.FecCounts()
    peer: Any = SimpleNamespace(
        connected=True, link=ViewerLink(), fec=SimpleNamespace(counts=counts),
        protection=Protection(), rate=None,
    )  # fmt: skip
    idle: Any = SimpleNamespace(connected=False, protection=Protection())
    pipeline.peers.update({"p": peer, "idle": idle})
    for _ in range(4):
        counts.media_packets += 100
        peer.link.nacked += 2
        pipeline.adapt_protection()
    assert peer.protection.fec_share == pytest.approx(fec.protection_share(0.02, False))
    assert peer.protection.loss == pytest.approx(0.02)
    assert idle.protection.counted == (0, 0)  # a viewer still connecting: not judged


async def test_a_frame_longer_than_a_group_gets_its_fec_after_its_last_packet() -> None:
    # A key frame of the full layer is 60-85 packets. An FEC packet numbered inside it
    # made Chromium drop the frame (its H.264 frames are the numbers from one
    # timestamp's first packet to the marker).
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.25)
    frame = [_rtp(100 + i, 9000, bytes([i]) * 100, marker=i == 69) for i in range(70)]
    for p in frame:
        await sender(p)
    kinds = [fec.red_unwrap(p)[1] & 0x7F for p in wire.sent]
    assert kinds[:70] == [MEDIA_PT] * 70 and set(kinds[70:]) == {ULPFEC_PT}
    assert len(kinds) - 70 == sender.counts.fec_packets == 12 + 6  # 48 × 0.25, 22 × 0.25
    receiver = fec.FecReceiver(RED_PT, ULPFEC_PT)
    for i, data in enumerate(wire.sent):
        if i not in (3, 50):  # one lost in each group
            receiver.receive(data)
    assert receiver.counts.recovered == 2


async def test_what_a_viewer_s_nacks_can_grow_is_bounded() -> None:
    # A viewer (or anyone with a peer) may NACK any number it likes, as often as it likes
    wire = Wire()
    sender = fec.FecSender(wire, RED_PT, ULPFEC_PT, lambda: 0.25)
    for p in _stream(12, first_seq=0):
        await sender(p)
    link = ViewerLink()
    for start in range(0, 65536, 512):
        seqs = list(range(start, start + 512))
        sender.feedback_s(seqs)
        link.count_nacked(seqs)
        link.nack_rtt(0.1, float(start))
    assert len(sender._asked) == fec.SEQ_MAP_SIZE
    assert len(link.nacked_recent) == viewer_link.NACKED_KEPT and link.nacked == 65536
    assert len(link.nack_rtts) == viewer_link.NACK_RTTS_KEPT
    delay = playout.AdaptivePlayout()
    for i in range(1000):
        delay.repair(float(i) / 1000, 0.3)
    assert len(delay._needs) == playout.MAX_REPAIRS_KEPT
