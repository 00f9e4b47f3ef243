"""The recordings folder as the API reads it (docs/recording.md, "Reading over the
API"): which recording an id names, the list (a page of the index, never a parse per
request), one recording's entry, and the review's timeline and MP4 (made once by a job
in its own process and kept in ``.review/``). The recording being written is refused
(409) by everything that would parse it; ids too long for a file name are refused
(422) before the disk is touched.

The server calls the ``async`` methods on its event loop: they touch the disk only in
threads and parse MCAP only in ``readjobs``' processes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from telerobot.drivers.base import TelerobotError
from telerobot.server.recording.index import (
    MAX_TOPICS,
    RecordingIndex,
    blank_entry,
    episodes_listed,
    from_metadata,
    public,
    stamped,
    summarise,
)
from telerobot.server.recording.readjobs import (
    FIRST,
    LATER,
    NEXT,
    ReadBudgets,
    ReadJobs,
    RecordingHasNoVideo,
)
from telerobot.server.recording.schemas import VIDEO as VIDEO_TOPIC
from telerobot.server.recording.timeline import REVIEW_TOPICS

MAX_ID_CHARS = 200  # a recording's id (its file name; the recorder's are < 100)
ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*$")
REVIEW_DIR = ".review"  # the timelines and MP4s made for the review page
TIMELINE_VARIANTS = 8  # whole timelines kept per recording (topics × points asked for)
# Pieces of timelines kept per recording (the review page's: a handful per load, the same
# ranges each time; other ranges asked for push the oldest out).
TIMELINE_PIECES = 32
MAX_PAGE = 200  # recordings per page of the list
DEFAULT_PAGE = 50
# A tokenless reader's page of the list is the one encoded at most this long ago (s), a
# few pages kept: a loop of tokenless listings costs the server one encoding a second
# per page, not one per request (bench.abuse's recordings_listing). The token's reads
# are always fresh.
SHARED_PAGE_S = 1.0
SHARED_PAGES = 8


class RecordingNotFound(TelerobotError):
    code = "not_found"
    http_status = 404


class RecordingIdTooLong(TelerobotError):
    code = "recording_id_too_long"
    http_status = 422


class RecordingActive(TelerobotError):
    code = "recording_active"
    http_status = 409


class RangeRefused(TelerobotError):
    code = "timeline_range_refused"
    http_status = 422


ActiveEntry = Callable[[], dict[str, Any] | None]


def _no_active() -> dict[str, Any] | None:
    return None


class RecordingLibrary:
    """``active`` gives the recording being written (the recorder's status), if any."""

    def __init__(
        self,
        folder: Path,
        *,
        active: ActiveEntry = _no_active,
        budgets: ReadBudgets | None = None,
        jobs: ReadJobs | None = None,
    ) -> None:
        self.folder = folder
        self.active = active
        self.index = RecordingIndex(folder)
        self.budgets = budgets or ReadBudgets()
        self.jobs = jobs or ReadJobs()
        self.clock: Callable[[], float] = time.monotonic
        # (limit, offset) → (encoded at, the page as JSON, recordings in all)
        self._shared: OrderedDict[tuple[int, int], tuple[float, bytes, int]] = OrderedDict()

    # ------------------------------------------------------------ ids
    def file_name(self, recording_id: str) -> str:
        """The file an id names (its file name, ``.mcap`` optional)."""
        if len(recording_id) > MAX_ID_CHARS:
            raise RecordingIdTooLong(
                f"a recording id is at most {MAX_ID_CHARS} characters (this one has"
                f" {len(recording_id)}): ids are the file names GET /api/v1/recordings lists"
            )
        if not ID.match(recording_id):
            raise RecordingNotFound(f"no recording {recording_id!r}: ids are its file names")
        return recording_id if recording_id.endswith(".mcap") else f"{recording_id}.mcap"

    def path(self, recording_id: str, *, allow_active: bool = False) -> Path:
        """The recording's file; 404 if there is none, 409 if it is being written
        (unless ``allow_active``: a download or a delete decides for itself)."""
        file = self.file_name(recording_id)
        path = self.folder / file
        if not path.is_file():
            raise RecordingNotFound(
                f"no recording {recording_id!r} (GET /api/v1/recordings lists them)"
            )
        if not allow_active and self._active_file() == file:
            raise RecordingActive(
                f"{file} is being recorded: it can be read once it has stopped"
                " (POST /api/v1/recordings/active/stop)"
            )
        return path

    def _active_file(self) -> str | None:
        a = self.active()
        return None if a is None else str(a["file"])

    # ------------------------------------------------------------ the list
    def _active_entry(self) -> dict[str, Any] | None:
        a = self.active()
        if a is None:
            return None
        listed, count = episodes_listed(a.get("episodes", []))
        return {
            **blank_entry(a["file"]),
            "name": a["name"],
            "bytes": a.get("bytes") or 0,
            "duration_s": a.get("elapsed_s"),
            "episodes": listed,
            "episode_count": count,
            "active": True,
        }

    def _page(self, limit: int, offset: int) -> tuple[list[tuple[str, Any]], int]:
        """``(file, entry | stat | None)`` for a page: its entry if kept, else the stat
        it is to be summarised for (None: the file went away)."""
        names = [n for n in self.index.names() if len(n) <= MAX_ID_CHARS]
        active = self._active_entry()
        rows: list[tuple[str, Any]] = []
        for file in names[offset : offset + limit]:
            if active is not None and file == active["file"]:
                rows.append((file, active))
                continue
            try:
                stat = (self.folder / file).stat()
            except OSError:
                rows.append((file, None))
                continue
            rows.append((file, self.index.lookup(file, stat) or stat))
        return rows, len(names)

    def listing_now(self, limit: int, offset: int = 0) -> tuple[list[dict[str, Any]], int]:
        """The page, summarising what is not indexed here, in this thread (the CLI's and
        the tests'; the server's is ``listing``)."""
        rows, total = self._page(limit, offset)
        out = []
        for file, got in rows:
            if isinstance(got, os.stat_result):
                got = summarise(self.folder / file)
                self.index.put(got)
            out.append(self._shown(file, got))
        return out, total

    async def listing(
        self, limit: int, offset: int, *, peer: str, privileged: bool
    ) -> tuple[list[dict[str, Any]], int]:
        """The page, from the index; recordings not in it yet are summarised by one job
        (and kept: the next list reads them from the index)."""
        rows, total = await asyncio.to_thread(self._page, limit, offset)
        missing = [file for file, got in rows if isinstance(got, os.stat_result)]
        made: dict[str, dict[str, Any]] = {}
        if missing:
            if not privileged:
                self.budgets.job(peer)
            answer = await self.jobs.run(
                "summaries:" + "/".join(missing),
                {"kind": "summaries", "paths": [str(self.folder / f) for f in missing]},
                privileged=privileged,
            )
            made = {e["file"]: e for e in answer["entries"] if e.get("file") in missing}
            await asyncio.to_thread(self._keep, list(made.values()))
        return [self._shown(file, made.get(file, got)) for file, got in rows], total

    async def listing_json(
        self, limit: int, offset: int, *, peer: str, privileged: bool
    ) -> tuple[bytes, int]:
        """The page as JSON and the recordings in all; a tokenless reader may get one
        encoded up to ``SHARED_PAGE_S`` ago."""
        key = (limit, offset)
        now = self.clock()
        kept = self._shared.get(key)
        if not privileged and kept is not None and now - kept[0] < SHARED_PAGE_S:
            return kept[1], kept[2]
        entries, total = await self.listing(limit, offset, peer=peer, privileged=privileged)
        body = await asyncio.to_thread(lambda: json.dumps(entries, allow_nan=False).encode())
        self._shared[key] = (now, body, total)
        self._shared.move_to_end(key)
        while len(self._shared) > SHARED_PAGES:
            self._shared.popitem(last=False)
        return body, total

    def _keep(self, entries: list[dict[str, Any]]) -> None:
        for entry in entries:  # the job wrote their .index/ files
            self.index.remember(entry)

    @staticmethod
    def _shown(file: str, got: Any) -> dict[str, Any]:
        entry = got if isinstance(got, dict) else blank_entry(file)
        return {**public(entry), "active": bool(entry.get("active", False))}

    async def entry(self, recording_id: str, *, peer: str, privileged: bool) -> dict[str, Any]:
        """One recording's entry with its topics' counts and its metadata (the active
        one: what is known while it is written)."""
        file = self.file_name(recording_id)
        active = self._active_entry()
        if active is not None and active["file"] == file:
            return active
        path = await asyncio.to_thread(self.path, file)
        stat = await asyncio.to_thread(path.stat)
        entry = await asyncio.to_thread(self.index.lookup, file, stat)
        if entry is None:
            if not privileged:
                self.budgets.job(peer)
            answer = await self.jobs.run(
                f"summaries:{file}",
                {"kind": "summaries", "paths": [str(path)]},
                privileged=privileged,
            )
            entry = answer["entries"][0]
            self.index.remember(entry)
        return {**{k: v for k, v in entry.items() if k not in ("key", "v")}, "active": False}

    def closed(
        self,
        path: Path,
        meta: dict[str, str],
        counts: dict[str, int],
        *,
        complete: bool,
        reason: str,
    ) -> None:
        """The recorder closed ``path`` (or its writer ended): kept in the index with
        why it stopped, even when the file has no summary (a full disk)."""
        entry = from_metadata(path.name, meta, counts, complete=complete, reason=reason)
        self.index.put(stamped(entry, path.stat()))

    # ------------------------------------------------------------ the review's reads
    def _review(self) -> Path:
        cache = self.folder / REVIEW_DIR
        cache.mkdir(exist_ok=True)
        return cache

    @staticmethod
    def _fresh(made: Path, source: Path) -> bool:
        try:
            return made.stat().st_mtime_ns >= source.stat().st_mtime_ns
        except OSError:
            return False

    async def timeline(
        self,
        recording_id: str,
        topics: list[str],
        max_points: int,
        *,
        start_s: float | None = None,
        end_s: float | None = None,
        peer: str,
        privileged: bool,
    ) -> Path:
        """The timeline's JSON file, or a piece of it (``start_s``/``end_s``): kept, or
        made now by a job."""
        path = await asyncio.to_thread(self.path, recording_id)
        mask = sum(1 << REVIEW_TOPICS.index(t) for t in set(topics))
        cache = await asyncio.to_thread(self._review)
        # (v3: range_start and range_end said; v2: client ids replaced by aliases. A file
        # kept from before is not served.)
        whole = start_s is None and end_s is None
        if whole:
            out = cache / f"{path.stem}.timeline-v3-{max_points}-{mask}.json"
        else:
            lo = 0 if start_s is None else round(start_s * 1e9)
            hi = "end" if end_s is None else round(end_s * 1e9)
            out = cache / f"{path.stem}.piece-v3-{max_points}-{mask}-{lo}-{hi}.json"
        if await asyncio.to_thread(self._fresh, out, path):
            return out
        if not privileged:
            self.budgets.job(peer)
        request = {
            "kind": "timeline",
            "path": str(path),
            "topics": topics,
            "max_points": max_points,
            "start_s": start_s,
            "end_s": end_s,
            # what a piece learnt of the chunks before it, for the next piece
            "walk": str(cache / f"{path.stem}.walk-v1.json"),
            "out": str(out),
        }
        # A review page's first plots right after its picture; the rest of it after both.
        first = not start_s
        await self.jobs.run(
            str(out), request, privileged=privileged, priority=NEXT if first else LATER
        )
        if whole:
            await asyncio.to_thread(
                self._keep_newest, path.stem, "timeline", out, TIMELINE_VARIANTS
            )
        else:
            await asyncio.to_thread(self._keep_newest, path.stem, "piece", out, TIMELINE_PIECES)
        return out

    def _keep_newest(self, stem: str, kind: str, keep: Path, count: int) -> None:
        made = sorted(
            (self.folder / REVIEW_DIR).glob(f"{glob_escape(stem)}.{kind}-*.json"),
            key=lambda p: p.stat().st_mtime_ns if p.exists() else 0,
            reverse=True,
        )
        for old in [p for p in made if p != keep][count - 1 :]:
            with contextlib.suppress(OSError):
                old.unlink()

    async def mp4(self, recording_id: str, *, peer: str, privileged: bool) -> Path:
        """The recorded video as an MP4: kept, or remuxed now by a job. A recording its
        index says holds no video is answered so at once (the review page asks for the
        video before it knows: no job, and no job's budget, for nothing)."""
        path = await asyncio.to_thread(self.path, recording_id)
        out = await asyncio.to_thread(lambda: self._review() / f"{path.stem}.mp4")
        if await asyncio.to_thread(self._fresh, out, path):
            return out
        if await asyncio.to_thread(self._indexed_without_video, path):
            raise RecordingHasNoVideo(f"{path.name} holds no video")
        if not privileged:
            self.budgets.job(peer)
        await self.jobs.run(  # a review page's first picture: before what waits with it
            str(out),
            {"kind": "mp4", "path": str(path), "out": str(out)},
            privileged=privileged,
            priority=FIRST,
        )
        return out

    def _indexed_without_video(self, path: Path) -> bool:
        """Whether the recording's index entry counts its topics and no video among them."""
        try:
            entry = self.index.lookup(path.name, path.stat())
        except OSError:
            return False
        counts = (entry or {}).get("counts") or {}
        return 0 < len(counts) < MAX_TOPICS and VIDEO_TOPIC not in counts

    def forget(self, file: str) -> None:
        """A recording deleted: its index entry and what the review made of it go too."""
        self.index.forget(file)
        stem = file.removesuffix(".mcap")
        for made in (self.folder / REVIEW_DIR).glob(f"{glob_escape(stem)}.*"):
            with contextlib.suppress(OSError):
                made.unlink()


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)
