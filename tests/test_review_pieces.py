"""The review's timeline in pieces (issue 55): ``GET …/timeline?start_s=&end_s=`` gives
the messages logged in that range, kept as the whole timeline keeps them, so the pieces
of a partition put end to end are the whole (samples, strides, events, client names);
a file without a summary is read as far as it is valid for any piece; a piece of a file
with its summary reads only the chunks it needs (and those before it once); the range
has limits; pieces are kept, a bounded number of them; a page's pieces fit a tokenless
reader's budget. And the reader under them: through the index, the same messages in the
same order as the ``mcap`` package's reader."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from harness.recordings import build
from telerobot.server.app import create_app
from telerobot.server.realtime.ratelimit import PeerLimits
from telerobot.server.recording import reader, readjobs
from telerobot.server.recording.library import TIMELINE_PIECES
from telerobot.server.recording.reader import IndexedRecording, read_raw
from telerobot.server.recording.timeline import MAX_RANGE_S, REVIEW_TOPICS, timeline
from telerobot.server.services import Services
from telerobot.server.settings import Settings
from tests.support import TOKEN
from tests.test_recordings_hardening import write_recording

OP = {"Authorization": f"Bearer {TOKEN}"}
ALL = list(REVIEW_TOPICS)
# The review page's pieces (web/src/review/recording.ts, pieceAfter): 0-10, 10-50, 50-210…
FIRST_PIECE_S, GROWTH = 10.0, 4


def page_pieces(duration: float) -> list[tuple[float, float | None]]:
    out: list[tuple[float, float | None]] = []
    start = 0.0
    while True:
        end = GROWTH * start + FIRST_PIECE_S
        if out and end >= duration:
            out.append((start, None))
            return out
        out.append((start, end))
        if end > duration:
            return out
        start = end


def joined(pieces: list[dict[str, Any]], topics: list[str]) -> dict[str, list[Any]]:
    return {t: [m for p in pieces for m in p["topics"].get(t, [])] for t in topics}


def assert_pieces_make_the_whole(
    path: Path, cuts: list[float], max_points: int, walk: Path | None = None
) -> dict[str, Any]:
    whole = timeline(path, ALL, max_points)
    ranges = list(zip([0.0, *cuts], [*cuts, None], strict=True))
    pieces = [timeline(path, ALL, max_points, a, b, walk=walk) for a, b in ranges]
    assert joined(pieces, list(whole["topics"])) == whole["topics"]
    for piece, (a, b) in zip(pieces, ranges, strict=True):
        for key in ("start", "duration", "video_start", "complete", "counts", "stride"):
            assert piece[key] == whole[key], key
        assert piece["range_start"] == a
        assert piece["range_end"] == (whole["duration"] if b is None else min(b, whole["duration"]))
        for series in piece["topics"].values():
            assert all(a <= m["time"] and (b is None or m["time"] < b) for m in series)
    return whole


# ---------------------------------------------------------------- the pieces are the whole
@pytest.fixture(scope="module")
def long_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """25 s: 1 kHz forces, 50 Hz states, commands from two clients (one refused), episodes,
    video; small chunks, as a long recording has many."""
    path = tmp_path_factory.mktemp("pieces") / "20260101-000000-long.mcap"
    return build(path, duration=25.0, width=64, height=32, video_fps=10).path


@pytest.fixture(scope="module")
def many_chunks(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """25 s as the recorder's writer writes it, in 16 kB chunks: many of them."""
    path = tmp_path_factory.mktemp("chunks") / "20260101-000000-chunks.mcap"
    return write_recording(path, seconds=25.0)


@pytest.mark.parametrize("max_points", [100, 4000])
def test_the_pieces_of_a_partition_put_end_to_end_are_the_whole_timeline(
    long_recording: Path, many_chunks: Path, tmp_path: Path, max_points: int
) -> None:
    cuts = [0.5, 1.7, 10.0, 12.3456, 24.9]
    whole = assert_pieces_make_the_whole(long_recording, cuts, max_points, walk=tmp_path / "a")
    assert whole["stride"]["/force"] == math.ceil(25_000 / max_points)
    assert len(whole["topics"]["/force"]) == math.ceil(25_000 / whole["stride"]["/force"])
    # (the two clients named as the whole names them, in every piece)
    assert {c["client_id"] for c in whole["topics"]["/commands"]} == {"client-1", "client-2"}
    whole = assert_pieces_make_the_whole(many_chunks, cuts, max_points, walk=tmp_path / "b")
    assert len(whole["topics"]["/force"]) == math.ceil(25_000 / whole["stride"]["/force"])


