"""bench.wan's aiortc viewer (its receiver: harness/wan_receiver.py) goes on past a gap
as libwebrtc does: a key frame received after it is decoded at once; after the NACKs
had their chance it asks for one if none has come, again every 0.2 s while none comes
(the server sends key frames only when asked). An injected clock; a give-up of 0 s."""

from __future__ import annotations

from aiortc.rtp import RtpPacket

from harness.wan_receiver import keyframe_skipping_buffer


def packet(seq: int, timestamp: int, key: bool = False) -> RtpPacket:
    p = RtpPacket(sequence_number=seq, timestamp=timestamp)
    p._data = (b"\x00\x00\x00\x01\x67" if key else b"\x00\x00\x00\x01\x41") + b"."  # type: ignore[attr-defined]
    return p


def test_a_gap_is_skipped_to_the_next_key_frame_asked_for_until_it_comes() -> None:
    now = [0.0]
    buffer = keyframe_skipping_buffer(0.0, reask_s=0.2, clock=lambda: now[0])
    for seq, ts in [(0, 1), (1, 1), (2, 2), (3, 2)]:  # frame 1 comes out, frame 2 waits
        buffer.add(packet(seq, ts, key=seq == 0))
    asks = [buffer.add(packet(seq, 3))[0] for seq in (6, 7, 8)]  # 4 and 5 lost for good
    assert asks == [False, True, False]  # the gap noticed, then one key frame asked for
    now[0] = 0.19
    assert not buffer.add(packet(12, 5))[0]
    now[0] = 0.2  # that request was lost, or its answer: ask again
    assert buffer.add(packet(13, 5))[0]
    _, frame = buffer.add(packet(9, 4, key=True))
    assert buffer.skips == 1 and frame is None  # skipped to the key frame's start
    _, frame = buffer.add(packet(10, 5))
    assert frame is not None and frame.timestamp == 4  # the key frame, whole
    assert buffer.add(packet(11, 6))[1].timestamp == 5  # and on from there


def test_a_gap_filled_in_time_is_not_skipped() -> None:
    buffer = keyframe_skipping_buffer(60.0)
    for seq, ts in [(0, 1), (1, 1), (3, 2), (4, 3)]:
        buffer.add(packet(seq, ts, key=seq == 0))
    _, frame = buffer.add(packet(2, 1))  # the retransmission: frame 1 complete
    assert frame is not None and frame.timestamp == 1 and buffer.skips == 0


def test_a_key_frame_after_a_gap_is_taken_at_once() -> None:
    buffer = keyframe_skipping_buffer(60.0)  # the NACKs would have a minute
    for seq, ts in [(0, 1), (1, 1), (2, 2)]:
        buffer.add(packet(seq, ts, key=seq == 0))
    buffer.add(packet(5, 4, key=True))  # 3 and 4 lost: frame 3 cannot be whole
    _, frame = buffer.add(packet(6, 5))
    assert frame is not None and frame.timestamp == 4 and buffer.skips == 1
