"""The stereo video in the recording: the packets the fan-out gets, as they
are (no second encode), starting on a keyframe with SPS/PPS, through a bounded hand-over
that drops and counts rather than stall the encoder; the pipeline runs while recording
with nobody watching; what was logged decodes frame by frame from the first."""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any, cast

import av
import numpy as np
import pytest
from av.video.codeccontext import VideoCodecContext

from telerobot.drivers.base import ArmSnapshot
from telerobot.drivers.camera.sim import SimStereoCamera
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.media.encoder import EncodedFrame
from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
from telerobot.server.media.supervisor import MediaSupervisor
from telerobot.server.media.tap import PacketPipe, pack, unpack
from telerobot.server.recording.reader import read, summary
from telerobot.server.recording.video import (
    VIDEO_TOPIC,
    VideoTap,
    nal_types,
    remux_mp4,
    starts_decodable,
)
from telerobot.server.recording.writer import McapFile
from telerobot.server.settings import Settings

W, H = 320, 180


def _frame(keyframe: bool, seq: int = 0, data: bytes = b"\x00\x00\x00\x01\x65xx") -> EncodedFrame:
    return EncodedFrame(data, keyframe, len(data), 1.0 + seq / 30, seq, 1.0)  # at 30 fps


def test_the_wire_format_round_trips() -> None:
    p = unpack(pack(True, 12.5, 7, 3, b"\x00\x00\x01\x67abc"))
    assert (p.keyframe, p.capture_time, p.seq, p.dropped, p.data) == (
        True,
        12.5,
        7,
        3,
        b"\x00\x00\x01\x67abc",
    )


def test_nal_types_and_a_decodable_start() -> None:
    au = b"\x00\x00\x00\x01\x67s\x00\x00\x00\x01\x68p\x00\x00\x01\x65i"
    assert nal_types(au) == [7, 8, 5]
    assert starts_decodable(au)
    assert not starts_decodable(b"\x00\x00\x00\x01\x65i")  # no SPS/PPS before it
    assert not starts_decodable(b"\x00\x00\x00\x01\x41p")  # not a keyframe


def test_the_hand_over_is_bounded_drops_counts_and_resumes_on_a_keyframe() -> None:
    release = threading.Event()
    sent: list[bytes] = []

    def slow_send(message: bytes) -> None:  # the server stopped reading
        release.wait(10)
        sent.append(message)

    asked: list[int] = []
    pipe = PacketPipe(slow_send, lambda: asked.append(1), limit=4)
    pipe.restart()
    pipe.push(_frame(False, 0))  # before the first keyframe: not handed over
    pipe.push(_frame(True, 1))  # the first; the thread takes it and blocks in send
    deadline = time.monotonic() + 5
    while pipe._queue:  # the thread holds it
        assert time.monotonic() < deadline
        time.sleep(0.001)
    for seq in range(2, 2 + 4 + 1):  # four fit, the fifth finds the queue full
        pipe.push(_frame(False, seq))
    # push never waited for the pipe: every push returned while the send still blocks.
    assert sent == [] and not release.is_set()
    assert pipe.dropped == 5 and asked == [1] and not pipe._queue
    pipe.push(_frame(False, 7))  # not a keyframe: still waiting for one
    pipe.push(_frame(True, 8))  # the asked-for keyframe: the stream resumes here
    release.set()
    deadline = time.monotonic() + 5
    while len(sent) < 2:
        assert time.monotonic() < deadline
        time.sleep(0.001)
    got = [unpack(m) for m in sent]
    assert [(p.seq, p.keyframe, p.dropped) for p in got] == [(1, True, 0), (8, True, 5)]
    pipe.close()


