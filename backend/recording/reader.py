"""Read a recording back: ``read(path, topics)`` yields ``(topic, log_time_ns, dict)``
in log-time order (video ``data`` as bytes); ``recover(path)`` rewrites a file whose
writer was killed before it wrote its summary (every message of every complete chunk
kept). ``telerobot recording recover FILE`` runs it.

A file without a valid summary (a writer killed, the recording being written, a copy
cut short: one byte missing is enough) is still read, as far as it is valid, by
``telerobot.server.recording.salvage``: in file order (the order it was written, which is
log-time order but for threads racing by a few µs), stopping quietly at the first
record that is cut or broken. A file that is not an MCAP at all raises
``NotARecording``, one damaged where its index points ``UnreadableRecording`` (both
422 over the API), never a parser's exception."""

from __future__ import annotations

import base64
import json
import os
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.summary import Summary
from mcap.writer import CompressionType, Writer

from telerobot.drivers.base import TelerobotError
from telerobot.server.recording.schemas import BYTES_FIELDS

# What the mcap reader raises on a file cut short or damaged (struct: a record's length
# field itself cut; ValueError: zstd or a JSON schema that does not parse).
BROKEN = (McapError, EOFError, struct.error, ValueError)


class UnreadableRecording(TelerobotError, ValueError):
    """Not an MCAP file, or damaged where its index says the messages are."""

    code = "recording_unreadable"
    http_status = 422


def _decode(topic: str, data: bytes, encoding: str) -> dict[str, Any]:
    if encoding != "json":
        return {"data": data}
    message: dict[str, Any] = json.loads(data)
    field = BYTES_FIELDS.get(topic)
    if field is not None and isinstance(message.get(field), str):
        message[field] = base64.b64decode(message[field])
    return message


def decode(topic: str, data: bytes, encoding: str) -> dict[str, Any]:
    """One message's payload as ``read`` gives it (for callers of ``read_raw``)."""
    return _decode(topic, data, encoding)


def valid_summary(f: IO[bytes]) -> Summary | None:
    """The file's summary when it has a whole one (else None: cut, torn or absent)."""
    try:
        s = make_reader(f).get_summary()
    except (*BROKEN, OSError):  # (a file shorter than a footer: seeking before its start)
        return None
    return s if s is not None and s.statistics is not None else None


def read_raw(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    in_file_order: bool = False,
) -> Iterator[tuple[str, int, bytes, str]]:
    """``(topic, log_time_ns, data, message_encoding)``, nothing decoded: a reader that
    keeps few of the messages (a decimated timeline) decodes only those. In log-time
    order, or with ``in_file_order`` as written (no merge of the chunks by time: a
    topic's messages in the order they were logged, as a decoder wants a video's)."""
    from telerobot.server.recording.salvage import SalvageReader, is_mcap

    wanted = set(topics) if topics is not None else None
    name = Path(path).name
    with open(path, "rb") as f:
        summary = valid_summary(f) if is_mcap(path) else None
        if summary is not None and summary.chunk_indexes:
            f.seek(0)
            reader = make_reader(f)
            try:
                for _s, channel, message in reader.iter_messages(
                    topics=wanted, log_time_order=not in_file_order
                ):
                    yield channel.topic, message.log_time, message.data, channel.message_encoding
            except BROKEN as exc:
                raise UnreadableRecording(f"{name} is damaged: {type(exc).__name__}") from None
            return
    salvage = SalvageReader(path)  # raises NotARecording for what is not an MCAP
    for record in salvage.records():
        if isinstance(record, Message):
            channel = salvage.channels[record.channel_id]
            if wanted is None or channel.topic in wanted:
                yield channel.topic, record.log_time, record.data, channel.message_encoding


def read(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    in_file_order: bool = False,
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    for topic, log_time, data, encoding in read_raw(path, topics, in_file_order=in_file_order):
        yield topic, log_time, _decode(topic, data, encoding)


def summary(path: str | os.PathLike[str]) -> tuple[dict[str, int], dict[str, str]]:
    """Each topic's message count and the ``telerobot`` metadata, from the summary
    (raises ``McapError``/``ValueError`` for a file without one)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        s = reader.get_summary()
        if s is None or s.statistics is None:
            raise ValueError(f"{path} has no summary: run `telerobot recording recover {path}`")
        counts = {
            s.channels[cid].topic: n for cid, n in s.statistics.channel_message_counts.items()
        }
        meta: dict[str, str] = {}
        for record in reader.iter_metadata():
            if record.name == "telerobot":
                meta = dict(record.metadata)
        return counts, meta


def has_summary(path: str | os.PathLike[str]) -> bool:
    try:
        summary(path)
    except (*BROKEN, OSError):
        return False
    return True


def recover(path: str | os.PathLike[str], *, reason: str = "recovered") -> int:
    """Rewrite ``path`` in place with an index and a summary, keeping every message
    that can be read (a torn last chunk is dropped). Returns the messages kept."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.recover")
    kept = 0
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with open(path, "rb") as src, open(tmp, "wb") as dst:
        writer = Writer(dst, compression=CompressionType.ZSTD)
        writer.start(profile="", library="telerobot recover (mcap python)")
        out_schema: dict[int, int] = {}
        out_channel: dict[int, int] = {}
        stream = NonSeekingReader(src, validate_crcs=False)
        it = stream.iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, message = next(it)
            except StopIteration:
                break
            except Exception:
                break
            if schema is not None and schema.id not in out_schema:
                schemas[schema.id] = schema
                out_schema[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in out_channel:
                channels[channel.id] = channel
                out_channel[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    out_schema.get(channel.schema_id, 0),
                    dict(channel.metadata),
                )
            assert isinstance(message, Message)
            writer.add_message(
                out_channel[channel.id],
                message.log_time,
                message.data,
                message.publish_time,
                message.sequence,
            )
            kept += 1
        writer.add_metadata("telerobot", {"stop_reason": reason, "recovered_messages": str(kept)})
        writer.finish()  # type: ignore[no-untyped-call]
    os.replace(tmp, path)
    return kept
