"""Recordings: real MCAP files, read back with the reader."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from telerobot.drivers.clock import MonotonicClock
from telerobot.server.app import create_app
from telerobot.server.recording import reader
from telerobot.server.recording.recorder import Recorder, RecordingEvent
from telerobot.server.settings import Settings
from tests.support import TOKEN


def _events(rec: Recorder) -> list[RecordingEvent]:
    seen: list[RecordingEvent] = []
    rec.events.subscribe(seen.append)
    return seen


async def test_force_by_seq_and_every_topic(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, MonotonicClock())
    path = rec.start("unit")
    for seq in range(5000):
        rec.log("/force", {"seq": seq, "sensor_time": seq / 1000, "values": [0.0] * 6})
    rec.log("/video/stereo", {"frame_id": "stereo", "format": "h264", "data": b"\0\0\0\1\x67"})
    rec.episode_start("pick")
    rec.episode_end(True, "ok")
    await rec.stop()
    seqs = [m["seq"] for _t, _ns, m in reader.read(path, ["/force"])]
    assert seqs == list(range(5000))
    video = [m for _t, _ns, m in reader.read(path, ["/video/stereo"])]
    assert video[0]["data"] == b"\0\0\0\1\x67"
    counts, meta = reader.summary(path)
    assert counts["/episodes"] == 2 and meta["name"] == "unit"


async def test_overflow_drops_and_counts_never_blocks(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, MonotonicClock(), max_queue=10)
    rec.start("tiny")
    assert rec._active is not None and rec._active.thread is not None
    for seq in range(20_000):  # far faster than the writer can go
        rec.log("/force", {"seq": seq})
    path = await rec.stop()
    counts, meta = reader.summary(path)
    dropped = int(meta.get("dropped./force", "0"))
    assert dropped > 0 and counts["/force"] + dropped == 20_000


async def test_a_killed_writer_stops_with_a_reason_and_leaves_a_recoverable_file(
    tmp_path: Path,
) -> None:
    rec = Recorder(tmp_path, MonotonicClock(), chunk_bytes=1024)
    seen = _events(rec)
    path = rec.start("killed")
    assert rec._active is not None
    writer = rec._active.process
    assert writer.pid != os.getpid()  # encoding and writing happen in a process of its own
    for seq in range(2000):
        rec.log("/force", {"seq": seq})
    deadline = time.monotonic() + 30
    while rec.status()["bytes"] == 0:  # type: ignore[index]
        assert time.monotonic() < deadline, "the writer never reported progress"
        await asyncio.sleep(0.05)
    os.kill(writer.pid, signal.SIGKILL)  # type: ignore[arg-type]
    for seq in range(2000, 4000):
        rec.log("/force", {"seq": seq})
    while rec.active:  # the recording ends on its own, with the reason
        assert time.monotonic() < deadline, "the recording did not notice its writer died"
        await asyncio.sleep(0.05)
    assert seen[-1].kind == "stopped" and "writer failed" in seen[-1].reason
    assert "killed (signal 9)" in seen[-1].reason
    assert not rec.active
    if not reader.has_summary(path):
        reader.recover(path)
    assert sum(1 for _ in reader.read(path, ["/force"])) > 0


FULL_DISK = textwrap.dedent(
    """
    import asyncio, resource, signal, sys
    from pathlib import Path
    from telerobot.server.recording.recorder import Recorder
    from telerobot.drivers.clock import MonotonicClock
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
    async def main():
        rec = Recorder(Path(sys.argv[1]), MonotonicClock(), chunk_bytes=4096)
        seen = []
        rec.events.subscribe(seen.append)
        rec.start("full")
        for seq in range(200_000):
            rec.log("/force", {"seq": seq, "values": [seq * 1.1] * 6})
            if seq % 1000 == 0:
                await asyncio.sleep(0)
        if rec.active:
            await rec.stop()
        await asyncio.sleep(0)  # the writer's own end is announced on the loop
        print("REASON", seen[-1].reason)
    asyncio.run(main())
    """
)


def test_full_disk_leaves_a_recoverable_file(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=Path(__file__).parents[1],
    )  # fmt: skip
    assert "REASON" in out.stdout, out.stderr
    assert "too large" in out.stdout.lower() or "errno" in out.stdout.lower(), out.stdout
    (path,) = tmp_path.glob("*.mcap")
    if not reader.has_summary(path):
        assert reader.recover(path) > 0
    assert sum(1 for _ in reader.read(path, ["/force"])) > 0


def test_rest_record_commands_and_token_rules(tmp_path: Path) -> None:
    settings = Settings(
        state_dir=tmp_path, video=False, viewer=False, priority_port=0, operator_token=TOKEN
    )
    with TestClient(create_app(settings), base_url="http://127.0.0.1") as c:
        op = {"Authorization": f"Bearer {TOKEN}"}
        assert c.post("/api/v1/recordings", json={"name": "r"}).status_code == 403
        started = c.post("/api/v1/recordings", json={"name": "r"}, headers=op).json()
        assert started["recording"] and c.get("/api/v1/recordings/active").json()["recording"]
        client = c.post("/api/v1/lease", json={"name": "script"}, headers=op).json()["client_id"]
        move = {**op, "X-Client-Id": client}
        # refused: outside the joint limits / not initialised; accepted or not, it is logged
        body = {"space": "joint", "mode": "absolute", "joints": [9, 9, 9, 9, 9, 9]}
        refused_move = c.post("/api/v1/robot/move", json=body, headers=move)
        assert refused_move.status_code in (409, 422), refused_move.text
        c.post("/api/v1/recordings/active/episodes", json={"task": "pick"}, headers=op)
        c.post("/api/v1/recordings/active/episodes/end", json={"success": False}, headers=op)
        # a recalibration (here: cleared) while recording is in the file from then on
        assert c.delete("/api/v1/calibration", headers=op).status_code == 200
        file = started["file"]
        assert c.delete(f"/api/v1/recordings/{file}", headers=op).status_code == 409
        stopped = c.post("/api/v1/recordings/active/stop", headers=op).json()
        assert stopped["complete"] and stopped["episodes"][0]["success"] is False
        listing = c.get("/api/v1/recordings").json()
        assert [e["file"] for e in listing] == [file]
        data = c.get(f"/api/v1/recordings/{file}/download").content
        path = tmp_path / "recordings" / file
        assert data == path.read_bytes()
        commands = [m for _t, _ns, m in reader.read(path, ["/commands"])]
        assert commands[0]["kind"] == "lease" and commands[0]["source"] == "rest"
        refused = [m for m in commands if not m["accepted"]]
        assert refused and refused[0]["reason"] and refused[0]["code"]
        calibrations = [m for _t, _ns, m in reader.read(path, ["/calibration"])]
        assert len(calibrations) == 2 and calibrations[1]["cameras"] == {}
        topics = {t for t, _ns, _m in reader.read(path)}
        assert {"/force", "/robot/state", "/tf", "/settings", "/calibration", "/commands",
                "/safety", "/episodes"} <= topics  # fmt: skip
        assert c.delete(f"/api/v1/recordings/{file}").status_code >= 400  # no token
        assert path.exists()
        assert c.delete(f"/api/v1/recordings/{file}", headers=op).status_code == 200
        assert not path.exists()
        # the robot still works after all this
        assert c.get("/api/v1/robot/state").status_code == 200


@pytest.mark.parametrize("bad", ["../x.mcap", "a/b.mcap", ".hidden.mcap"])
def test_paths_stay_in_the_folder(tmp_path: Path, bad: str) -> None:
    rec = Recorder(tmp_path, MonotonicClock())
    with pytest.raises(Exception, match="no recording"):
        rec.path_of(bad)


def test_the_list_shows_only_the_newest_recordings(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, MonotonicClock(), max_listed=3)
    for minute in range(5):
        (tmp_path / f"20260101-00{minute:02d}00-r{minute}.mcap").write_bytes(b"not mcap")
    listing = rec.listing()
    assert [e["file"] for e in listing] == [
        "20260101-000400-r4.mcap",
        "20260101-000300-r3.mcap",
        "20260101-000200-r2.mcap",
    ]
    assert not any(e["complete"] for e in listing)  # unreadable files are listed, not trusted


FRAME = {"frame_id": "stereo", "format": "h264", "data": b"\0\0\0\1\x65"}


async def test_an_episode_opened_before_the_first_frame_starts_with_it(tmp_path: Path) -> None:
    """A recording with video: an episode opened before its first video frame waits for
    it and starts with it (the export then has no seconds without a picture to cut);
    once the video flows, episodes open at once; without any frame in `wait_s` the
    episode starts anyway."""
    clock = MonotonicClock()
    rec = Recorder(tmp_path, clock)
    rec.expects_video = True
    rec.start("video late")
    opening = asyncio.create_task(rec.episode_start_with_video("pick"))
    await asyncio.sleep(0.3)
    assert not opening.done()  # no picture yet
    framed = clock.now()
    rec.log("/video/stereo", FRAME)
    episode = await asyncio.wait_for(opening, 10)
    assert episode.started >= framed
    rec.episode_end(True)
    t0 = clock.now()
    await rec.episode_start_with_video("place", wait_s=60)  # the video flows: at once
    assert clock.now() - t0 < 30  # (a margin any machine keeps: it waits 60 s if wrong)
    await rec.stop()

    rec.start("no video comes")
    t0 = clock.now()
    await rec.episode_start_with_video("pick", wait_s=0.2)
    assert clock.now() - t0 >= 0.2  # it waited, then started without a picture
    await rec.stop()


async def test_without_video_expected_an_episode_opens_at_once(tmp_path: Path) -> None:
    clock = MonotonicClock()
    rec = Recorder(tmp_path, clock)  # no video tap follows it (a server without video)
    rec.start("no video")
    t0 = clock.now()
    await rec.episode_start_with_video("pick", wait_s=60)
    assert clock.now() - t0 < 30  # (it would wait 60 s if it waited)
    await rec.stop()


def _frame_at(wall_s: float) -> dict[str, object]:
    sec = int(wall_s)
    return {**FRAME, "timestamp": {"sec": sec, "nsec": int((wall_s - sec) * 1e9)}}


async def test_stopping_waits_for_the_frames_captured_before_the_stop(tmp_path: Path) -> None:
    """Frames reach the recorder ~0.1 s after their capture: a stop right after an
    episode's end waits (2 s at most) for the frame captured at the stop, so the
    episode's last moments have their picture and the export does not cut its end."""
    rec = Recorder(tmp_path, MonotonicClock())
    rec.expects_video = True
    path = rec.start("tail")
    rec.log("/video/stereo", _frame_at(time.time() - 1.0))  # the video flows, behind
    stopping = asyncio.create_task(rec.stop())
    await asyncio.sleep(0.3)
    assert not stopping.done()  # the frame of the stop's moment is not in yet
    rec.log("/video/stereo", _frame_at(time.time()))
    await asyncio.wait_for(stopping, 30)
    assert len(list(reader.read(path, ["/video/stereo"]))) == 2  # both kept

    path = rec.start("no more frames")
    rec.log("/video/stereo", _frame_at(time.time() - 1.0))
    t0 = time.monotonic()
    await rec.stop()  # none comes: it stops after its wait
    assert time.monotonic() - t0 >= 1.9
