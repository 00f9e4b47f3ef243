"""RTP header extensions in the one-byte form (RFC 8285), read in place: where each
element of a packet's extension block stands. The pacer writes abs-send-time again there
(``pacer.py``); the playout delay is added as an element (``playout.py``). aiortc writes
only this form."""

from __future__ import annotations

import struct
from dataclasses import dataclass

ONE_BYTE_PROFILE = 0xBEDE


@dataclass(frozen=True)
class Block:
    """A packet's extension block: from ``start`` (past the fixed header and the CSRCs,
    where the profile and length words stand) to ``end`` (the payload's start; equal to
    ``start`` for a packet without one), and its ``elements``: (id, where its data
    starts, its length)."""

    start: int
    end: int
    elements: list[tuple[int, int, int]]


def block(packet: bytes) -> Block | None:
    """``packet``'s one-byte extension block (an empty one where it has none), or None
    where it cannot be read here: shorter than an RTP header, cut inside its block,
    two-byte headers, an element of id 15 (the form's end marker)."""
    if len(packet) < 12:
        return None
    start = 12 + 4 * (packet[0] & 0x0F)  # past the CSRCs
    if not packet[0] & 0x10:  # no extension
        return Block(start, start, []) if len(packet) >= start else None
    if len(packet) < start + 4:
        return None
    profile, words = struct.unpack_from("!HH", packet, start)
    end = start + 4 + 4 * words
    if profile != ONE_BYTE_PROFILE or end > len(packet):
        return None
    elements = []
    pos = start + 4
    while pos < end:
        head = packet[pos]
        if head == 0:  # padding
            pos += 1
            continue
        x_id, length = head >> 4, (head & 0x0F) + 1
        if x_id == 15 or pos + 1 + length > end:
            return None
        elements.append((x_id, pos + 1, length))
        pos += 1 + length
    return Block(start, end, elements)