def test_a_recording_asks_for_a_keyframe_every_two_seconds_of_video() -> None:
    """The encoder makes none unless asked: a recording without them could only be
    played from its start."""
    asked: list[int] = []
    pipe = PacketPipe(lambda _: None, lambda: asked.append(seq), limit=1000)
    for recording in range(2):
        pipe.restart()
        asked.clear()
        pending = False
        start = recording * 1000
        for seq in range(start, start + 32 * 5):  # 5 s at 32 fps (exact in binary)
            key, pending = seq == start or pending, False  # asked: the next frame is one
            size = len(asked)
            pipe.push(EncodedFrame(b"", key, 0, seq / 32, seq, 1.0))
            pending = len(asked) > size
        # 64 frames (2 s) after each keyframe; a new recording counts from its own first
        assert asked == [start + 64, start + 129], recording
    pipe.close()


def _camera() -> SimStereoCamera:
    snap = ArmSnapshot(time.monotonic(), NAMED_POSES["qn"], np.zeros(6))
    return SimStereoCamera(
        default_workcell(width=W, height=H),
        lambda: snap,
        Puma560Kinematics(tool_transform(0.1)),
        fps=30,
    )


async def test_the_pipeline_encodes_for_the_tap_with_nobody_watching() -> None:
    pipeline = VideoPipeline(_camera(), VideoSettings(fps=30, keyframe_interval=10.0))
    pipeline.start()
    got: list[EncodedFrame] = []
    try:
        await asyncio.sleep(0.2)
        assert pipeline.encoding.frames_encoded == 0  # no viewer, no recording: nothing encoded
        pipeline.encoding.start_tap(got.append)
        deadline = time.monotonic() + 30
        while len(got) < 10:
            assert time.monotonic() < deadline, "the tap got no packets"
            await asyncio.sleep(0.05)
        pipeline.encoding.stop_tap()
        n = len(got)
        await asyncio.sleep(0.3)
        assert len(got) == n  # the tap is off: no more packets, and no viewer: no encoding
    finally:
        await pipeline.close()
    assert pipeline.viewers == 0
    assert got[0].keyframe  # the encoder's first frame (and one asked for)
    assert starts_decodable(bytes(got[0].packet))
    assert all(bytes(e.packet).startswith(b"\x00\x00\x00\x01") for e in got)  # Annex B


def decode_all(packets: list[bytes]) -> list[Any]:
    ctx = cast(VideoCodecContext, av.CodecContext.create("h264", "r"))
    frames = []
    for data in packets:
        frames.extend(ctx.decode(av.Packet(data)))
    frames.extend(ctx.decode(None))
    return frames


class _Robot:
    def snapshot(self) -> ArmSnapshot:
        return ArmSnapshot(time.monotonic(), NAMED_POSES["qn"], np.zeros(6))


async def test_the_media_worker_sends_the_recording_its_packets(tmp_path: Any) -> None:
    """The real worker process, nobody watching: a stand-in recorder gets a stream
    that decodes from its first message."""
    settings = Settings(
        state_dir=tmp_path, video_width=W, video_height=H, video_fps=30, keyframe_interval_s=10.0
    )
    media = MediaSupervisor(settings, _Robot())  # type: ignore[arg-type]
    logged: list[tuple[str, dict[str, Any]]] = []
    tap = VideoTap(media)
    await media.start()
    try:
        await tap.start(lambda topic, payload: logged.append((topic, payload)))
        deadline = time.monotonic() + 60
        while len(logged) < 45:
            assert time.monotonic() < deadline, f"only {len(logged)} packets logged"
            await asyncio.sleep(0.1)
        counts = await tap.stop()
        n = len(logged)
        await asyncio.sleep(0.5)
        assert len(logged) == n
    finally:
        await media.stop()
    assert all(topic == VIDEO_TOPIC for topic, _ in logged)
    first = logged[0][1]
    assert first["format"] == "h264" and first["frame_id"] == "stereo"
    assert starts_decodable(first["data"])
    wall = first["timestamp"]["sec"] + first["timestamp"]["nsec"] / 1e9
    assert abs(wall - time.time()) < 60  # capture time on the wall clock
    assert counts.worker_dropped == 0 and counts.packets == n
    # Through the recording's own writer and reader, then decoded from the first message.
    path = tmp_path / "rec.mcap"
    mcap = McapFile(path)
    for topic, payload in logged:
        mcap.write(topic, time.time_ns(), payload)
    mcap.close({"name": "t"})
    read_back = [m["data"] for _, _, m in read(path, [VIDEO_TOPIC])]
    assert read_back == [p["data"] for _, p in logged]
    frames = decode_all(read_back)
    assert len(frames) == n
    assert (frames[0].width, frames[0].height) == (2 * W, H)
    # The review's MP4: the same packets, remuxed, every frame there and decodable.
    info = remux_mp4(path, tmp_path / "rec.mp4")
    assert info["frames"] == n and (info["width"], info["height"]) == (2 * W, H)
    with av.open(str(tmp_path / "rec.mp4")) as mp4:
        stream = mp4.streams.video[0]
        decoded = list(mp4.decode(stream))
        assert len(decoded) == n
        duration = float(decoded[-1].time or 0)
    # Timed by the capture times: the last frame where the last packet was captured
    # (how many frames a busy machine captured in that time does not matter).
    captured = [p["timestamp"]["sec"] + p["timestamp"]["nsec"] / 1e9 for _, p in logged]
    assert duration == pytest.approx(captured[-1] - captured[0], abs=1 / 30), captured