def test_a_piece_asked_before_the_one_the_walk_is_at_is_still_the_whole_s(
    long_recording: Path, tmp_path: Path
) -> None:
    """What a piece learnt of the chunks before it is kept for the next; asked out of
    order (a later piece first, then an earlier one), each is still what the whole keeps."""
    walk = tmp_path / "walk.json"
    whole = timeline(long_recording, ALL, 500)
    late = timeline(long_recording, ALL, 500, 20.0, None, walk=walk)
    assert walk.exists()
    early = timeline(long_recording, ALL, 500, 0.0, 5.0, walk=walk)
    middle = timeline(long_recording, ALL, 500, 5.0, 20.0, walk=walk)
    assert joined([early, middle, late], list(whole["topics"])) == whole["topics"]
    # A walk kept of another file (or of this one before it changed) is not used.
    walk.write_text(json.dumps({**json.loads(walk.read_text()), "size": 1}))
    again = timeline(long_recording, ALL, 500, 20.0, None, walk=walk)
    assert again["topics"] == late["topics"]


@pytest.mark.parametrize("how", ["killed writer", "torn", "one byte short"])
def test_a_piece_of_a_file_without_a_summary_still_works(tmp_path: Path, how: str) -> None:
    path = tmp_path / "20260101-000000-r.mcap"
    if how == "killed writer":
        write_recording(path, seconds=6.0, close=False)
    else:
        whole_file = write_recording(tmp_path / "whole.mcap", seconds=6.0).read_bytes()
        path.write_bytes(
            whole_file[: len(whole_file) * 2 // 3] if how == "torn" else whole_file[:-1]
        )
    whole = assert_pieces_make_the_whole(path, [1.0, 2.5, 3.0], 100)
    assert whole["complete"] is False and whole["topics"]["/force"]
    assert len(whole["topics"]["/force"]) <= 100


def test_a_piece_reads_only_the_chunks_it_needs(
    many_chunks: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Through the summary's chunk indexes: the first piece inflates the chunks of its
    range, not the file's others; each next piece goes on from the chunk the one before
    ended in (read by both: the boundary falls in it), not from the file's start."""
    read: list[int] = []
    real = IndexedRecording.read

    def counted(self: IndexedRecording, chunk: Any) -> Any:
        read.append(chunk.chunk_start_offset)
        return real(self, chunk)

    monkeypatch.setattr(IndexedRecording, "read", counted)
    with open(many_chunks, "rb") as f:
        chunks = len(make_reader(f).get_summary().chunk_indexes)  # type: ignore[union-attr]
    assert chunks > 40
    walk = tmp_path / "walk.json"
    before: set[int] = set()
    for a in range(0, 25, 5):
        read.clear()
        timeline(many_chunks, ALL, 4000, float(a), float(a + 5), walk=walk)
        assert 0 < len(read) < chunks / 3, (a, len(read), chunks)
        assert len(set(read) & before) <= 1, a  # the boundary's chunk, at most
        before |= set(read)
    assert len(before) == chunks  # every chunk read, each once but for the boundaries


# ---------------------------------------------------------------- over the API
def _settings(state: Path) -> Settings:
    return Settings(
        state_dir=state, video=False, viewer=False, priority_port=0, operator_token=TOKEN
    )


@pytest.fixture
def app(tmp_path: Path) -> Iterator[tuple[TestClient, Services, Path]]:
    folder = tmp_path / "recordings"
    folder.mkdir()
    with TestClient(create_app(_settings(tmp_path)), base_url="http://127.0.0.1") as c:
        yield c, c.app.state.services, folder  # type: ignore[attr-defined]


def test_the_page_s_pieces_over_the_api_are_the_whole_and_fit_a_tokenless_budget(
    app: tuple[TestClient, Services, Path], long_recording: Path
) -> None:
    """A tokenless page on a fresh budget that does not refill: its list, the recording's
    pieces as the page asks for them, and the video all answered (2-minute recordings
    come in 3 pieces; this one in 2), each piece made once and kept."""
    c, s, folder = app
    path = folder / long_recording.name
    path.write_bytes(long_recording.read_bytes())
    s.recorder.library.budgets = readjobs.ReadBudgets(clock=lambda: 50.0)  # no refill
    assert c.get("/api/v1/recordings").status_code == 200
    whole = c.get(f"/api/v1/recordings/{path.name}/timeline", params={"max_points": 4000})
    assert whole.status_code == 200
    pieces = []
    for a, b in page_pieces(whole.json()["duration"]):
        query: dict[str, Any] = {"max_points": 4000, "start_s": a}
        if b is not None:
            query["end_s"] = b
        r = c.get(f"/api/v1/recordings/{path.name}/timeline", params=query)
        assert r.status_code == 200, r.text
        pieces.append(r.json())
    assert c.get(f"/api/v1/recordings/{path.name}/video.mp4").status_code == 200
    assert len(pieces) == 2
    assert joined(pieces, list(whole.json()["topics"])) == whole.json()["topics"]
    started = s.recorder.library.jobs.started
    again = c.get(
        f"/api/v1/recordings/{path.name}/timeline",
        params={"max_points": 4000, "start_s": 0, "end_s": FIRST_PIECE_S},
    )
    assert again.json() == pieces[0] and s.recorder.library.jobs.started == started  # kept


def test_a_2_minute_recording_is_3_pieces() -> None:
    assert page_pieces(126.0) == [(0.0, 10.0), (10.0, 50.0), (50.0, None)]


@pytest.mark.parametrize(
    ("query", "words"),
    [
        ({"start_s": -1}, "greater than or equal"),
        ({"end_s": 0}, "greater than"),
        ({"start_s": 5, "end_s": 5}, "must be after start_s"),
        ({"start_s": 5, "end_s": 2}, "must be after start_s"),
        ({"end_s": MAX_RANGE_S * 2}, "less than or equal"),
        ({"start_s": "nan"}, ""),
        ({"end_s": "inf"}, ""),
    ],
)
def test_a_piece_s_range_has_limits(
    app: tuple[TestClient, Services, Path], query: dict[str, Any], words: str
) -> None:
    c, s, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap", seconds=1.0)
    started = s.recorder.library.jobs.started
    r = c.get(f"/api/v1/recordings/{path.name}/timeline", params=query)
    assert r.status_code == 422, r.text
    assert words in r.text
    assert s.recorder.library.jobs.started == started  # refused before any read


def test_a_piece_past_the_end_is_empty_not_an_error(app: tuple[TestClient, Services, Path]) -> None:
    c, _s, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap", seconds=1.0)
    r = c.get(f"/api/v1/recordings/{path.name}/timeline", params={"start_s": 100, "end_s": 200})
    assert r.status_code == 200, r.text
    tl = r.json()
    assert all(series == [] for series in tl["topics"].values())
    assert tl["range_start"] == 100 and tl["range_end"] == tl["duration"] < 2


def test_pieces_are_kept_a_bounded_number_per_recording(
    app: tuple[TestClient, Services, Path],
) -> None:
    c, s, folder = app
    s.recorder.library.budgets.jobs = PeerLimits(connections_per_s=1000.0, connection_burst=1000)
    path = write_recording(folder / "20260101-000000-r.mcap", seconds=1.0)
    for k in range(TIMELINE_PIECES + 4):
        r = c.get(
            f"/api/v1/recordings/{path.name}/timeline",
            params={"start_s": k / 100, "end_s": (k + 1) / 100},
            headers=OP,
        )
        assert r.status_code == 200, r.text
    kept = list((folder / ".review").glob(f"{path.stem}.piece-*.json"))
    assert len(kept) == TIMELINE_PIECES
    assert len(list((folder / ".review").glob(f"{path.stem}.walk-*.json"))) == 1
    assert c.delete(f"/api/v1/recordings/{path.name}", headers=OP).status_code == 200
    assert not list((folder / ".review").glob(f"{path.stem}.*"))


def test_the_video_of_a_recording_indexed_without_one_is_refused_without_a_job(
    app: tuple[TestClient, Services, Path],
) -> None:
    """The review page asks for the video at once, before the timeline says whether
    there is one: the index answers (404), no job is started."""
    c, s, folder = app
    path = write_recording(folder / "20260101-000000-r.mcap", seconds=0.5)
    assert c.get("/api/v1/recordings").status_code == 200  # indexed
    started = s.recorder.library.jobs.started
    r = c.get(f"/api/v1/recordings/{path.name}/video.mp4")
    assert r.status_code == 404 and "holds no video" in r.text
    assert s.recorder.library.jobs.started == started


# ---------------------------------------------------------------- the reader under them
def _mcap_read(path: Path, topics: list[str] | None, in_file_order: bool) -> list[Any]:
    with open(path, "rb") as f:
        return [
            (c.topic, m.log_time, m.data, c.message_encoding)
            for _s, c, m in make_reader(f).iter_messages(
                topics=topics, log_time_order=not in_file_order
            )
        ]


def _overlapping_chunks(path: Path, compression: CompressionType = CompressionType.ZSTD) -> Path:
    """Chunks whose times overlap (messages written out of time order, as threads racing
    by a few µs do, far more here), two channels, equal times."""
    with path.open("wb") as f:
        w = Writer(f, chunk_size=300, compression=compression)
        w.start(profile="", library="test")
        s = w.register_schema("s", "jsonschema", b"{}")
        a = w.register_channel("/a", "json", s)
        b = w.register_channel("/b", "json", s)
        for i in range(400):
            t = 1_000_000 + (i * 7919) % 997 * 1000  # a scramble of times, some repeated
            w.add_message(a if i % 3 else b, t, json.dumps({"i": i}).encode(), t, i)
        w.finish()  # type: ignore[no-untyped-call]
    return path


@pytest.mark.parametrize("in_file_order", [False, True])
@pytest.mark.parametrize("topics", [None, ["/a"], ["/b", "/nothing"]])
def test_the_indexed_reader_reads_what_the_mcap_package_reads(
    tmp_path: Path, long_recording: Path, in_file_order: bool, topics: list[str] | None
) -> None:
    for compression in CompressionType:  # zstd (the recorder's), lz4, none
        scrambled = _overlapping_chunks(tmp_path / f"{compression.name}.mcap", compression)
        got = list(read_raw(scrambled, topics, in_file_order=in_file_order))
        assert got == _mcap_read(scrambled, topics, in_file_order)
        assert len(got) > 100 or topics is not None
    real = ["/force", "/video/stereo"] if topics else None
    assert list(read_raw(long_recording, real, in_file_order=in_file_order)) == _mcap_read(
        long_recording, real, in_file_order
    )


def test_a_chunk_that_inflates_past_what_its_index_says_is_refused(tmp_path: Path) -> None:
    """A crafted file cannot make the reader allocate more than its index admits."""
    path = _overlapping_chunks(tmp_path / "r.mcap")
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    first = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = bytearray(path.read_bytes())
    at = first.chunk_start_offset + 1 + 8 + 8 + 8  # the chunk's uncompressed size
    data[at : at + 8] = (first.uncompressed_size - 10).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(reader.UnreadableRecording, match="damaged"):
        list(read_raw(path))


def test_a_chunk_not_where_its_index_says_is_refused_as_damaged(tmp_path: Path) -> None:
    path = build(tmp_path / "r.mcap", duration=1.0, width=32, height=16).path
    with open(path, "rb") as f:
        first = make_reader(f).get_summary().chunk_indexes[0]  # type: ignore[union-attr]
    data = bytearray(path.read_bytes())
    data[first.chunk_start_offset] = 0x42  # not a chunk's opcode
    path.write_bytes(bytes(data))
    with pytest.raises(reader.UnreadableRecording, match="damaged where its index points"):
        list(read_raw(path))


# ---------------------------------------------------------------- the jobs' order
class _Recorded(readjobs.ReadJobs):
    """Jobs that record the order they ran in and end when told (no process)."""

    def __init__(self) -> None:
        super().__init__()
        self.ran: list[str] = []
        self.started: dict[str, asyncio.Event] = {}
        self.release: dict[str, asyncio.Event] = {}

    def event(self, events: dict[str, asyncio.Event], name: str) -> asyncio.Event:
        return events.setdefault(name, asyncio.Event())

    async def _in_process(self, request: dict[str, Any]) -> dict[str, Any]:
        self.ran.append(request["name"])
        self.event(self.started, request["name"]).set()
        await self.event(self.release, request["name"]).wait()
        return {"name": request["name"]}


async def test_waiting_jobs_run_by_priority_then_in_the_order_asked() -> None:
    """The review's video before the timeline's first piece before the rest, whatever
    order they were asked in; a job whose waiter goes away does not hold the line."""
    jobs = _Recorded()

    def ask(name: str, priority: int) -> asyncio.Task[dict[str, Any]]:
        return asyncio.ensure_future(
            jobs.run(name, {"name": name}, privileged=True, priority=priority)
        )

    async def finish(name: str) -> None:
        await asyncio.wait_for(jobs.event(jobs.started, name).wait(), 10)
        jobs.event(jobs.release, name).set()

    running = ask("list", readjobs.LATER)
    await asyncio.sleep(0)
    later = [ask("piece 2", readjobs.LATER), ask("piece 3", readjobs.LATER)]
    first_piece = ask("piece 1", readjobs.NEXT)
    video = ask("video", readjobs.FIRST)
    gone = ask("gone", readjobs.FIRST)
    await asyncio.sleep(0)
    jobs._jobs["gone"].cancel()  # (its client gone and the job with it: server shutting down)
    for name in ("list", "video", "piece 1", "piece 2", "piece 3"):
        await finish(name)
    await asyncio.gather(running, video, first_piece, *later)
    assert jobs.ran == ["list", "video", "piece 1", "piece 2", "piece 3"]
    with pytest.raises(asyncio.CancelledError):
        await gone
    assert not jobs._busy and not jobs._line
