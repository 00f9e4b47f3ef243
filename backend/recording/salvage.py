"""Read a recording as far as it is valid, whatever the file is: a complete recording,
what a killed writer leaves (no summary, a torn last chunk), the recording being
written, a file cut anywhere or corrupted in the middle, or a file that is not an MCAP
at all (``NotARecording``, 422).

``SalvageReader(path).records()`` yields the schema, channel and message records in
file order and stops, without raising, at the first byte that is not a whole valid
record (a failed CRC, a torn record, a chunk that will not inflate); afterwards the
reader says whether it reached the footer (``complete``) and, if not, why it stopped
(``stopped``). ``messages(topics)`` decodes them as ``telerobot.server.recording.reader.read``
does (docs/recording.md). Nothing is loaded past the limits: a record longer than
``MAX_RECORD_BYTES`` or a chunk that says it inflates past ``MAX_CHUNK_BYTES`` ends the
read there (the writer's chunks are 256 kB), so a crafted length cannot make a reader
allocate gigabytes.

The order is the file's, which is the order the writer was given the messages (log
time, for a recording of this server): no index is needed, so a torn file reads as
a whole one does.
"""

from __future__ import annotations

import base64
import json
import os
import struct
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from telerobot.drivers.base import TelerobotError
from telerobot.server.recording.schemas import BYTES_FIELDS

MAGIC = b"\x89MCAP0\r\n"
MAX_RECORD_BYTES = 64 * 1024 * 1024
MAX_CHUNK_BYTES = 64 * 1024 * 1024
LZ4_MAX_RATIO = 255  # LZ4 inflates at most this much: a bound known before inflating


class NotARecording(TelerobotError):
    """The file is not an MCAP recording at all (not even the start of one)."""

    code = "not_a_recording"
    http_status = 422


def is_mcap(path: str | os.PathLike[str]) -> bool:
    """The file starts with MCAP's magic bytes (a recording, maybe a torn one)."""
    with open(path, "rb") as f:
        return f.read(len(MAGIC)) == MAGIC


def has_footer(path: str | os.PathLike[str]) -> bool:
    """The file ends as a finished MCAP does (the magic bytes after the footer): a quick
    test that its writer finished; ``complete`` after a read is the thorough one."""
    with open(path, "rb") as f:
        f.seek(0, os.SEEK_END)
        if f.tell() < 2 * len(MAGIC):
            return False
        f.seek(-len(MAGIC), os.SEEK_END)
        return f.read(len(MAGIC)) == MAGIC


def has_summary(path: str | os.PathLike[str]) -> bool:
    """The file ends with a readable MCAP summary (its writer finished it). Whatever is
    wrong with the file, the answer is False, never an exception."""
    try:
        if not (is_mcap(path) and has_footer(path)):
            return False
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
        return summary is not None and summary.statistics is not None
    except Exception:  # a torn or crafted summary: struct.error, McapError, …
        return False


def decode(topic: str, data: bytes, encoding: str) -> dict[str, Any]:
    """A message's payload as ``reader.read`` gives it: JSON as a dict (its bytes fields
    as bytes), anything else as ``{"data": bytes}``."""
    if encoding != "json":
        return {"data": data}
    message = json.loads(data)
    if not isinstance(message, dict):
        raise ValueError(f"a {topic} message is not a JSON object")
    field = BYTES_FIELDS.get(topic)
    if field is not None and isinstance(message.get(field), str):
        message[field] = base64.b64decode(message[field])
    return message


class SalvageReader:
    """One pass over ``path``: call ``records()`` or ``messages()`` once, then read
    ``complete``, ``stopped``, ``messages_read`` and ``undecodable``."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.complete = False  # the footer was reached: nothing was cut or torn
        self.stopped = ""  # why the read ended before the footer
        self.messages_read = 0
        self.undecodable = 0  # messages skipped by messages(): not the JSON they claim
        self.channels: dict[int, Channel] = {}

    def records(self) -> Iterator[Schema | Channel | Message]:
        """Every schema, channel and message record up to the first invalid byte."""
        with open(self.path, "rb") as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise NotARecording(
                    f"{self.path.name} is not an MCAP recording (it does not start with "
                    "MCAP's magic bytes)"
                )
            f.seek(0)
            stream = StreamReader(
                f, emit_chunks=True, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES
            )
            records = stream.records
            while True:
                try:
                    record = next(records)
                    inner = self._inflate(record) if isinstance(record, Chunk) else [record]
                except StopIteration:
                    self.complete = True
                    return
                except Exception as exc:  # anything unreadable ends the valid part
                    self.stopped = _why(exc)
                    return
                for r in inner:
                    if isinstance(r, Channel):
                        self.channels[r.id] = r
                    elif isinstance(r, Message):
                        if r.channel_id not in self.channels:
                            continue  # a message of no channel: nothing says what it is
                        self.messages_read += 1
                    elif not isinstance(r, Schema):
                        continue
                    yield r
                if isinstance(record, Footer):
                    self.complete = True
                    return

    def messages(
        self, topics: Iterable[str] | None = None, *, keep: Callable[[str], bool] | None = None
    ) -> Iterator[tuple[str, int, dict[str, Any]]]:
        """``(topic, log_time_ns, payload)`` of the valid part, in file order; a message
        that is not the JSON it claims to be is skipped and counted (``undecodable``).
        ``topics`` (or ``keep``, for topics not known by name in advance) chooses."""
        wanted = set(topics) if topics is not None else None
        for r in self.records():
            if not isinstance(r, Message):
                continue
            channel = self.channels[r.channel_id]
            if wanted is not None and channel.topic not in wanted:
                continue
            if keep is not None and not keep(channel.topic):
                continue
            try:
                payload = decode(channel.topic, r.data, channel.message_encoding)
            except (ValueError, TypeError):  # json and base64 errors are ValueErrors
                self.undecodable += 1
                continue
            yield channel.topic, r.log_time, payload

    @staticmethod
    def _inflate(chunk: Chunk) -> list[Any]:
        """A chunk's records, refused before inflating when it would be too big."""
        if chunk.uncompressed_size > MAX_CHUNK_BYTES:
            raise ValueError(
                f"a chunk says it holds {chunk.uncompressed_size} bytes "
                f"(at most {MAX_CHUNK_BYTES} are read)"
            )
        if chunk.compression == "lz4" and len(chunk.data) * LZ4_MAX_RATIO > MAX_CHUNK_BYTES:
            raise ValueError("an LZ4 chunk could inflate past the size read")
        if chunk.compression not in ("", "zstd", "lz4"):
            raise ValueError(f"a chunk has an unknown compression {chunk.compression[:20]!r}")
        records: list[Any] = breakup_chunk(chunk, validate_crc=True)
        return records


def _why(exc: BaseException) -> str:
    text = str(exc).strip()
    name = type(exc).__name__
    if name == "EndOfFile" or isinstance(exc, EOFError | struct.error):  # read past the end
        return "the file ends inside a record (cut or still being written)"
    return f"{name}: {text[:200]}" if text else name