if __name__ == "__main__":
    pytest.main([__file__])


def test_a_recording_from_the_real_server_holds_the_video_and_reviews(tmp_path: Any) -> None:
    """`telerobot serve` (simulation), nobody watching: record a few seconds over the
    REST API, download the file, read it back and decode every frame from the first;
    the review's MP4 and timeline answer for it."""
    import httpx

    from tests.support.servers import serving

    token = "t" * 32
    env = {
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_VIDEO": "true",  # tests turn it off by default
        "TELEROBOT_VIDEO_WIDTH": str(W),
        "TELEROBOT_VIDEO_HEIGHT": str(H),
    }
    auth = {"Authorization": f"Bearer {token}"}
    with serving(env) as base, httpx.Client(base_url=base, timeout=30) as http:
        deadline = time.monotonic() + 60
        while not http.get("api/v1/video").json()["worker_alive"]:  # the media worker is up
            assert time.monotonic() < deadline, "the media worker never answered"
            time.sleep(0.2)
        r = http.post("api/v1/recordings", json={"name": "video test"}, headers=auth)
        assert r.status_code == 200, r.text
        deadline = time.monotonic() + 60
        while True:  # a few seconds of video reached the writer
            active = http.get("api/v1/recordings/active").json()
            if active["elapsed_s"] > 3 and active["bytes"] > 50_000:
                break
            assert time.monotonic() < deadline, active
            time.sleep(0.2)
        entry = http.post("api/v1/recordings/active/stop", headers=auth).json()
        file = entry["file"]
        path = tmp_path / file
        path.write_bytes(http.get(f"api/v1/recordings/{file}/download").content)
        mp4 = http.get(f"api/v1/recordings/{file}/video.mp4")
        assert mp4.status_code == 200, (mp4.text, summary(path))
        assert mp4.headers["content-type"] == "video/mp4"
        part = http.get(f"api/v1/recordings/{file}/video.mp4", headers={"Range": "bytes=0-99"})
        assert part.status_code == 206 and len(part.content) == 100  # seekable
        tl = http.get(f"api/v1/recordings/{file}/timeline", params={"max_points": 100}).json()
    packets = [m for _, _, m in read(path, [VIDEO_TOPIC])]
    assert len(packets) > 30, len(packets)
    assert starts_decodable(packets[0]["data"])
    frames = decode_all([m["data"] for m in packets])
    assert abs(len(frames) - len(packets)) <= 1
    assert (frames[0].width, frames[0].height) == (2 * W, H)
    (tmp_path / "got.mp4").write_bytes(mp4.content)
    with av.open(str(tmp_path / "got.mp4")) as f:
        assert sum(1 for _ in f.decode(f.streams.video[0])) == len(packets)
    assert tl["video_start"] is not None and 0 <= tl["video_start"] < tl["duration"]
    assert 0 < len(tl["topics"]["/force"]) <= 100 and tl["stride"]["/force"] > 1
    assert tl["topics"]["/calibration"] and tl["topics"]["/robot/state"]
