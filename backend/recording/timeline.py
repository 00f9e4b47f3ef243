"""A recording's channels on one timeline for the review page (web/review.html): forces
and states decimated to a bounded number of points, events (commands, safety,
episodes, calibration, who drove) as they are up to a bounded number, each message with ``time``
(s from the recording's first message) added. A multi-arm recording's arms' states and
forces (``/arms/<name>/state``, ``/arms/<name>/force``) come with ``/robot/state`` and
``/force`` (each arm's a series of its own), and ``/arms`` says which arms there are.

Computed by ``readjobs`` in a process of its own and kept beside the recording (the
review reads it many times; the server's interpreter never decodes the file). Bounded
whatever the file holds: ``MAX_POINTS`` per series, ``MAX_EVENTS`` per event topic,
``MAX_TOPIC_BYTES`` of payload per topic; only the messages kept are decoded. A file
without a summary (a writer killed, a copy cut short) is read as far as it is valid.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

from telerobot.server.recording import schemas as ch
from telerobot.server.recording.reader import read_raw, valid_summary
from telerobot.server.recording.schemas import VIDEO as VIDEO_TOPIC

MAX_POINTS = 20_000  # per decimated series (force, state): a page plots this many at most
MAX_EVENTS = 5_000  # commands, safety changes, episodes: the first this many
MAX_TOPIC_BYTES = 4 * 1024 * 1024  # of one topic's kept payloads (a foreign file's may be big)
MAX_ARMS = 16  # arms' series kept (a server drives at most 8; a foreign file may name more)
SERIES = ("/force", "/robot/state")
# Fields that hold a live client's id: the timeline is read without a token, and an id
# opened that client's own figures to anyone (GET /safety?client=); each id becomes
# "client-N" in the order it first appears (the review still tells clients apart).
CLIENT_ID_FIELDS = ("client_id", "lease_holder")
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


def _asked_as(topic: str) -> str:
    """The review topic that asks for ``topic``: an arm's state or force channel is
    asked for with ``/robot/state`` or ``/force``; any other is itself."""
    arm = ch.arm_of(topic)
    if arm is None:
        return topic
    return ch.ROBOT_STATE if arm[1] == ch.ARM_STATE else ch.FORCE


def _counts_in_summary(path: str | os.PathLike[str]) -> dict[str, int] | None:
    with open(path, "rb") as f:
        s = valid_summary(f)
    if s is None or s.statistics is None:
        return None
    return {s.channels[c].topic: n for c, n in s.statistics.channel_message_counts.items()}


def _payload(data: bytes) -> dict[str, Any] | None:
    try:
        m = json.loads(data)
    except ValueError:  # a foreign file's message that is not JSON: left out
        return None
    return m if isinstance(m, dict) else {"value": m}


def timeline(path: str | os.PathLike[str], topics: list[str], max_points: int) -> dict[str, Any]:
    """The ``Timeline`` of ``backend/api/recording_review.py`` as a dict. A series's
    stride is exact when the file has its summary (its counts); without one it starts
    at 1 and doubles whenever the series would pass ``max_points``."""
    summary_counts = _counts_in_summary(path)
    complete = summary_counts is not None
    known = summary_counts or {}
    stride = {t: max(1, math.ceil(known.get(t, 0) / max_points)) for t in topics if t in SERIES}
    out: dict[str, list[dict[str, Any]]] = {t: [] for t in topics}
    kept_bytes: dict[str, int] = dict.fromkeys(topics, 0)
    asked = set(topics)
    arm_series = 0
    aliases: dict[str, str] = {}  # a client's id → its name here
    counts: dict[str, int] = {}
    first_ns: int | None = None
    last_ns = 0
    video_start: float | None = None
    for topic, log_ns, data, encoding in read_raw(path):
        i = counts.get(topic, 0)
        counts[topic] = i + 1
        if first_ns is None:
            first_ns = log_ns
        last_ns = max(last_ns, log_ns)
        if topic == VIDEO_TOPIC:
            if video_start is None and encoding == "json":
                ts = (_payload(data) or {}).get("timestamp") or {}
                if isinstance(ts, dict):
                    video_start = float(ts.get("sec", 0)) + float(ts.get("nsec", 0)) / 1e9
            continue
        if topic not in out and _asked_as(topic) in asked and arm_series < MAX_ARMS:
            # An arm's state or forces (a multi-arm recording): a series like /robot/state's.
            arm_series += 1
            out[topic], kept_bytes[topic] = [], 0
            stride[topic] = max(1, math.ceil(known.get(topic, 0) / max_points))
        if topic not in out or encoding != "json":
            continue
        if topic in stride:
            if i % stride[topic]:
                continue
        elif len(out[topic]) >= MAX_EVENTS:
            continue
        if kept_bytes[topic] + len(data) > MAX_TOPIC_BYTES:
            continue
        m = _payload(data)
        if m is None:
            continue
        kept_bytes[topic] += len(data)
        series = out[topic]
        for key in CLIENT_ID_FIELDS:
            if isinstance(m.get(key), str) and m[key]:
                m[key] = aliases.setdefault(m[key], f"client-{len(aliases) + 1}")
        series.append({**m, "time": (log_ns - first_ns) / 1e9})
        if topic in stride and len(series) > max_points:  # no summary said how many
            series[:] = series[::2]
            stride[topic] *= 2
            kept_bytes[topic] //= 2
    start = (first_ns or 0) / 1e9
    return {
        "start": start,
        "duration": (last_ns - (first_ns or 0)) / 1e9,
        "video_start": None if video_start is None else video_start - start,
        "complete": complete,
        "counts": counts,
        "stride": stride,
        "topics": out,
    }
