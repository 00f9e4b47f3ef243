"""Recordings read by anyone: the list is a page of an
index, never a parse per request, and does not hold the event loop; heavy reads are
made once, in a process of their own, within a budget per address; a file cut short is
read as far as it is valid, one that is not a recording and the one being written are
refused with 422 and 409, never a 500; ids too long for a file name are 422; a
recording stops at its size cap or a nearly full disk with the reason kept, and does
not start on a full disk. Real MCAP files, written by the recorder's own writer."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from harness.recordings import build
from telerobot.drivers.clock import MonotonicClock
from telerobot.server.app import create_app
from telerobot.server.errors import REFUSAL_DELAY_S
from telerobot.server.realtime.ratelimit import PeerLimits
from telerobot.server.recording import readjobs
from telerobot.server.recording.index import LABEL_CHARS, LISTED_EPISODES
from telerobot.server.recording.library import SHARED_PAGE_S, SHARED_PAGES
from telerobot.server.recording.recorder import Recorder, RecordingEvent, RecordingNoSpace
from telerobot.server.recording.writer import McapFile
from telerobot.server.services import Services
from telerobot.server.settings import Settings
from tests.support import TOKEN
from tests.support.servers import serving

OP = {"Authorization": f"Bearer {TOKEN}"}
WALL0_NS = 1_767_225_600_000_000_000


def write_recording(
    path: Path,
    *,
    seconds: float = 2.0,
    episodes: int = 2,
    label: str = "pick the block",
    close: bool = True,
) -> Path:
    """A recording as the recorder writes one (its writer, its topics, its metadata):
    forces at 1 kHz, states at 50 Hz, episode events; ``close`` False leaves it as a
    killed writer does (no summary)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    f = McapFile(path, chunk_bytes=16 * 1024)
    eps = []
    for e in range(episodes):
        start = 1000.0 + e * seconds / max(episodes, 1)
        eps.append(
            {"episode": e, "task": label, "started": start, "ended": start + 0.1,
             "success": True, "notes": label}
        )  # fmt: skip
    for i in range(int(seconds * 1000)):
        ns, t = WALL0_NS + i * 1_000_000, 1000.0 + i / 1000
        f.write("/force", ns, {"t": t, "seq": i, "values": [i % 7 * 0.1] * 6})
        if i % 20 == 0:
            f.write(
                "/robot/state", ns,
                {"t": t, "status": "READY", "joints": [0.0] * 6, "target_joints": [0.0] * 6,
                 "position": [0.1, 0.2, 0.3], "rotation": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
            )  # fmt: skip
    for ep in eps[:100]:
        f.write("/episodes", WALL0_NS, {"t": ep["started"], "event": "start", **ep})
    if close:
        f.close(
            {"name": path.stem[16:], "duration_s": f"{seconds:.3f}",
             "stop_reason": "stopped by the operator", "episodes": json.dumps(eps)}
        )  # fmt: skip
    else:
        f.flush()
        f.abandon()
    return path


def _settings(state: Path, **more: Any) -> Settings:
    return Settings(
        state_dir=state, video=False, viewer=False, priority_port=0, operator_token=TOKEN, **more
    )


@pytest.fixture
def app(tmp_path: Path) -> Iterator[tuple[TestClient, Services, Path]]:
    """The server in process, its recordings folder (``state/recordings``). Its budget of
    reads that start a job is lifted (one test client makes many; the budget has its
    own test)."""
    folder = tmp_path / "recordings"
    folder.mkdir()
    with TestClient(create_app(_settings(tmp_path)), base_url="http://127.0.0.1") as c:
        services: Services = c.app.state.services  # type: ignore[attr-defined]
        services.recorder.library.budgets.jobs = PeerLimits(
            connections_per_s=1000.0, connection_burst=1000
        )
        yield c, services, folder


def _no_tracebacks(caplog: pytest.LogCaptureFixture) -> None:
    bad = [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info]
    assert not bad, [r.getMessage() for r in bad]


# ---------------------------------------------------------------- torn, foreign, active
CUTS = {
    "one byte short": lambda data: data[:-1],
    "the summary cut": lambda data: data[: len(data) - 300],
    "a chunk torn": lambda data: data[: len(data) * 2 // 3],
}


@pytest.mark.parametrize("cut", CUTS)
def test_a_file_cut_short_is_read_as_far_as_it_is_valid(
    app: tuple[TestClient, Services, Path], cut: str, caplog: pytest.LogCaptureFixture
) -> None:
    c, _s, folder = app
    whole = write_recording(folder / "20260101-000000-whole.mcap")
    torn = folder / "20260101-000001-torn.mcap"
    torn.write_bytes(CUTS[cut](whole.read_bytes()))
    killed = write_recording(folder / "20260101-000002-killed.mcap", close=False)
    caplog.set_level(logging.INFO)
    for path in (torn, killed):
        r = c.get(f"/api/v1/recordings/{path.name}/timeline", params={"max_points": 100})
        assert r.status_code == 200, r.text
        tl = r.json()
        assert not tl["complete"] and tl["counts"]["/force"] > 0
        assert 0 < len(tl["topics"]["/force"]) <= 100 and tl["topics"]["/robot/state"]
        meta = c.get(f"/api/v1/recordings/{path.name}/metadata")
        assert meta.status_code == 200 and meta.json()["complete"] is False, meta.text
        assert c.get(f"/api/v1/recordings/{path.name}/download").content == path.read_bytes()
    whole_tl = c.get(f"/api/v1/recordings/{whole.name}/timeline").json()
    if cut == "one byte short":  # every message is there: only the footer's last byte is not
        torn_tl = c.get(f"/api/v1/recordings/{torn.name}/timeline").json()
        assert torn_tl["counts"] == whole_tl["counts"] and whole_tl["complete"]
    listed = {e["file"]: e for e in c.get("/api/v1/recordings").json()}
    assert listed[whole.name]["complete"] and not listed[torn.name]["complete"]
    _no_tracebacks(caplog)


def test_a_recording_cut_short_still_gives_its_video_and_its_export(
    app: tuple[TestClient, Services, Path], caplog: pytest.LogCaptureFixture
) -> None:
    """What a killed writer leaves: the MP4 and the LeRobot export of what is there."""
    c, _s, folder = app
    built = build(folder / "20260101-000000-video.mcap", duration=3.0)
    data = built.path.read_bytes()
    built.path.write_bytes(data[:-1])
    caplog.set_level(logging.INFO)
    mp4 = c.get(f"/api/v1/recordings/{built.path.name}/video.mp4")
    assert mp4.status_code == 200, mp4.text
    assert mp4.headers["content-type"] == "video/mp4" and len(mp4.content) > 1000
    export = c.post(f"/api/v1/recordings/{built.path.name}/export/lerobot", headers=OP)
    assert export.status_code == 200, export.text
    assert export.json()["episodes"] == 2
    _no_tracebacks(caplog)


def test_a_file_that_is_not_a_recording_is_refused_with_422(
    app: tuple[TestClient, Services, Path], caplog: pytest.LogCaptureFixture
) -> None:
    c, _s, folder = app
    notes = folder / "20260101-000000-notes.mcap"
    notes.write_text("shopping list: milk, eggs\n" * 100)
    caplog.set_level(logging.INFO)
    for route in ("timeline", "video.mp4"):
        r = c.get(f"/api/v1/recordings/{notes.name}/{route}")
        assert r.status_code == 422, r.text
        assert "not an MCAP" in r.json()["detail"]
    r = c.post(f"/api/v1/recordings/{notes.name}/export/lerobot", headers=OP)
    assert r.status_code == 422 and "not an MCAP" in r.json()["detail"], r.text
    (entry,) = c.get("/api/v1/recordings").json()
    assert entry["file"] == notes.name and not entry["complete"]
    assert notes.read_text().startswith("shopping list")  # nothing wrote to it
    _no_tracebacks(caplog)


def test_the_recording_being_written_is_refused_with_409(
    app: tuple[TestClient, Services, Path], caplog: pytest.LogCaptureFixture
) -> None:
    c, _s, _folder = app
    started = c.post("/api/v1/recordings", json={"name": "live"}, headers=OP)
    assert started.status_code == 200, started.text
    file = started.json()["file"]
    caplog.set_level(logging.INFO)
    try:
        for route in ("timeline", "video.mp4", "download"):
            r = c.get(f"/api/v1/recordings/{file}/{route}")
            assert r.status_code == 409, (route, r.text)
            assert "being recorded" in r.json()["detail"]
        r = c.post(f"/api/v1/recordings/{file}/export/lerobot", headers=OP)
        assert r.status_code == 409 and "being recorded" in r.json()["detail"], r.text
        (entry,) = c.get("/api/v1/recordings").json()
        assert entry["file"] == file and entry["active"] and entry["name"] == "live"
        meta = c.get(f"/api/v1/recordings/{file}/metadata")
        assert meta.status_code == 200 and meta.json()["active"], meta.text
    finally:
        stopped = c.post("/api/v1/recordings/active/stop", headers=OP)
    assert stopped.status_code == 200 and stopped.json()["complete"], stopped.text
    assert c.get(f"/api/v1/recordings/{file}/timeline").status_code == 200  # once stopped
    _no_tracebacks(caplog)


# ---------------------------------------------------------------- ids
@pytest.mark.parametrize("length", [201, 5000, 15000])
def test_an_id_longer_than_a_file_name_is_422(
    app: tuple[TestClient, Services, Path], length: int
) -> None:
    c, _s, _folder = app
    long = "a" * (length - 5) + ".mcap"
    asks = [
        ("get", f"/api/v1/recordings/{long}/download", {}),
        ("get", f"/api/v1/recordings/{long}/metadata", {}),
        ("get", f"/api/v1/recordings/{long}/timeline", {}),
        ("get", f"/api/v1/recordings/{long}/video.mp4", {}),
        ("delete", f"/api/v1/recordings/{long}", OP),
        ("post", f"/api/v1/recordings/{long}/export/lerobot", OP),
    ]
    for method, url, headers in asks:
        r = c.request(method, url, headers=headers)
        assert r.status_code == 422, (method, url[:60], r.status_code, r.text[:300])
        assert "at most 200 characters" in r.json()["detail"]


# ---------------------------------------------------------------- the list
def test_the_list_is_a_page_summarised_from_the_index(
    app: tuple[TestClient, Services, Path],
) -> None:
    """10 000 long episode labels had made one tokenless listing 21 MB; each listing
    parsed every file's summary again."""
    c, s, folder = app
    write_recording(folder / "20260101-000000-long.mcap", episodes=2000, label="x" * 2000)
    for minute in range(1, 6):
        write_recording(folder / f"20260101-00{minute:02d}00-r{minute}.mcap", seconds=0.2)
    r = c.get("/api/v1/recordings")
    assert r.status_code == 200 and r.headers["x-total-count"] == "6"
    assert len(r.content) < 64 * 1024, len(r.content)
    long = next(e for e in r.json() if e["name"] == "long")
    assert long["episode_count"] == 2000 and len(long["episodes"]) == LISTED_EPISODES
    assert all(len(e["task"]) <= LABEL_CHARS for e in long["episodes"])
    assert (folder / ".index" / "20260101-000000-long.mcap.json").is_file()
    jobs = s.recorder.library.jobs.started
    page = c.get("/api/v1/recordings", params={"limit": 2, "offset": 1}).json()
    assert [e["file"] for e in page] == ["20260101-000400-r4.mcap", "20260101-000300-r3.mcap"]
    assert s.recorder.library.jobs.started == jobs  # read from the index: nothing parsed
    too_many = c.get("/api/v1/recordings", params={"limit": 201})
    assert too_many.status_code == 422 and "limit" in too_many.json()["detail"]


def test_a_tokenless_list_is_a_page_up_to_a_second_old(
    app: tuple[TestClient, Services, Path],
) -> None:
    """A loop of tokenless listings costs one encoding of a page a second; the token's
    listing is always fresh, and a kept page is replaced once a second old."""
    c, s, folder = app
    library = s.recorder.library
    now = [1000.0]
    library.clock = lambda: now[0]
    write_recording(folder / "20260101-000100-a.mcap", seconds=0.2)
    assert [e["name"] for e in c.get("/api/v1/recordings").json()] == ["a"]
    write_recording(folder / "20260101-000200-b.mcap", seconds=0.2)
    now[0] += SHARED_PAGE_S / 2
    kept = c.get("/api/v1/recordings")
    assert [e["name"] for e in kept.json()] == ["a"] and kept.headers["x-total-count"] == "1"
    fresh = c.get("/api/v1/recordings", headers=OP).json()
    assert [e["name"] for e in fresh] == ["b", "a"]
    write_recording(folder / "20260101-000300-c.mcap", seconds=0.2)
    now[0] += SHARED_PAGE_S
    assert [e["name"] for e in c.get("/api/v1/recordings").json()] == ["c", "b", "a"]
    for offset in range(SHARED_PAGES + 4):  # pages kept: a few, the oldest let go
        c.get("/api/v1/recordings", params={"offset": offset}, headers=OP)
    assert len(library._shared) == SHARED_PAGES


def test_the_list_does_not_hold_the_event_loop(tmp_path: Path) -> None:
    """A real server with 120 recordings it has not indexed: until the tokenless list's
    answer starts (the first time: every summary read), cheap requests keep being
    answered. Before, the summaries were parsed on the event loop and nothing else was
    answered until the list was."""
    folder = tmp_path / "recordings"
    for n in range(120):
        write_recording(
            folder / f"20260101-{n // 60:02d}{n % 60:02d}00-r{n}.mcap",
            seconds=0.05, episodes=300, label="y" * 900,
        )  # fmt: skip
    answered_first = 0
    with (
        serving({"TELEROBOT_VIDEO": "false"}, "--state-dir", str(tmp_path)) as base,
        httpx.Client(base_url=base, timeout=120) as lister,
        httpx.Client(base_url=base, timeout=120) as other,
    ):
        lister.get("api/v1/health")  # both connections open before the race
        other.get("api/v1/health")
        listed = threading.Event()
        entries: list[Any] = []

        def list_them() -> None:
            with lister.stream("GET", "api/v1/recordings", params={"limit": 200}) as r:
                listed.set()  # its status line and headers: the server has made the list
                entries.extend(json.loads(r.read()) if r.status_code == 200 else [r.text])

        thread = threading.Thread(target=list_them)
        thread.start()
        while not listed.is_set():
            assert other.get("api/v1/health").status_code == 200
            if not listed.is_set():
                answered_first += 1
        thread.join()
    assert len(entries) == 120, entries[:1]
    assert answered_first >= 10, answered_first  # (before: 2; now: ~200)


# ---------------------------------------------------------------- budgets, kept reads
def test_a_loop_of_timeline_reads_is_one_job_kept_beside_the_recording(
    app: tuple[TestClient, Services, Path],
) -> None:
    c, s, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap")
    jobs = s.recorder.library.jobs
    before = jobs.started
    answers = [c.get(f"/api/v1/recordings/{path.name}/timeline").content for _ in range(8)]
    assert jobs.started == before + 1
    assert len(set(answers)) == 1 and json.loads(answers[0])["counts"]["/force"] == 2000
    kept = list((folder / ".review").glob("20260101-000000-r.timeline-*.json"))
    assert len(kept) == 1
    assert c.delete(f"/api/v1/recordings/{path.name}", headers=OP).status_code == 200
    assert not kept[0].exists() and not (folder / ".index" / f"{path.name}.json").exists()


def test_a_read_job_is_started_off_the_event_loop(
    app: tuple[TestClient, Services, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The job's process is started from a thread where no event loop runs. Before,
    uvloop's subprocess_exec forked the whole server on its event loop: 16 ms of a
    stalled loop per job in a ~300 MB server (the e-stop's worst case in bench.abuse)."""
    c, _, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap")
    loops_running: list[bool] = []
    popen = readjobs.subprocess.Popen

    def spy(*args: Any, **kwargs: Any) -> Any:
        try:
            asyncio.get_running_loop()
            loops_running.append(True)
        except RuntimeError:
            loops_running.append(False)
        return popen(*args, **kwargs)

    monkeypatch.setattr(readjobs.subprocess, "Popen", spy)
    assert c.get(f"/api/v1/recordings/{path.name}/timeline").status_code == 200
    assert loops_running == [False]


async def test_a_read_job_past_its_time_is_stopped_with_a_clear_error(tmp_path: Path) -> None:
    """A job that has not answered within its time is killed (its process reaped), and
    the read fails saying so; the next job runs."""
    path = write_recording(tmp_path / "20260101-000000-r.mcap")
    jobs = readjobs.ReadJobs(timeout_s=0.01)  # less than the job's interpreter takes to start
    request = {"kind": "summaries", "paths": [str(path)]}
    with pytest.raises(readjobs.ReadFailed, match=r"longer than 0\.01 s and was stopped"):
        await jobs.run("slow", request, privileged=True)
    jobs.timeout_s = 60.0
    answer = await jobs.run("again", request, privileged=True)
    assert answer["entries"][0]["file"] == path.name


def test_reads_have_a_budget_per_address_that_the_token_lifts(
    app: tuple[TestClient, Services, Path],
) -> None:
    c, s, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap", seconds=0.2)
    s.recorder.library.budgets.clock = lambda: 100.0  # no time passes: no refill
    codes = [c.get("/api/v1/recordings").status_code for _ in range(readjobs.READ_BURST + 5)]
    assert codes[: readjobs.READ_BURST] == [200] * readjobs.READ_BURST
    assert codes[readjobs.READ_BURST :] == [429] * 5
    refused = c.get("/api/v1/recordings")
    assert "too many recording reads" in refused.json()["detail"]
    assert all(c.get("/api/v1/recordings", headers=OP).status_code == 200 for _ in range(10))
    # a fresh budget: timelines not yet made each start a job, JOB_BURST of them
    s.recorder.library.budgets = readjobs.ReadBudgets(clock=lambda: 200.0)
    made = [
        c.get(f"/api/v1/recordings/{path.name}/timeline", params={"max_points": 10 + n})
        for n in range(readjobs.JOB_BURST + 1)
    ]
    assert [r.status_code for r in made] == [200] * readjobs.JOB_BURST + [429]
    assert "not yet read" in made[-1].json()["detail"]
    again = c.get(f"/api/v1/recordings/{path.name}/timeline", params={"max_points": 10})
    assert again.status_code == 200  # made already: no job, no job budget
    with_token = c.get(
        f"/api/v1/recordings/{path.name}/timeline", params={"max_points": 99}, headers=OP
    )
    assert with_token.status_code == 200


def test_a_refusal_is_answered_late_and_says_when_to_ask_again(
    app: tuple[TestClient, Services, Path],
) -> None:
    """A loop that repeats a refused read as fast as it is answered asks at most
    1/REFUSAL_DELAY_S times a second per connection (bench.abuse: the e-stop's worst
    went from 26.7 to 13 ms when refusals stopped coming back at once)."""
    c, s, _folder = app
    s.recorder.library.budgets = readjobs.ReadBudgets(clock=lambda: 400.0)  # no refill
    for _ in range(readjobs.READ_BURST):
        assert c.get("/api/v1/recordings").status_code == 200
    started = time.monotonic()
    refused = c.get("/api/v1/recordings")
    assert refused.status_code == 429 and refused.headers["retry-after"] == "1"
    assert time.monotonic() - started >= REFUSAL_DELAY_S
    answered = time.monotonic()
    assert c.get("/api/v1/recordings", headers=OP).status_code == 200
    assert time.monotonic() - answered < 5  # the token's reads are never delayed


def test_what_a_read_sends_is_charged_to_its_address(
    app: tuple[TestClient, Services, Path],
) -> None:
    """A loop of reads of a kept file costs its bytes: a tokenless address may take
    about READS_PER_S × BYTES_PER_READ a second, not whatever the server can send."""
    c, s, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap", seconds=2.0)
    size = path.stat().st_size
    s.recorder.library.budgets = readjobs.ReadBudgets(clock=lambda: 300.0)  # no refill
    url = f"/api/v1/recordings/{path.name}/download"
    reads = readjobs.READ_BURST / (1 + size / readjobs.BYTES_PER_READ)
    codes = [c.get(url).status_code for _ in range(int(reads) + 2)]
    assert codes[: int(reads) - 1] == [200] * (int(reads) - 1)
    assert codes[-1] == 429, (size, reads, codes)
    # a range costs what it sends; the token is never charged
    s.recorder.library.budgets = readjobs.ReadBudgets(clock=lambda: 400.0)
    n = readjobs.READ_BURST - 1  # each costs a read and 100 bytes
    small = [c.get(url, headers={"Range": "bytes=0-99"}) for _ in range(n)]
    assert [r.status_code for r in small] == [206] * n
    assert all(c.get(url, headers=OP).status_code == 200 for _ in range(int(reads) + 2))


# ---------------------------------------------------------------- size cap, full disk
def _events(rec: Recorder) -> list[RecordingEvent]:
    seen: list[RecordingEvent] = []
    rec.events.subscribe(seen.append)
    return seen


async def _log_until_stopped(rec: Recorder, seconds: float = 60.0) -> None:
    deadline = time.monotonic() + seconds
    seq = 0
    while rec.active:
        assert time.monotonic() < deadline, "the recording did not stop by itself"
        for _ in range(500):
            rec.log("/force", {"seq": seq, "values": list(os.urandom(48))})
            seq += 1
        await asyncio.sleep(0.01)


async def test_the_size_cap_stops_the_recording_and_the_list_keeps_why(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, MonotonicClock(), chunk_bytes=4096, max_bytes=200_000)
    seen = _events(rec)
    path = rec.start("capped")
    await _log_until_stopped(rec)
    assert seen[-1].kind == "stopped" and seen[-1].reason.startswith("size cap reached"), seen
    (entry,) = Recorder(tmp_path, MonotonicClock()).listing()  # a new server: from the index
    assert entry["file"] == path.name and entry["complete"]
    assert entry["stop_reason"].startswith("size cap reached")
    assert "recording_max_bytes" in entry["stop_reason"]


async def test_a_nearly_full_disk_stops_the_recording_and_the_list_keeps_why(
    tmp_path: Path,
) -> None:
    free = [10**9]
    rec = Recorder(tmp_path, MonotonicClock(), chunk_bytes=4096, free_bytes=lambda _p: free[0])
    seen = _events(rec)
    path = rec.start("filling")
    free[0] = 1024**2  # the disk fills while it records
    await _log_until_stopped(rec)
    assert "disk is nearly full" in seen[-1].reason
    (entry,) = rec.listing()
    assert entry["file"] == path.name and entry["complete"]
    assert "disk is nearly full" in entry["stop_reason"]
    with pytest.raises(RecordingNoSpace, match="disk is nearly full"):
        rec.start("again")
    assert not rec.active
    assert [n for n in os.listdir(tmp_path) if n.endswith(".mcap")] == [path.name]


async def test_a_killed_writer_s_reason_is_kept_in_the_list(tmp_path: Path) -> None:
    """Its file has no summary to hold the reason: the index does."""
    rec = Recorder(tmp_path, MonotonicClock(), chunk_bytes=1024)
    path = rec.start("killed")
    assert rec._active is not None
    for seq in range(2000):
        rec.log("/force", {"seq": seq})
    deadline = time.monotonic() + 30
    while rec.status()["bytes"] == 0:  # type: ignore[index]
        assert time.monotonic() < deadline
        await asyncio.sleep(0.05)
    os.kill(rec._active.process.pid, signal.SIGKILL)  # type: ignore[arg-type]
    while rec.active:
        assert time.monotonic() < deadline
        await asyncio.sleep(0.05)
    (entry,) = Recorder(tmp_path, MonotonicClock()).listing()
    assert entry["file"] == path.name and not entry["complete"]
    assert "killed (signal 9)" in entry["stop_reason"], entry


def test_a_start_on_a_full_disk_is_refused(tmp_path: Path) -> None:
    """A real server whose disk has less free space than a recording needs."""
    env = {"TELEROBOT_VIDEO": "false", "TELEROBOT_RECORDING_MIN_FREE_BYTES": str(10**18)}
    with serving(env, "--state-dir", str(tmp_path)) as base, httpx.Client(base_url=base) as http:
        r = http.post("api/v1/recordings", json={"name": "full"}, headers=OP)
        assert r.status_code == 507, r.text
        assert "disk is nearly full" in r.json()["detail"]
        assert "recording_min_free_bytes" in r.json()["detail"]
        assert http.get("api/v1/recordings/active").json()["recording"] is False
    assert not list((tmp_path / "recordings").glob("*.mcap"))


def test_log_times_never_go_back_within_a_file(tmp_path: Path) -> None:
    """Messages taken on several threads reach the writer in queue order, one a few ms
    after a later one: ``mcap doctor`` warned of messages logged before one already in
    the file. Log times now never go back; each message's own time is its publish time."""
    from mcap.reader import make_reader

    path = tmp_path / "order.mcap"
    f = McapFile(path)
    taken = [1_000, 3_000, 2_000, 4_000, 3_500, 5_000]  # ns: two came late
    for i, t in enumerate(taken):
        f.write("/force" if i % 2 else "/robot/state", t, {"t": t})
    f.close({})
    with path.open("rb") as stream:
        messages = [m for _, _, m in make_reader(stream).iter_messages(log_time_order=False)]
    logged = [m.log_time for m in messages]
    assert logged == sorted(logged) == [1_000, 3_000, 3_000, 4_000, 4_000, 5_000]
    assert [m.publish_time for m in messages] == taken


def test_tokenless_reads_from_many_addresses_share_one_budget() -> None:
    """Each address within its own budget, many addresses together are not: a budget
    per address alone grew with the addresses a client had (six loopback ones raised
    the operator's stale command drops ninefold)."""
    budgets = readjobs.ReadBudgets(clock=lambda: 300.0)  # no time passes: no refill
    served = 0
    with pytest.raises(readjobs.TooManyReads, match="in all, whatever their addresses"):
        for n in range(1000):
            budgets.read(f"127.0.0.{n % 50}")  # 50 addresses, each far below its own burst
            served += 1
    assert served == readjobs.ALL_READ_BURST
    # the bytes an answer sends count against everyone's budget too
    budgets = readjobs.ReadBudgets(clock=lambda: 300.0)
    budgets.sent("10.0.0.1", readjobs.ALL_READ_BURST * readjobs.BYTES_PER_READ)
    with pytest.raises(readjobs.TooManyReads, match="in all"):
        budgets.read("10.0.0.2")


def test_a_timeline_names_clients_by_alias_never_by_their_id(tmp_path: Path) -> None:
    """The timeline is read without a token; a client's live id in it opened that
    client's own figures to anyone. Each id is "client-N" in the order seen, so the
    review still tells who drove from who was refused."""
    from telerobot.server.recording.timeline import timeline

    path = tmp_path / "r.mcap"
    build(path, duration=1.0)
    commands = timeline(path, ["/commands"], 100)["topics"]["/commands"]
    assert commands, "no commands in the timeline"
    text = json.dumps(commands)
    assert '"c1"' not in text and '"c2"' not in text
    assert {c["client_id"] for c in commands} == {"client-1", "client-2"}
    assert {c["lease_holder"] for c in commands} == {"client-1"}
