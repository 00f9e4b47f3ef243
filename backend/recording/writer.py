"""One MCAP file, written with the maintained ``mcap`` writer (no home-made container).

Why ``mcap`` and not ``foxglove-sdk`` (measured on this machine, 10 000 small JSON force
messages = 10 s at 1 kHz, 2 cores): ``mcap`` 81–91 ms of CPU (0.8 % of a core), zstd
291 kB; ``foxglove-sdk`` 48 ms (0.5 %), 294 kB. The SDK is cheaper by 0.3 % of a core,
but it writes from Rust behind our back: a full disk or a closed file does not reach
the caller as an ``OSError``. With ``mcap`` the file object is ours: every failure
surfaces in the writer process, which stops the recording and says why, and the same
package reads and recovers the file. Encoding (JSON) happens here, in the writer
process (``serve_file``), never in the server's.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.writer import CompressionType, Writer

from telerobot.server.recording.schemas import BYTES_FIELDS, schema_of
from telerobot.tuning import yield_cpu

CHUNK_BYTES = 256 * 1024  # a killed writer loses at most the chunk being filled


def _default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if isinstance(value, tuple | set):
        return list(value)
    return str(value)


def encode(topic: str, payload: dict[str, Any]) -> bytes:
    field = BYTES_FIELDS.get(topic)
    if field is not None and isinstance(payload.get(field), bytes | bytearray | memoryview):
        payload = {**payload, field: base64.b64encode(bytes(payload[field])).decode("ascii")}
    return json.dumps(payload, separators=(",", ":"), default=_default).encode()


class McapFile:
    """Channels are registered on first use; every call may raise ``OSError`` (a full
    disk) or ``ValueError`` (the file closed under it): the caller decides."""

    def __init__(self, path: Path, *, chunk_bytes: int = CHUNK_BYTES, mode: str = "xb") -> None:
        self.path = path
        self._file: IO[bytes] = open(path, mode)  # noqa: SIM115 (closed by close())
        self._writer = Writer(self._file, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="telerobot (mcap python)")
        self._channels: dict[str, int] = {}
        self._schemas: dict[bytes, int] = {}  # one record per schema (the arms' share theirs)
        self._sequence: dict[str, int] = {}
        self.count: dict[str, int] = {}
        self._last_log_ns = 0

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            name, schema = schema_of(topic)
            data = json.dumps({"title": name, **schema}).encode()
            schema_id = self._schemas.get(data)
            if schema_id is None:
                schema_id = self._schemas[data] = self._writer.register_schema(
                    name, "jsonschema", data
                )
            channel = self._writer.register_channel(topic, "json", schema_id)
            self._channels[topic] = channel
            self._sequence[topic] = 0
            self.count[topic] = 0
        return channel

    def write(self, topic: str, log_time_ns: int, payload: dict[str, Any] | bytes) -> int:
        """Write one message; returns its size in bytes. Its ``publish_time`` is when it
        was taken (``log_time_ns``); its ``log_time`` never goes back within the file
        (``mcap doctor`` requires it): messages taken on several threads reach the
        writer in the order they were queued, one up to a few ms after a later one."""
        channel = self._channel(topic)
        data = payload if isinstance(payload, bytes) else encode(topic, payload)
        seq = self._sequence[topic] = self._sequence[topic] + 1
        logged = self._last_log_ns = max(log_time_ns, self._last_log_ns)
        self._writer.add_message(channel, logged, data, log_time_ns, seq)
        self.count[topic] += 1
        return len(data)

    def flush(self) -> None:
        self._file.flush()

    def tell(self) -> int:
        return self._file.tell()

    def close(self, metadata: dict[str, str]) -> None:
        """Write the metadata, the index and the summary, and close the file (closed
        even if writing them fails)."""
        try:
            self._writer.add_metadata("telerobot", metadata)
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._file.flush()
        finally:
            self.abandon()

    def abandon(self) -> None:
        """Close the file as it is (no summary: ``recover`` rewrites it with one)."""
        with contextlib.suppress(OSError, ValueError):
            self._file.close()

    @property
    def raw(self) -> IO[bytes]:
        return self._file


# ---------------------------------------------------------------- the writer process
WRITER_NICE = 5  # the file waits behind control, forces and live video
PROGRESS_S = 0.5  # the writer flushes and says how far it got at least this often


def describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.strerror} (errno {exc.errno})"
    return f"{type(exc).__name__}: {exc}"


def serve_file(conn: Connection, path: str, chunk_bytes: int) -> None:
    """The writer process's main: encodes (JSON, base64, zstd) and writes what the server
    sends, so none of that holds the server's GIL against the force stream and the
    event loop. Receives ``("batch", [(topic, wall_ns, t, payload), …])`` and
    ``("close", metadata)``; answers ``("progress", bytes, messages)`` after each flush,
    ``("closed", bytes, messages, {topic: count})`` or ``("failed", reason)``. A dead
    server (the pipe closed) leaves the file as it is, recoverable."""
    yield_cpu(WRITER_NICE)
    messages = 0
    file: McapFile | None = None
    try:
        file = McapFile(Path(path), chunk_bytes=chunk_bytes, mode="wb")
        last_flush = time.monotonic()
        while True:
            try:
                kind, body = conn.recv() if conn.poll(PROGRESS_S) else ("batch", [])
            except EOFError:  # the server went away: keep what is written
                file.abandon()
                return
            if kind == "close":
                file.close(body)
                conn.send(("closed", os.path.getsize(path), messages, file.count))
                return
            for topic, wall_ns, t, payload in body:
                if isinstance(payload, dict) and "t" not in payload:
                    payload = {"t": t, **payload}
                file.write(topic, wall_ns, payload)
                messages += 1
            if time.monotonic() - last_flush >= PROGRESS_S:
                file.flush()
                conn.send(("progress", file.tell(), messages))
                last_flush = time.monotonic()
    except BaseException as exc:  # a full disk, the file gone, a bug
        if file is not None:
            file.abandon()
        with contextlib.suppress(OSError, ValueError):
            conn.send(("failed", describe(exc)))
