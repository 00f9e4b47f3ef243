"""The CLI on torn and foreign files: ``telerobot recording recover`` refuses
what is not an MCAP and writes what it recovers beside the original, never over it
(a file cut mid-summary included, without a traceback); ``telerobot export lerobot``
of a torn recording says so in one line and exits non-zero."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer

from telerobot.server.cli import main
from telerobot.server.recording.reader import read, summary


@pytest.fixture(scope="module")
def whole(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished recording of 500 small JSON messages in 4 kB chunks (as the server
    writes, in smaller chunks: a cut file keeps most of them)."""
    path = tmp_path_factory.mktemp("rec") / "20260101-000000-whole.mcap"
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=4096, compression=CompressionType.ZSTD)
        writer.start(profile="", library="tests")
        schema = writer.register_schema("telerobot.Force", "jsonschema", b'{"type":"object"}')
        channel = writer.register_channel("/force", "json", schema)
        for i in range(500):
            data = json.dumps({"t": 1000 + i / 1000, "seq": i, "values": [i, 0, 0, 0, 0, 0]})
            writer.add_message(channel, i * 1_000_000, data.encode(), i * 1_000_000, i)
        writer.add_metadata("telerobot", {"name": "whole", "stop_reason": "stopped"})
        writer.finish()  # type: ignore[no-untyped-call]
    return path


def messages(path: Path) -> int:
    return sum(1 for _ in read(path))


def copy_cut(src: Path, dst: Path, drop: int) -> Path:
    """``src`` without its last ``drop`` bytes (what a writer killed mid-write leaves)."""
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) - drop])
    return dst


def test_recover_refuses_a_file_that_is_not_a_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes: not a recording\n")
    assert main(["recording", "recover", str(notes)]) != 0
    err = capsys.readouterr().err
    assert "not an MCAP recording" in err and "nothing was written" in err
    assert notes.read_text() == "my notes: not a recording\n"  # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


@pytest.mark.parametrize(
    ("drop", "all_kept"),
    [
        (200, True),  # cut inside the summary: every message is there
        (None, False),  # cut halfway through: the complete chunks are kept
    ],
)
def test_recover_writes_beside_the_original_and_leaves_it_as_it_was(
    whole: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    drop: int | None,
    all_kept: bool,
) -> None:
    size = whole.stat().st_size
    torn = copy_cut(whole, tmp_path / whole.name, size // 2 if drop is None else drop)
    before = torn.read_bytes()
    assert main(["recording", "recover", str(torn)]) == 0
    out = capsys.readouterr().out
    recovered = tmp_path / "20260101-000000-whole.recovered.mcap"
    assert f"into {recovered}" in out
    assert torn.read_bytes() == before  # never written over
    counts, meta = summary(recovered)  # an index and a summary now
    assert meta["stop_reason"] == "recovered" and meta["recovered_from"] == torn.name
    kept = messages(recovered)
    assert kept == sum(counts.values()) and f"recovered {kept} messages" in out
    if all_kept:
        assert kept == messages(whole)
    else:
        assert 0 < kept < messages(whole) and "could not be read" in out
    # Again: the copy is there, and it is not overwritten either.
    assert main(["recording", "recover", str(torn)]) != 0
    assert "exists already" in capsys.readouterr().err


def test_recover_of_a_file_cut_anywhere_in_its_summary_keeps_every_message(
    whole: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The summary's last records (its offsets, 26 bytes each) and the footer: a cut
    # inside one of them once raised struct.error ("unpack requires a buffer of 8
    # bytes") with a traceback.
    data = whole.read_bytes()
    footer = len(data) - 8 - 29  # the footer record, then the closing magic bytes
    summary_start = struct.unpack("<Q", data[footer + 9 : footer + 17])[0]
    everything = messages(whole)
    torn = tmp_path / whole.name
    recovered = tmp_path / "20260101-000000-whole.recovered.mcap"
    for drop in range(9, min(len(data) - summary_start, 100)):
        torn.write_bytes(data[: len(data) - drop])
        assert main(["recording", "recover", str(torn)]) == 0, drop
        assert messages(recovered) == everything, drop
        recovered.unlink()
    assert "Traceback" not in capsys.readouterr().err


def test_export_of_a_torn_recording_says_so_in_one_line(whole: Path, tmp_path: Path) -> None:
    torn = copy_cut(whole, tmp_path / whole.name, 1000)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "telerobot.server.cli",
            "export",
            "lerobot",
            str(torn),
            str(tmp_path / "ds"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode != 0
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "is torn" in lines[0] and "recording recover" in lines[0], lines
    assert not (tmp_path / "ds").exists()  # nothing half-written
