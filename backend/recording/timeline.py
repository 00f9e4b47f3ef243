"""A recording's channels on one timeline for the review page (web/review.html): forces
and states decimated to a bounded number of points, events (commands, safety,
episodes, calibration, who drove) as they are up to a bounded number, each message with ``time``
(s from the recording's first message) added. A multi-arm recording's arms' states and
forces (``/arms/<name>/state``, ``/arms/<name>/force``) come with ``/robot/state`` and
``/force`` (each arm's a series of its own), and ``/arms`` says which arms there are.

**In pieces.** ``start_s``/``end_s`` ask for the messages logged in that range of the
timeline only (the review page loads a long recording a piece at a time, the first
small, so its first seconds show at once). What a message's place in the whole
decides is decided the same in a piece, so the pieces of a partition of the timeline,
put end to end, are the whole timeline:

- a series keeps every ``stride``-th message of its topic, counted in file order over
  the whole file (``stride`` from the whole file's counts: its summary's);
- an event topic keeps its first ``MAX_EVENTS`` messages of the whole file;
- a client's id becomes ``client-N`` in the order the ids first appear in the whole
  file's ``/commands`` and ``/safety`` (their first ``MAX_EVENTS`` messages each);
- ``start``, ``duration``, ``video_start``, ``counts`` and ``stride`` are the whole
  recording's.

(Only ``MAX_TOPIC_BYTES`` is per answer: a foreign file's topic that big is cut in each
piece.) A file with its summary is read through its index: a piece inflates only the
chunks that overlap its range, and those before it only to count messages and learn
client ids, once per recording (``walk``: what was learnt up to the chunk a piece ends
in, kept beside the timelines, so the next piece goes on from there). A file without a
summary (a writer killed, a copy cut short) is read as far as it is valid, all of it
for any piece (nothing says where a time is in it without reading it).

Computed by ``readjobs`` in a process of its own and kept beside the recording (the
review reads it many times; the server's interpreter never decodes the file). Bounded
whatever the file holds: ``MAX_POINTS`` per series, ``MAX_EVENTS`` per event topic,
``MAX_TOPIC_BYTES`` of payload per topic; only the messages kept are decoded.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from pathlib import Path
from typing import Any

from telerobot.server.recording import schemas as ch
from telerobot.server.recording.reader import IndexedRecording, indexed
from telerobot.server.recording.schemas import VIDEO as VIDEO_TOPIC

MAX_POINTS = 20_000  # per decimated series (force, state): a page plots this many at most
MAX_EVENTS = 5_000  # commands, safety changes, episodes: the first this many
MAX_TOPIC_BYTES = 4 * 1024 * 1024  # of one topic's kept payloads (a foreign file's may be big)
MAX_ARMS = 16  # arms' series kept (a server drives at most 8; a foreign file may name more)
MAX_RANGE_S = 7 * 24 * 3600.0  # a piece's start and end (s): a week, far past any recording
SERIES = ("/force", "/robot/state")
# Fields that hold a live client's id: the timeline is read without a token, and an id
# opened that client's own figures to anyone (GET /safety?client=); each id becomes
# "client-N" in the order it first appears (the review still tells clients apart).
CLIENT_ID_FIELDS = ("client_id", "lease_holder")
NAMING_TOPICS = ("/commands", "/safety")  # the topics whose ids are numbered in file order
REVIEW_TOPICS = (
    "/force",  # with every arm's /arms/<name>/force (a multi-arm recording's)
    "/robot/state",  # with every arm's /arms/<name>/state
    "/commands",
    "/safety",
    "/episodes",
    "/calibration",
    "/autonomy",
    "/arms",  # (new ones last: the cache's topic masks of the others keep their bits)
)
WALK_VERSION = 1


def _asked_as(topic: str) -> str:
    """The review topic that asks for ``topic``: an arm's state or force channel is
    asked for with ``/robot/state`` or ``/force``; any other is itself."""
    arm = ch.arm_of(topic)
    if arm is None:
        return topic
    return ch.ROBOT_STATE if arm[1] == ch.ARM_STATE else ch.FORCE


def _payload(data: bytes) -> dict[str, Any] | None:
    try:
        m = json.loads(data)
    except ValueError:  # a foreign file's message that is not JSON: left out
        return None
    return m if isinstance(m, dict) else {"value": m}


def _stride(count: int, max_points: int) -> int:
    return max(1, math.ceil(count / max_points))


def _doubled_stride(count: int, max_points: int) -> int:
    """The stride a series of ``count`` ends with when it starts at 1 and doubles
    whenever it would pass ``max_points`` (a file without a summary's: its counts are
    known only at its end)."""
    stride = 1
    while math.ceil(count / stride) > max_points:
        stride *= 2
    return stride


def _video_start(payload: dict[str, Any] | None) -> float | None:
    ts = (payload or {}).get("timestamp") or {}
    if not isinstance(ts, dict):
        return None
    return float(ts.get("sec", 0)) + float(ts.get("nsec", 0)) / 1e9


class _Clients:
    """Client ids → "client-N", numbered in the order they first appear."""

    def __init__(self, seen: list[str] | None = None) -> None:
        self.order: list[str] = list(seen or [])
        self.alias = {c: f"client-{i + 1}" for i, c in enumerate(self.order)}

    def learn(self, m: dict[str, Any]) -> None:
        for key in CLIENT_ID_FIELDS:
            value = m.get(key)
            if isinstance(value, str) and value and value not in self.alias:
                self.order.append(value)
                self.alias[value] = f"client-{len(self.order)}"

    def hide(self, m: dict[str, Any]) -> None:
        self.learn(m)
        for key in CLIENT_ID_FIELDS:
            if isinstance(m.get(key), str) and m[key]:
                m[key] = self.alias[m[key]]


class _Kept:
    """What one answer keeps of each asked topic (series by stride, events up to
    ``MAX_EVENTS``, each topic's payloads up to ``MAX_TOPIC_BYTES``)."""

    def __init__(self, topics: list[str], stride: dict[str, int]) -> None:
        self.asked = set(topics)
        self.stride = stride
        self.out: dict[str, list[dict[str, Any]]] = {t: [] for t in topics}
        self.bytes: dict[str, int] = dict.fromkeys(topics, 0)
        self.arm_series = 0

    def wants(self, topic: str) -> bool:
        """Whether ``topic``'s messages are asked for (an arm's series: the first
        ``MAX_ARMS`` of them, from the first of its messages seen)."""
        if topic in self.out:
            return True
        if _asked_as(topic) in self.asked and self.arm_series < MAX_ARMS:
            self.arm_series += 1
            self.out[topic], self.bytes[topic] = [], 0
            return True
        return False

    def picks(self, topic: str, rank: int) -> bool:
        """Whether the ``rank``-th message of the topic (in file order) is one kept."""
        stride = self.stride.get(topic)
        return rank % stride == 0 if stride is not None else rank < MAX_EVENTS

    def keep(self, topic: str, m: dict[str, Any], size: int, time: float) -> bool:
        if self.bytes[topic] + size > MAX_TOPIC_BYTES:
            return False
        self.bytes[topic] += size
        self.out[topic].append({**m, "time": time})
        return True


def timeline(
    path: str | os.PathLike[str],
    topics: list[str],
    max_points: int,
    start_s: float | None = None,
    end_s: float | None = None,
    *,
    walk: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """The ``Timeline`` of ``backend/api/recording_review.py`` as a dict: the whole, or
    the messages logged in ``[start_s, end_s)`` (timeline s; None: from the start, to
    the end). ``walk``: where what a piece learnt of the chunks before it is kept."""
    with open(path, "rb") as f:
        through_index = indexed(f, path)
        if through_index is not None:
            return _through_index(
                through_index, Path(path), topics, max_points, start_s, end_s, walk
            )
    return _salvaged(path, topics, max_points, start_s, end_s)


def _answer(
    first_ns: int,
    last_ns: int,
    video_start: float | None,
    complete: bool,
    counts: dict[str, int],
    kept: _Kept,
    start_s: float | None,
    end_s: float | None,
) -> dict[str, Any]:
    start = first_ns / 1e9
    duration = (last_ns - first_ns) / 1e9
    for series in kept.out.values():
        series.sort(key=lambda m: m["time"])  # file order is log order but for µs races
    return {
        "start": start,
        "duration": duration,
        "video_start": None if video_start is None else video_start - start,
        "complete": complete,
        "counts": counts,
        "stride": kept.stride,
        "topics": kept.out,
        "range_start": start_s or 0.0,
        "range_end": duration if end_s is None else min(end_s, duration),
    }


# ---------------------------------------------------------------- a file with its summary
def _through_index(
    rec: IndexedRecording,
    path: Path,
    topics: list[str],
    max_points: int,
    start_s: float | None,
    end_s: float | None,
    walk: str | os.PathLike[str] | None,
) -> dict[str, Any]:
    stats = rec.summary.statistics
    assert stats is not None  # (valid_summary: a summary with its statistics)
    counts: dict[str, int] = {}
    for cid, n in stats.channel_message_counts.items():
        if cid in rec.channels:
            topic = rec.channels[cid].topic
            counts[topic] = counts.get(topic, 0) + n
    first_ns, last_ns = stats.message_start_time, stats.message_end_time
    lo = None if start_s is None else first_ns + round(start_s * 1e9)
    hi = None if end_s is None else first_ns + round(end_s * 1e9)
    stride = {t: _stride(counts.get(t, 0), max_points) for t in topics if t in SERIES}
    kept = _Kept(topics, stride)
    # Every arm's series, even one with no message in this piece (the page knows its arms
    # from the first piece), in the order the file registered them.
    for cid in sorted(rec.channels):
        topic = rec.channels[cid].topic
        if ch.arm_of(topic) is not None and kept.wants(topic):
            stride[topic] = _stride(counts.get(topic, 0), max_points)

    def overlaps(c: Any) -> bool:
        return (lo is None or c.message_end_time >= lo) and (
            hi is None or c.message_start_time < hi
        )

    inside = [k for k, c in enumerate(rec.chunks) if overlaps(c)]
    first_chunk, end_chunk = (inside[0], inside[-1] + 1) if inside else (0, 0)
    ranks: dict[str, int] = {}
    clients = _Clients()
    walked = 0
    kept_walk = _load_walk(walk, path)
    if kept_walk is not None and kept_walk["chunks"] <= first_chunk:
        walked, ranks, clients = (
            kept_walk["chunks"],
            kept_walk["ranks"],
            _Clients(kept_walk["clients"]),
        )
    topic_of = {cid: c.topic for cid, c in rec.channels.items()}
    encoding_of = {cid: c.message_encoding for cid, c in rec.channels.items()}
    # What is known at the start of this piece's last chunk is kept for the next piece,
    # whose range starts in that chunk (the chunk its boundary falls in).
    known: tuple[int, dict[str, int], list[str]] | None = None
    for k in range(walked, end_chunk):
        if k == end_chunk - 1:
            known = (k, dict(ranks), list(clients.order))
        got = rec.read(rec.chunks[k])
        for cid, log_ns, at, end in got.messages:
            topic = topic_of[cid]
            rank = ranks.get(topic, 0)
            ranks[topic] = rank + 1
            m: dict[str, Any] | None = None
            json_encoded = encoding_of[cid] == "json"
            if topic in NAMING_TOPICS and rank < MAX_EVENTS and json_encoded:
                m = _payload(got.data[at:end])
                if m is not None:
                    clients.learn(m)
            if (
                k < first_chunk
                or (lo is not None and log_ns < lo)
                or (hi is not None and log_ns >= hi)
            ):
                continue
            if not json_encoded or not kept.wants(topic) or not kept.picks(topic, rank):
                continue
            if m is None:
                m = _payload(got.data[at:end])
                if m is None:
                    continue
            clients.hide(m)
            kept.keep(topic, m, end - at, (log_ns - first_ns) / 1e9)
    if known is not None and (kept_walk is None or known[0] > kept_walk["chunks"]):
        _save_walk(walk, path, *known)
    video_start = _first_video(rec)
    return _answer(first_ns, last_ns, video_start, True, counts, kept, start_s, end_s)


def _first_video(rec: IndexedRecording) -> float | None:
    """The first recorded frame's capture time (wall clock s): from the first chunk that
    holds video (one chunk read)."""
    ids = {cid for cid, c in rec.channels.items() if c.topic == VIDEO_TOPIC}
    if not ids:
        return None
    for chunk in rec.chunks:
        if not rec.holds(chunk, ids):
            continue
        got = rec.read(chunk)
        for cid, _log_ns, at, end in got.messages:
            if cid in ids and rec.channels[cid].message_encoding == "json":
                return _video_start(_payload(got.data[at:end]))
    return None


def _load_walk(walk: str | os.PathLike[str] | None, path: Path) -> dict[str, Any] | None:
    """What an earlier piece learnt of this recording's first chunks, if it is of this
    very file (its size and time)."""
    if walk is None:
        return None
    try:
        kept = json.loads(Path(walk).read_bytes())
        stat = path.stat()
        if kept.get("v") != WALK_VERSION or [kept["size"], kept["mtime_ns"]] != [
            stat.st_size,
            stat.st_mtime_ns,
        ]:
            return None
        return {
            "chunks": int(kept["chunks"]),
            "ranks": {str(t): int(n) for t, n in kept["ranks"].items()},
            "clients": [str(c) for c in kept["clients"]],
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def _save_walk(
    walk: str | os.PathLike[str] | None,
    path: Path,
    chunks: int,
    ranks: dict[str, int],
    clients: list[str],
) -> None:
    if walk is None:
        return
    stat = path.stat()
    kept = {
        "v": WALK_VERSION,
        "size": stat.st_size,
        "mtime_ns": stat.st_mtime_ns,
        "chunks": chunks,
        "ranks": ranks,
        "clients": clients,
    }
    out = Path(walk)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    with contextlib.suppress(OSError):  # a cache: the next piece reads again without it
        tmp.write_text(json.dumps(kept))
        os.replace(tmp, out)


# ---------------------------------------------------------------- a file without one
def _salvaged(
    path: str | os.PathLike[str],
    topics: list[str],
    max_points: int,
    start_s: float | None,
    end_s: float | None,
) -> dict[str, Any]:
    """Read as far as it is valid, in file order, all of it (its counts are known only
    at its end): a series kept at a stride that doubles as it grows (bounded), then
    thinned to the stride the whole file's count gives."""
    from mcap.records import Channel, Message

    from telerobot.server.recording.salvage import SalvageReader

    salvage = SalvageReader(path)  # raises NotARecording for what is not an MCAP
    stride = {t: 1 for t in topics if t in SERIES}
    kept = _Kept(topics, stride)
    clients = _Clients()
    counts: dict[str, int] = {}
    first_ns: int | None = None
    lo = hi = None
    last_ns = 0
    video_start: float | None = None
    # A kept series message's rank and size (to thin it as it grows, and at the end).
    rank_of: dict[str, list[tuple[int, int]]] = {}
    for record in salvage.records():
        if isinstance(record, Channel):
            topic = record.topic
            if ch.arm_of(topic) is not None and kept.wants(topic):
                stride[topic] = 1
            continue
        if not isinstance(record, Message):
            continue
        channel = salvage.channels[record.channel_id]
        topic, log_ns, data = channel.topic, record.log_time, record.data
        rank = counts.get(topic, 0)
        counts[topic] = rank + 1
        if first_ns is None:
            first_ns = log_ns
            lo = None if start_s is None else first_ns + round(start_s * 1e9)
            hi = None if end_s is None else first_ns + round(end_s * 1e9)
        last_ns = max(last_ns, log_ns)
        json_encoded = channel.message_encoding == "json"
        if topic == VIDEO_TOPIC:
            if video_start is None and json_encoded:
                video_start = _video_start(_payload(data))
            continue
        m: dict[str, Any] | None = None
        if topic in NAMING_TOPICS and rank < MAX_EVENTS and json_encoded:
            m = _payload(data)
            if m is not None:
                clients.learn(m)
        if (lo is not None and log_ns < lo) or (hi is not None and log_ns >= hi):
            continue
        if not json_encoded or not kept.wants(topic) or not kept.picks(topic, rank):
            continue
        if m is None:
            m = _payload(data)
            if m is None:
                continue
        clients.hide(m)
        if kept.keep(topic, m, len(data), (log_ns - first_ns) / 1e9) and topic in stride:
            ranks = rank_of.setdefault(topic, [])
            ranks.append((rank, len(data)))
            if len(kept.out[topic]) > max_points:  # thinned as it grows: bounded
                stride[topic] *= 2
                _thin(kept, topic, ranks, stride[topic])
    for topic in list(stride):  # the whole file's stride, known now
        stride[topic] = _doubled_stride(counts.get(topic, 0), max_points)
        _thin(kept, topic, rank_of.get(topic, []), stride[topic])
    return _answer(first_ns or 0, last_ns, video_start, False, counts, kept, start_s, end_s)


def _thin(kept: _Kept, topic: str, ranks: list[tuple[int, int]], stride: int) -> None:
    """Keeps the series' messages whose rank is a multiple of ``stride``."""
    pairs = [(m, r) for m, r in zip(kept.out[topic], ranks, strict=True) if r[0] % stride == 0]
    kept.out[topic][:] = [m for m, _ in pairs]
    ranks[:] = [r for _, r in pairs]
    kept.bytes[topic] = sum(size for _, (_, size) in pairs)
