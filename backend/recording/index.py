"""What the recordings list shows, kept rather than re-read: one small JSON file per
recording in ``<recordings>/.index/`` (its name, size, duration, episodes, whether it
is complete and why it stopped, its topics' counts and metadata), written by the
recorder when a recording closes, or made once from the file's MCAP summary for a
recording it did not close (copied in, recovered, from before the index). The list
then never parses an MCAP file per request: with 223 recordings a tokenless client
listing in a loop had held the event loop (the e-stop's) for every summary.

What is kept is summarised and bounded: at most ``LISTED_EPISODES`` episodes, labels
cut to ``LABEL_CHARS``, metadata values to ``METADATA_CHARS`` (10 000 long episode
labels had made one listing 21 MB). An entry is trusted while the recording's size and
modification time are those it was made from; a recording rewritten (``recover``)
is summarised again.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

from telerobot.server.recording.reader import BROKEN, summary

INDEX_VERSION = 1
INDEX_DIR = ".index"
LISTED_EPISODES = 50  # per recording (``episode_count`` says how many it has)
LABEL_CHARS = 80  # of an episode's task and notes in a listing
NAME_CHARS = 64  # of a recording's name (the recorder keeps as many)
REASON_CHARS = 500  # of a stop reason
METADATA_CHARS = 500  # per metadata value
METADATA_KEYS = 64
MAX_TOPICS = 64  # counts kept per recording
SIDECAR_MAX_BYTES = 256 * 1024  # an index file larger than this is not ours: ignored
CACHED_ENTRIES = 256  # entries kept in memory (the rest are read from .index/ again)
NAMES_SETTLE_S = 2.0  # a folder changed this recently is listed again, not from memory


def _text(value: Any, limit: int) -> str:
    s = value if isinstance(value, str) else ("" if value is None else str(value))
    return s if len(s) <= limit else s[: limit - 1] + "…"


def _number(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _episode(raw: Any, n: int) -> dict[str, Any] | None:
    """One episode as the list shows it, from whatever a file's metadata holds (a
    foreign file's may hold anything: a malformed one is left out, never a 500)."""
    if not isinstance(raw, dict):
        return None
    episode = raw.get("episode", n)
    started = _number(raw.get("started"))
    if not isinstance(episode, int) or isinstance(episode, bool) or started is None:
        return None
    success = raw.get("success")
    return {
        "episode": episode,
        "task": _text(raw.get("task"), LABEL_CHARS),
        "started": started,
        "ended": _number(raw.get("ended")),
        "success": success if isinstance(success, bool) else None,
        "notes": _text(raw.get("notes"), LABEL_CHARS),
    }


def episodes_listed(episodes: Any) -> tuple[list[dict[str, Any]], int]:
    """The first ``LISTED_EPISODES`` episodes, summarised, and how many there are."""
    if not isinstance(episodes, list):
        return [], 0
    listed = []
    for n, raw in enumerate(episodes[:LISTED_EPISODES]):
        ep = _episode(raw, n)
        if ep is not None:
            listed.append(ep)
    return listed, len(episodes)


def blank_entry(file: str) -> dict[str, Any]:
    """A recording known only by its file name (``YYYYMMDD-HHMMSS-<name>.mcap``)."""
    return {
        "file": file,
        "name": _text(file.removesuffix(".mcap")[16:], NAME_CHARS),
        "bytes": 0,
        "duration_s": None,
        "episodes": [],
        "episode_count": 0,
        "complete": False,
        "stop_reason": "",
        "robot_model": None,
        "counts": {},
        "metadata": {},
    }


def from_metadata(
    file: str, meta: dict[str, str], counts: dict[str, int], *, complete: bool, reason: str
) -> dict[str, Any]:
    """An entry from a recording's ``telerobot`` metadata (as the recorder writes it)."""
    entry = blank_entry(file)
    try:
        episodes = json.loads(meta.get("episodes", "[]"))
    except ValueError:
        episodes = []
    listed, count = episodes_listed(episodes)
    kept = {
        _text(k, 64): _text(v, METADATA_CHARS)
        for k, v in list(meta.items())[:METADATA_KEYS]
        if k != "episodes"  # listed on their own
    }
    entry.update(
        name=_text(meta.get("name") or entry["name"], NAME_CHARS),
        duration_s=_number(meta.get("duration_s")),
        episodes=listed,
        episode_count=count,
        complete=complete,
        stop_reason=_text(reason or meta.get("stop_reason", ""), REASON_CHARS),
        robot_model=_text(meta.get("robot_model"), NAME_CHARS) or None,
        counts={_text(t, 200): int(n) for t, n in list(counts.items())[:MAX_TOPICS]},
        metadata=kept,
    )
    return entry


