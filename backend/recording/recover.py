"""``telerobot recording recover FILE``: a recording whose writer was killed (no summary,
a torn last chunk, a summary cut short) copied, as far as it is valid, into a new file
beside it with an index and a summary: ``NAME.recovered.mcap``. The original is never
written to (it may be all there is of a session, or not a recording at all), and a
file that is not an MCAP is refused (``NotARecording``) before anything is written.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Message, Schema
from mcap.writer import CompressionType, Writer

from telerobot.drivers.base import TelerobotError
from telerobot.server.recording.salvage import NotARecording, SalvageReader, is_mcap

SUFFIX = ".recovered.mcap"


class RecoverRefused(TelerobotError):
    """Recovering would overwrite something, or there is nothing to recover into."""

    code = "recover_refused"
    http_status = 409


@dataclass(frozen=True)
class Recovered:
    source: Path
    out: Path
    messages: int  # copied into ``out``
    complete: bool  # the source was whole (its footer read): nothing was lost
    stopped: str  # why the source's valid part ended ("" if complete)


def recovered_path(path: Path) -> Path:
    """Where the recovered copy of ``path`` goes: beside it, ``NAME.recovered.mcap``."""
    stem = path.name.removesuffix(".mcap")
    return path.with_name(stem + SUFFIX)


def recover_copy(path: str | os.PathLike[str], *, reason: str = "recovered") -> Recovered:
    """Copy every valid message of ``path`` into ``recovered_path(path)`` with an index
    and a summary (the metadata ``telerobot`` says ``stop_reason`` and how many
    messages were kept). Refuses a file that is not an MCAP and an existing output."""
    source = Path(path)
    if not is_mcap(source):
        raise NotARecording(
            f"{source} is not an MCAP recording (it does not start with MCAP's magic "
            "bytes): nothing was written"
        )
    out = recovered_path(source)
    if out.exists():
        raise RecoverRefused(f"{out} exists already: move it away to recover {source.name} again")
    tmp = out.with_name(f".{out.name}.part")
    reader = SalvageReader(source)
    kept = 0
    try:
        with open(tmp, "xb") as dst:
            writer = Writer(dst, compression=CompressionType.ZSTD)
            writer.start(profile="", library="telerobot recover (mcap python)")
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}
            schemas: dict[int, Schema] = {}
            for record in reader.records():
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    if record.id in channel_ids:
                        continue
                    schema = schemas.get(record.schema_id)
                    if schema is not None and schema.id not in schema_ids:
                        schema_ids[schema.id] = writer.register_schema(
                            schema.name, schema.encoding, schema.data
                        )
                    channel_ids[record.id] = writer.register_channel(
                        record.topic,
                        record.message_encoding,
                        schema_ids.get(record.schema_id, 0),
                        dict(record.metadata),
                    )
                elif isinstance(record, Message) and record.channel_id in channel_ids:
                    writer.add_message(
                        channel_ids[record.channel_id],
                        record.log_time,
                        record.data,
                        record.publish_time,
                        record.sequence,
                    )
                    kept += 1
            if kept == 0:
                why = reader.stopped or "it holds none"
                raise RecoverRefused(
                    f"no message of {source.name} could be read ({why}): nothing was written"
                )
            writer.add_metadata(
                "telerobot",
                {
                    "stop_reason": reason,
                    "recovered_messages": str(kept),
                    "recovered_from": source.name,
                    "source_stopped": reader.stopped,
                },
            )
            writer.finish()  # type: ignore[no-untyped-call]
        os.replace(tmp, out)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return Recovered(source, out, kept, reader.complete, reader.stopped)
