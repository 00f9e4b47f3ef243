"""The ATI Net F/T's Raw Data Transfer (RDT) protocol over UDP, defined once for the
driver and the emulator.

Request (8 bytes, big-endian): header 0x1234, command, sample count (0 = until told
to stop). Record (36 bytes, big-endian): rdt_sequence (counts every packet the sensor
sends: a gap is a lost packet), ft_sequence (the sensor's internal sample counter),
status (0 = healthy), then Fx Fy Fz Tx Ty Tz in counts (divide by counts-per-force /
counts-per-torque from the sensor's calibration).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

RDT_PORT: Final = 49152
HEADER: Final = 0x1234
REQUEST: Final = struct.Struct(">HHI")
RECORD: Final = struct.Struct(">3I6i")

CMD_STOP: Final = 0x0000
CMD_STREAM: Final = 0x0002  # real-time, high-speed streaming
CMD_BIAS: Final = 0x0042  # zero the readings (software bias in the sensor)

COUNTS_PER_FORCE: Final = 1_000_000  # the sensor's defaults; a real one reports its own
COUNTS_PER_TORQUE: Final = 1_000_000


def request(command: int, count: int = 0) -> bytes:
    return REQUEST.pack(HEADER, command, count)


def parse_request(data: bytes) -> tuple[int, int] | None:
    """(command, count), or None if ``data`` is not a request."""
    if len(data) != REQUEST.size:
        return None
    header, command, count = REQUEST.unpack(data)
    return (command, count) if header == HEADER else None


@dataclass(frozen=True)
class Record:
    rdt_seq: int
    ft_seq: int
    status: int
    counts: tuple[int, int, int, int, int, int]

    def pack(self) -> bytes:
        return RECORD.pack(self.rdt_seq, self.ft_seq, self.status, *self.counts)


def parse_record(data: bytes) -> Record | None:
    """The record in ``data``, or None for a packet of the wrong size."""
    if len(data) != RECORD.size:
        return None
    rdt, ft, status, *counts = RECORD.unpack(data)
    return Record(rdt, ft, status, tuple(counts))
