"""Stereo video: the simulated camera against its ground truth, frame pairing, and
real WebRTC peers (aiortc on both ends, in-process) receiving the shared stream."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest
from aiortc import RTCPeerConnection, RTCSessionDescription

from telerobot.drivers.base import ArmSnapshot, StereoFrame
from telerobot.drivers.camera import timecode
from telerobot.drivers.camera.sim import FIDUCIAL_COLOURS, IDLE_AFTER_S, SimStereoCamera
from telerobot.drivers.camera.slot import KEEP, FrameSlot
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.media.pipeline import (
    IDLE_POLL_S,
    BadOffer,
    VideoPipeline,
    VideoSettings,
    no_signal_frame,
)
from tests.support.video import SMALL, camera

SANE_AGE_S = 30.0  # a decoded capture time this old is from another clock, not late


def test_rendered_fiducials_sit_where_the_ground_truth_projects_them() -> None:
    cam = camera()
    img = cam.background  # the scene without the arm, which may hide a fiducial
    cell = cam.workcell
    for eye, pinhole in enumerate(cam.cameras):
        half = img[:, eye * cam.width : (eye + 1) * cam.width].astype(int)
        for colour, expected in zip(FIDUCIAL_COLOURS, pinhole.project(cell.fiducials), strict=True):
            mask = np.all(np.abs(half - np.array(colour)) < 30, axis=2)
            ys, xs = np.nonzero(mask)
            assert len(xs) > 20
            assert np.hypot(xs.mean() - expected[0], ys.mean() - expected[1]) < 1.0


def test_timecode_survives_the_round_trip() -> None:
    img = np.zeros((100, 700, 3), np.uint8)
    timecode.draw(img, 1234.5678)
    assert timecode.read(img) == timecode.encode_time(1234.5678)
    assert timecode.elapsed(timecode.encode_time(10.0), 10.25) == pytest.approx(0.25)


def test_newest_frame_wins_and_is_never_handed_out_twice() -> None:
    cam = camera()
    first = cam.capture()
    second = cam.capture()
    got = cam.next_frame(0, timeout=0.1)
    assert got is second and cam.dropped == 1  # the first was replaced before anyone read it
    assert cam.next_frame(second.seq, timeout=0.01) is None  # nothing newer: no stale repeat
    assert first.seq < second.seq
    assert got.left.base is got.sbs and got.right.shape == got.left.shape  # views of one capture


def test_a_reader_that_must_miss_none_gets_every_kept_frame_oldest_first() -> None:
    slot = FrameSlot()
    image = np.zeros((2, 4, 3), np.uint8)
    for i in range(1, 4):
        slot.put(StereoFrame(i, float(i), image))
    got = []
    seq = 0
    while (f := slot.next_frame(seq, 0.0, every=True)) is not None:
        got.append(f.seq)
        seq = f.seq
    assert got == [1, 2, 3] and slot.dropped == 0
    for i in range(4, 4 + KEEP):  # KEEP more, unread: none pushed out yet
        slot.put(StereoFrame(i, float(i), image))
    assert slot.dropped == 0
    slot.put(StereoFrame(4 + KEEP, 0.0, image))  # one more pushes frame 4 out, unread
    assert slot.dropped == 1
    first = slot.next_frame(seq, 0.0, every=True)
    assert first is not None and first.seq == 5  # the oldest kept
    newest = slot.next_frame(first.seq, 0.0)  # a live reader jumps to the newest
    assert newest is not None and newest.seq == 4 + KEEP
    assert slot.dropped == 1 + (KEEP - 2)  # those passed over, never read
    assert slot.next_frame(newest.seq, 0.0, every=True) is None


def test_a_held_up_camera_renders_the_exposures_it_missed_each_at_its_own_time() -> None:
    """On a busy machine the capture thread wakes late. It renders the exposures it
    missed (up to CATCH_UP_S), each stamped and drawn at its own grid time, so the
    recording has no missing frame; held up longer, it skips to now (a gap, counted)."""
    now = [100.0]
    fps = 30.0
    snap = ArmSnapshot(now[0], NAMED_POSES["qn"], np.zeros(6))
    stalls = {5: 0.1, 14: 0.5}  # after frame 5: three periods late; after 14: fifteen
    got: list[StereoFrame] = []

    def sleep(delay: float) -> None:
        seq = got[-1].seq if got else 0
        while (f := cam.next_frame(seq, 0.0, every=True)) is not None:
            got.append(f)
            seq = f.seq
        now[0] += delay + stalls.pop(cam._seq, 0.0)
        if len(got) >= 30:
            cam._stop.set()

    cam = SimStereoCamera(
        default_workcell(**SMALL),
        lambda: snap,
        Puma560Kinematics(tool_transform(0.1)),
        fps=fps,
        time_source=lambda: now[0],
        sleep=sleep,
    )
    cam.next_frame(0, 0.0)  # a reader asks: it renders
    cam._run()
    seqs = [f.seq for f in got]
    assert seqs == list(range(1, len(got) + 1)) and cam.dropped == 0  # none missed
    steps = np.diff([f.time for f in got])
    assert np.allclose(steps[:13], 1 / fps)  # the first stall caught up on the grid
    assert steps[13] > 0.5  # the second was too long: skipped to now, once
    assert np.allclose(steps[14:], 1 / fps)
    for f in got:  # each frame shows the time it was exposed at
        assert timecode.read(f.left) == timecode.encode_time(f.time)


def test_the_simulated_camera_renders_only_while_someone_reads() -> None:
    now = [100.0]
    snap = ArmSnapshot(now[0], NAMED_POSES["qn"], np.zeros(6))
    cam = SimStereoCamera(
        default_workcell(**SMALL),
        lambda: snap,
        Puma560Kinematics(tool_transform(0.1)),
        time_source=lambda: now[0],
    )
    assert not cam.wanted  # nobody has asked yet
    assert cam.next_frame(0, timeout=0.0) is None  # a reader asks (nothing rendered yet)
    assert cam.wanted
    now[0] += IDLE_AFTER_S
    assert cam.wanted
    now[0] += 0.01
    assert not cam.wanted  # the reader went away: the thread stops rendering


async def test_the_pipeline_pulls_no_frames_without_a_viewer() -> None:
    cam = camera(**SMALL)
    asked: list[int] = []
    real_next_frame = cam.next_frame

    def next_frame(after_seq: int, timeout: float) -> StereoFrame | None:
        asked.append(after_seq)
        return real_next_frame(after_seq, timeout)

    cam.next_frame = next_frame  # type: ignore[method-assign]
    pipeline = VideoPipeline(cam, VideoSettings(fps=30))
    pipeline.start()
    try:
        await asyncio.sleep(5 * IDLE_POLL_S)
        assert asked == [] and not cam.wanted
    finally:
        await pipeline.close()


def test_no_signal_frame_says_why() -> None:
    f = no_signal_frame(320, 180, "device /dev/video9 not found", -1, 0.0)
    assert f.sbs.shape == (180, 640, 3) and f.sbs.mean() > 40  # grey plus white text


async def _receive(pipeline: VideoPipeline, frames: int, codec: str = "") -> list[float]:
    """A real WebRTC viewer: offer, answer, decode ``frames`` frames, read each timecode."""
    from aiortc import RTCRtpSender

    pc = RTCPeerConnection()
    transceiver = pc.addTransceiver("video", direction="recvonly")
    if codec:  # a viewer that only takes this codec
        caps = RTCRtpSender.getCapabilities("video").codecs
        transceiver.setCodecPreferences(
            [c for c in caps if c.mimeType in (f"video/{codec}", "video/rtx")]
        )
    received: asyncio.Queue[object] = asyncio.Queue()
    pc.on("track", lambda track: received.put_nowait(track))
    await pc.setLocalDescription(await pc.createOffer())
    answer = await pipeline.answer(pc.localDescription.sdp, "offer")
    await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
    track = await asyncio.wait_for(received.get(), 10)
    latencies = []
    for _ in range(frames):
        frame = await asyncio.wait_for(track.recv(), 10)  # type: ignore[attr-defined]
        rgb = frame.to_ndarray(format="rgb24")
        code = timecode.read(rgb[:, : rgb.shape[1] // 2])
        assert code is not None
        latencies.append(timecode.elapsed(code, time.monotonic()))
    await pc.close()
    return latencies


async def test_a_webrtc_peer_receives_frames_and_decodes_the_timecode() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=2_000_000))
    pipeline.start()
    try:
        latencies = await _receive(pipeline, 20)
    finally:
        await pipeline.close()
    # Real capture times, decoded from the picture: this machine's monotonic clock, so
    # never ahead of it and not from another time base (a sanity bound, not a latency:
    # capture → decoded is bench.video's latency_p50_ms/_p99_ms).
    assert all(0 <= x < SANE_AGE_S for x in latencies)
    assert pipeline.encoding.frames_encoded >= 20 and pipeline.stats()["encode_ms_p50"] > 0


async def test_a_viewer_without_h264_gets_vp8_from_a_second_encoder() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=2_000_000))
    pipeline.start()
    try:
        latencies = await _receive(pipeline, 10, codec="VP8")
    finally:
        await pipeline.close()
    assert all(0 <= x < SANE_AGE_S for x in latencies)
    assert set(pipeline.encoding.encoders) == {("H264", "full"), ("VP8", "full")}
    assert pipeline.encoding.frames_encoded == 0  # no H.264 viewer


async def test_two_viewers_share_one_encoder() -> None:
    pipeline = VideoPipeline(camera(**SMALL), VideoSettings(bitrate=2_000_000))
    pipeline.start()
    try:
        await asyncio.gather(_receive(pipeline, 15), _receive(pipeline, 15))
        stats = pipeline.stats()
    finally:
        await pipeline.close()
    # Two viewers, one encode per captured frame: never twice the captured count.
    captured = pipeline.encoding.capture_interarrival.count + 1
    assert pipeline.encoding.frames_encoded <= captured + 1
    assert stats["frames_encoded"] >= 15


@pytest.mark.parametrize(
    ("sdp", "kind", "reason"),
    [
        ("v=0\r\n", "offer", "no video section"),
        ("garbage m=video H264", "offer", "cannot use this offer"),
        ("v=0 m=video", "answer", "expected an SDP of type 'offer'"),
        (
            "v=0\r\nm=video 9 UDP/TLS/RTP/SAVPF 96\r\na=rtpmap:96 AV1/90000\r\n",
            "offer",
            "neither H.264 nor VP8",
        ),
    ],
)
async def test_bad_offers_are_refused_with_the_reason(sdp: str, kind: str, reason: str) -> None:
    pipeline = VideoPipeline(camera(**SMALL))
    with pytest.raises(BadOffer, match=reason):
        await pipeline.answer(sdp, kind)
    assert pipeline.peers == {}


# ---------------------------------------------------------------- OpenCV cameras
def _numbered_video(
    path: str, frames: int, offset: int = 0, size: tuple[int, int] = (640, 360)
) -> None:
    import cv2

    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 30, size)
    assert writer.isOpened()
    for i in range(frames):
        img = np.zeros((size[1], size[0], 3), np.uint8)
        timecode.draw(img, (i + offset) * timecode.UNIT)
        writer.write(img)
    writer.release()


def test_two_device_camera_never_mixes_partners(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from telerobot.drivers.camera.opencv import OpenCVStereoCamera

    left, right = str(tmp_path / "left.avi"), str(tmp_path / "right.avi")
    _numbered_video(left, 60)
    _numbered_video(right, 60)
    cam = OpenCVStereoCamera(left, right, width=640, height=360, fps=200)
    cam.start()
    seen = 0
    seq = 0
    try:
        for _ in range(25):
            frame = cam.next_frame(seq, timeout=2.0)
            assert frame is not None
            seq = frame.seq
            assert timecode.read(frame.left) == timecode.read(frame.right)  # same instant
            assert frame.skew >= 0
            seen += 1
            time.sleep(0.004)  # a slow reader: frames are skipped, never mixed
    finally:
        cam.stop()
    assert seen == 25


def test_a_missing_camera_is_reported_and_retried(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from telerobot.drivers.base import CameraStatus
    from telerobot.drivers.camera.opencv import OpenCVSideBySideCamera

    path = str(tmp_path / "later.avi")
    cam = OpenCVSideBySideCamera(path, width=320, height=360, fps=100, retry_s=0.05)
    cam.start()
    try:
        deadline = time.monotonic() + 5
        while cam.retries < 2:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert cam.status is CameraStatus.FAILED and "cannot open camera" in cam.status_message
        assert cam.next_frame(0, timeout=0.05) is None
        _numbered_video(path, 30)  # the device appears
        frame = cam.next_frame(0, timeout=5)
        assert frame is not None and frame.sbs.shape == (360, 640, 3)
        assert cam.status is CameraStatus.RUNNING
    finally:
        cam.stop()


def test_constant_bitrate_fills_the_budget_even_for_a_still_scene() -> None:
    from telerobot.drivers.base import StereoFrame
    from telerobot.server.media.encoder import H264Encoder

    still = np.full((360, 1280, 3), 120, np.uint8)
    sizes = {}
    for cbr in (False, True):
        enc = H264Encoder(1280, 360, 30.0, 4_000_000, cbr=cbr)
        sizes[cbr] = sum(
            e.size for i in range(60) for e in enc.encode(StereoFrame(i, i / 30, still))
        )
    mbps = {k: v * 8 / 2.0 / 1e6 for k, v in sizes.items()}  # 60 frames = 2 s
    assert mbps[False] < 0.5  # "at most" 4 Mbit/s: a still scene needs next to nothing
    assert 3.6 < mbps[True] < 4.4  # constant: the budget, filled


def test_the_simulated_cameras_can_hold_up_a_charuco_board_for_calibration() -> None:
    import cv2

    from telerobot.calibration.charuco import detect
    from telerobot.drivers.camera.charuco_board import BoardSpec

    cam = camera()
    w = cam.width
    for view in range(0, 12, 3):
        cam.show_board(view)
        grey = cv2.cvtColor(cam.render(0.0), cv2.COLOR_RGB2GRAY)
        for eye in (grey[:, :w], grey[:, w:]):
            found = detect(eye, BoardSpec())
            assert found is not None and len(found[0]) > 20, view  # most corners, both eyes
    cam.show_board(None)
    assert detect(cv2.cvtColor(cam.render(0.0), cv2.COLOR_RGB2GRAY)[:, :w], BoardSpec()) is None


def test_keyframes_come_only_when_asked_unless_an_interval_is_set() -> None:
    """A periodic keyframe is a burst of tens of frames' bytes that queues everything
    behind it on a narrow link: by default there are none."""
    from telerobot.drivers.base import StereoFrame
    from telerobot.server.media.encoder import H264Encoder, Vp8Encoder

    rng = np.random.default_rng(1)
    for codec in (H264Encoder, Vp8Encoder):
        for interval, want in ((0.0, [0, 45]), (1.0, [0, 30, 45, 75])):
            enc = codec(320, 180, 30.0, 500_000, keyframe_interval=interval)
            keys = []
            for i in range(90):
                if i == 45:
                    enc.request_keyframe()  # a new viewer, a PLI
                picture = rng.integers(0, 255, (180, 640, 3), np.uint8)
                if any(e.keyframe for e in enc.encode(StereoFrame(i, i / 30, picture))):
                    keys.append(i)
            assert keys == want, (codec.codec, interval)
