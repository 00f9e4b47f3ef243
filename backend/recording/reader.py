"""Read a recording back: ``read(path, topics)`` yields ``(topic, log_time_ns, dict)``
in log-time order (video ``data`` as bytes); ``recover(path)`` rewrites a file whose
writer was killed before it wrote its summary (every message of every complete chunk
kept). ``telerobot recording recover FILE`` runs it."""

from __future__ import annotations

import base64
import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Message, Schema
from mcap.writer import CompressionType, Writer

from backend.recording.schemas import BYTES_FIELDS


def _decode(topic: str, data: bytes, encoding: str) -> dict[str, Any]:
    if encoding != "json":
        return {"data": data}
    message: dict[str, Any] = json.loads(data)
    field = BYTES_FIELDS.get(topic)
    if field is not None and isinstance(message.get(field), str):
        message[field] = base64.b64decode(message[field])
    return message


def read(
    path: str | os.PathLike[str], topics: Iterable[str] | None = None
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    wanted = list(topics) if topics is not None else None
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
            yield (
                channel.topic,
                message.log_time,
                _decode(channel.topic, message.data, channel.message_encoding),
            )


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
    except (McapError, ValueError, OSError, EOFError):
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