def summarise(path: Path) -> dict[str, Any]:
    """The entry of one recording from its MCAP summary; a file without a whole one
    (torn, being written, not an MCAP) is listed as not complete."""
    try:
        stat = path.stat()
    except OSError:
        return blank_entry(path.name)
    try:
        counts, meta = summary(path)
    except (*BROKEN, OSError):
        entry = blank_entry(path.name)
    else:
        entry = from_metadata(path.name, meta, counts, complete=True, reason="")
    return stamped(entry, stat)


def stamped(entry: dict[str, Any], stat: os.stat_result) -> dict[str, Any]:
    """The entry with the file's size and the key it is valid for."""
    return {**entry, "bytes": stat.st_size, "key": [stat.st_size, stat.st_mtime_ns]}


def public(entry: dict[str, Any]) -> dict[str, Any]:
    """What the list shows of an entry (no counts, metadata or key). An entry kept before
    the list said the arm model has none: not known (null)."""
    shown = {k: v for k, v in entry.items() if k not in ("counts", "metadata", "key", "v")}
    return {"robot_model": None, **shown}


class RecordingIndex:
    """The entries of one recordings folder: in memory (the newest ``CACHED_ENTRIES``
    used), in ``.index/`` on disk, or missing (then made with ``summarise``, off the
    server's interpreter: ``readjobs``). Thread-safe; every method may touch the disk,
    so the server calls them in a thread."""

    def __init__(self, folder: Path, *, cached: int = CACHED_ENTRIES) -> None:
        self.folder = folder
        self.cached = cached
        self._entries: OrderedDict[str, dict[str, Any]] = OrderedDict()
        self._names: tuple[int, list[str]] | None = None
        self._lock = threading.Lock()

    @property
    def directory(self) -> Path:
        return self.folder / INDEX_DIR

    def names(self) -> list[str]:
        """The recordings' file names, newest first (their names start with the UTC
        time). Kept while the folder is unchanged; a folder changed within the last
        ``NAMES_SETTLE_S`` is read again (its time stamp may not yet show a change)."""
        try:
            mtime = self.folder.stat().st_mtime_ns
        except OSError:
            return []
        with self._lock:
            if self._names is not None and self._names[0] == mtime:
                return self._names[1]
        try:
            with os.scandir(self.folder) as it:
                names = sorted(
                    (e.name for e in it if e.name.endswith(".mcap") and not e.name.startswith(".")),
                    reverse=True,
                )
        except OSError:
            return []
        if time.time_ns() - mtime > NAMES_SETTLE_S * 1e9:
            with self._lock:
                self._names = (mtime, names)
        return names

    def lookup(self, file: str, stat: os.stat_result) -> dict[str, Any] | None:
        """The entry of ``file`` if one is kept for it as it is now (``stat``)."""
        key = [stat.st_size, stat.st_mtime_ns]
        with self._lock:
            entry = self._entries.get(file)
            if entry is not None and entry.get("key") == key:
                self._entries.move_to_end(file)
                return entry
        entry = self._read_sidecar(file)
        if entry is None or entry.get("key") != key:
            return None
        self.remember(entry)
        return entry

    def put(self, entry: dict[str, Any]) -> None:
        """Keep an entry (made by ``summarise`` or by the recorder at close), in memory
        and in ``.index/``."""
        file = entry["file"]
        self.remember(entry)
        with contextlib.suppress(OSError):  # a full disk: kept in memory only
            self.directory.mkdir(exist_ok=True)
            sidecar = self.directory / f"{file}.json"
            tmp = sidecar.with_name(f".{sidecar.name}.{os.getpid()}.{threading.get_ident()}")
            tmp.write_text(json.dumps({**entry, "v": INDEX_VERSION}))
            os.replace(tmp, sidecar)

    def forget(self, file: str) -> None:
        with self._lock:
            self._entries.pop(file, None)
            self._names = None
        with contextlib.suppress(OSError):
            (self.directory / f"{file}.json").unlink()

    def remember(self, entry: dict[str, Any]) -> None:
        """Keep an entry in memory only (a job has written its ``.index/`` file)."""
        file = entry["file"]
        with self._lock:
            self._entries[file] = entry
            self._entries.move_to_end(file)
            while len(self._entries) > self.cached:
                self._entries.popitem(last=False)

    def _read_sidecar(self, file: str) -> dict[str, Any] | None:
        sidecar = self.directory / f"{file}.json"
        try:
            if sidecar.stat().st_size > SIDECAR_MAX_BYTES:
                return None
            entry = json.loads(sidecar.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(entry, dict) or entry.get("v") != INDEX_VERSION:
            return None
        if entry.get("file") != file:
            return None
        return entry
