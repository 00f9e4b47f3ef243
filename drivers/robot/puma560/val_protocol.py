"""The serial exchange between ``ValSerialPuma`` and a Unimation controller running
the resident program ``TRINC`` (docs/val-protocol.md is the full description).

Host lines end with CR; controller lines end with CR LF. Angles are degrees with
four decimals (VAL's own unit and precision). Both the driver and the emulator
format and parse through this module, so the two cannot drift apart.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

PROGRAM_NAME = "TRINC"
PROMPT = "."
READY_BANNER = f"{PROGRAM_NAME} READY"
END_BANNER = f"{PROGRAM_NAME} END"

# The resident VAL II program that InitializeRobot uploads (thesis §4.3.1): it reads
# joint increments from the terminal, moves by them and reports where it is.
RESIDENT_PROGRAM: tuple[str, ...] = (
    "; TRINC: Telerobot resident program. Reads joint increments, moves, reports.",
    'TYPE "TRINC READY"',
    '10 PROMPT "", $cmd',
    '   IF $MID($cmd, 1, 1) == "W" THEN',
    "      HERE #now",
    "      DECOMPOSE j[1] = #now",
    '      TYPE "POS ", /F9.4, j[1], j[2], j[3], j[4], j[5], j[6]',
    "      GOTO 10",
    "   END",
    '   IF $MID($cmd, 1, 1) == "Q" THEN',
    '      TYPE "TRINC END"',
    "      HALT",
    "   END",
    '   seq = VAL($DECODE($cmd, " ", 0))',
    "   FOR i = 1 TO 6",
    '      d[i] = VAL($DECODE($cmd, " ", 0))',
    "   END",
    "   HERE #now",
    "   DECOMPOSE j[1] = #now",
    "   FOR i = 1 TO 6",
    "      j[i] = j[i]+d[i]",
    "   END",
    "   SET #nxt = #PPOINT(j[1], j[2], j[3], j[4], j[5], j[6])",
    '   TYPE "ACK ", /I0, seq, " ", /F6.3, TIMEOF(#nxt)',
    "   MOVE #nxt",
    "   BREAK",
    "   HERE #now",
    "   DECOMPOSE j[1] = #now",
    '   TYPE "DONE ", /I0, seq, /F9.4, j[1], j[2], j[3], j[4], j[5], j[6]',
    "   GOTO 10",
)

_NUM = r"[-+]?\d+(?:\.\d+)?"
_SIX = r"\s+".join([f"({_NUM})"] * 6)
_POS = re.compile(rf"^POS\s+{_SIX}$")
_ACK = re.compile(rf"^ACK\s+(\d+)\s+({_NUM})$")
_NAK = re.compile(r"^NAK\s+(\d+)\s+(.+)$")
_DONE = re.compile(rf"^DONE\s+(\d+)\s+{_SIX}$")
_ERR = re.compile(r"^ERR\s+(.+)$")
_INC = re.compile(rf"^I\s+(\d+)\s+{_SIX}$")
_EDIT_LINE = re.compile(r"^(\d+)\.$")


class ProtocolError(ValueError):
    """A line that is not what the protocol allows at that point."""


def fmt_angles(deg: Sequence[float]) -> str:
    return " ".join(f"{a:.4f}" for a in deg)


def to_degrees(rad: Sequence[float]) -> list[float]:
    return [math.degrees(a) for a in rad]


def to_radians(deg: Sequence[float]) -> list[float]:
    return [math.radians(a) for a in deg]


# --------------------------------------------------------------- host → controller
def increment_line(seq: int, delta_deg: Sequence[float]) -> str:
    return f"I {seq} {fmt_angles(delta_deg)}"


def parse_increment(line: str) -> tuple[int, list[float]]:
    m = _INC.match(line.strip())
    if not m:
        raise ProtocolError(f"not an increment line: {line!r}")
    return int(m.group(1)), [float(x) for x in m.groups()[1:]]


# --------------------------------------------------------------- controller → host
@dataclass(frozen=True)
class Position:
    joints_deg: list[float]


@dataclass(frozen=True)
class Ack:
    seq: int
    duration: float  # seconds the controller expects the move to take


@dataclass(frozen=True)
class Nak:
    seq: int
    reason: str


@dataclass(frozen=True)
class Done:
    seq: int
    joints_deg: list[float]


@dataclass(frozen=True)
class ControllerError:
    reason: str


@dataclass(frozen=True)
class Text:
    """Prompts, banners and editor line prompts: compared literally by the caller."""

    text: str


Reply = Position | Ack | Nak | Done | ControllerError | Text


def position_line(joints_deg: Sequence[float]) -> str:
    return f"POS {fmt_angles(joints_deg)}"


def ack_line(seq: int, duration: float) -> str:
    return f"ACK {seq} {duration:.3f}"


def nak_line(seq: int, reason: str) -> str:
    return f"NAK {seq} {reason}"


def done_line(seq: int, joints_deg: Sequence[float]) -> str:
    return f"DONE {seq} {fmt_angles(joints_deg)}"


def parse_reply(line: str) -> Reply:
    """Parse one controller line; ``ProtocolError`` for anything unknown or malformed."""
    s = line.strip()
    if s in (PROMPT, READY_BANNER, END_BANNER) or _EDIT_LINE.match(s):
        return Text(s)
    head = s.split(" ", 1)[0]
    if head == "POS" and (m := _POS.match(s)):
        return Position([float(x) for x in m.groups()])
    if head == "ACK" and (m := _ACK.match(s)):
        return Ack(int(m.group(1)), float(m.group(2)))
    if head == "NAK" and (m := _NAK.match(s)):
        return Nak(int(m.group(1)), m.group(2))
    if head == "DONE" and (m := _DONE.match(s)):
        return Done(int(m.group(1)), [float(x) for x in m.groups()[1:]])
    if head == "ERR" and (m := _ERR.match(s)):
        return ControllerError(m.group(1))
    raise ProtocolError(f"unexpected reply from the controller: {s[:80]!r}")
