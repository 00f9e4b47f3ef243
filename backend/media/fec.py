"""Forward error correction for the video: RED (RFC 2198) carrying ULPFEC (RFC 5109), what
Chromium offers and decodes for H.264 and VP8 (``a=rtpmap:… red/90000`` and
``ulpfec/90000`` in every offer it makes).

Why: a lost packet otherwise costs its frame a NACK round trip (170–280 ms on
bench.netem's `mobile` link, which froze the picture 10–24 % of the time). An FEC
packet is the XOR of a few media packets: with it, one lost packet among them is rebuilt
as soon as the FEC packet arrives, a millisecond after the frame.

The parts:
* ``ulpfec_payload`` / ``recover``: the codec, on RTP packets as bytes. An FEC packet
  protects up to 48 media packets of one SSRC (the 16- or 48-bit mask); it XORs their
  header fields that can differ (P, X, CC, M, PT, timestamp, length) and everything
  after the 12-byte fixed header (CSRCs, header extensions, payload). libwebrtc does
  the same, and so a header extension rewritten after the FEC was made (the pacer's
  abs-send-time) comes back wrong in a rebuilt packet, which is harmless.
* ``FecSender``: in front of one viewer's transport (its RTP path, as the pacer and
  the playout-delay stamp are). It wraps each media packet in RED while protection is
  on and sends FEC packets after a group of them. FEC packets take sequence numbers of
  the media's SSRC (RFC 5109 with RED shares them), so aiortc's numbers are mapped to
  the wire's: ``to_sent`` for aiortc's retransmissions, ``nacked`` for the receiver's
  NACKs (aiortc resends from its history by its own numbers). An H.264 receiver
  (libwebrtc's packet buffer) will not release a frame while any earlier sequence
  number is missing, FEC packets included, so a NACKed FEC packet's number is answered
  with a padding-only packet (``pad_fec``): it fills the number at once, needs no
  history, and the media packets it covered are NACKed and resent on their own.
* ``FecReceiver``: the other side, as libwebrtc's UlpfecReceiver: RED unwrapped,
  media kept for a while, a missing packet rebuilt when an FEC packet covers it and
  every other packet it covers is there. bench.wan's viewer and the tests use it.
* ``protection_share``: how much FEC, from the loss the viewer's NACKs show (none on
  a clean link, so a LAN's bytes do not change).
"""

from __future__ import annotations

import math
import struct
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from aiortc.rtp import is_rtcp

from telerobot.server.media import aiortc_compat
from telerobot.server.media.rtp_extensions import block

RED_MIME = "video/red"
ULPFEC_MIME = "video/ulpfec"
# Our payload types when aiortc offers (in an answer the offer's are used); aiortc's
# own video codecs take 97-102.
RED_OFFER_PT = 121
ULPFEC_OFFER_PT = 122

FEC_HEADER = 10  # ULPFEC header: E L P X CC | M PT | SN base | TS | length recovery
MAX_PROTECTED = 48  # packets one FEC packet covers (the long mask)
SHORT_MASK = 16  # up to this span, the 16-bit mask (L = 0)
# A group of media packets protected together: closed at a frame's end once it has
# MIN_GROUP packets or holds GROUP_FRAMES frames (a still scene sends frames of one
# or two packets: FEC over each alone would double the stream), and at MAX_PROTECTED.
MIN_GROUP = 4
GROUP_FRAMES = 2
MAX_SHARE = 0.35  # at most about one FEC packet per three media packets
# Protection turns on when the viewer's NACKs show this share of packets lost (bench
# .netem's `wifi` link, 0.5 % random loss, is just above), and off below OFF_LOSS.
ON_LOSS = 0.004
OFF_LOSS = 0.002
# How many numbers we keep: ours against aiortc's, and which of ours were FEC.
SEQ_MAP_SIZE = 1024
# The receiver keeps this many media packets and FEC packets to recover from.
RX_MEDIA_KEPT = 512
RX_FEC_KEPT = 64
# The media's packets are cut to this payload (aiortc's 1300 by default) so that an FEC
# packet, ~40 bytes more than the longest it covers, still fits what SRTP takes
# (pylibsrtp: 1356 bytes) and a 1500-byte path; libwebrtc makes the same room.
MEDIA_PAYLOAD_MAX = 1200
RTP_MAX = 1356
PADDING = b"\x00\x00\x00\x04"  # four octets of padding, the last one saying so

Send = Callable[[bytes], Awaitable[None]]


def seq_of(packet: bytes) -> int:
    return int.from_bytes(packet[2:4], "big")


def with_seq(packet: bytes, seq: int) -> bytes:
    return packet[:2] + (seq & 0xFFFF).to_bytes(2, "big") + packet[4:]


def payload_start(packet: bytes) -> int:
    """Where the payload of an RTP packet starts (past CSRCs and header extensions)."""
    found = block(packet)
    if found is None:
        raise ValueError("not an RTP packet with a readable header")
    return found.end


def _seq_delta(a: int, b: int) -> int:
    """``a - b`` on 16-bit sequence numbers, in [-32768, 32767]."""
    return (a - b + 32768) % 65536 - 32768


def red_wrap(packet: bytes, red_pt: int) -> bytes:
    """``packet`` (a media RTP packet) as one RED block: the same header with RED's
    payload type, one byte naming the media's, then the media payload."""
    at = payload_start(packet)
    return (
        packet[:1]
        + bytes([(packet[1] & 0x80) | red_pt])
        + packet[2:at]
        + bytes([packet[1] & 0x7F])
        + packet[at:]
    )


def red_unwrap(packet: bytes) -> bytes | None:
    """The packet a one-block RED packet carries (its payload type in the header), or
    None if it is not one (several blocks: RFC 2198's redundancy, which we never send)."""
    at = payload_start(packet)
    if len(packet) <= at or packet[at] & 0x80:
        return None
    return packet[:1] + bytes([(packet[1] & 0x80) | packet[at]]) + packet[2:at] + packet[at + 1 :]


def _xor_into(target: bytearray, data: bytes, offset: int = 0) -> None:
    n = len(data)
    if n == 0:
        return
    a = int.from_bytes(target[offset : offset + n], "big")
    b = int.from_bytes(data, "big")
    target[offset : offset + n] = (a ^ b).to_bytes(n, "big")


def ulpfec_payload(packets: list[bytes]) -> bytes:
    """The ULPFEC payload (RFC 5109, one level) protecting ``packets``: media RTP packets
    of one SSRC, in sequence order, spanning at most MAX_PROTECTED numbers."""
    if not packets:
        raise ValueError("an FEC packet protects at least one packet")
    base = seq_of(packets[0])
    offsets = [_seq_delta(seq_of(p), base) for p in packets]
    if min(offsets) < 0 or max(offsets) >= MAX_PROTECTED:
        raise ValueError(f"packets must follow {base} within {MAX_PROTECTED} numbers")
    long_mask = max(offsets) >= SHORT_MASK
    mask_bits = 48 if long_mask else 16
    mask = 0
    for off in offsets:
        mask |= 1 << (mask_bits - 1 - off)
    length = max(len(p) for p in packets) - 12
    first = bytearray(8)  # bytes 0-1, 4-7 of each header, XORed; then length
    body = bytearray(length)
    length_xor = 0
    for p in packets:
        _xor_into(first, p[0:2] + p[4:8])
        length_xor ^= len(p) - 12
        _xor_into(body, p[12:])
    head = bytes([(first[0] & 0x3F) | (0x40 if long_mask else 0), first[1]])
    fec_header = head + struct.pack("!H", base) + bytes(first[2:6]) + struct.pack("!H", length_xor)
    level = struct.pack("!H", length) + mask.to_bytes(mask_bits // 8, "big")
    return fec_header + level + bytes(body)


@dataclass(frozen=True)
class FecPacket:
    """A received ULPFEC payload, read: what it covers and the XORs to rebuild one."""

    ssrc: bytes
    protected: tuple[int, ...]  # sequence numbers
    header_xor: bytes  # bytes 0-1 and 4-7 of the headers, XORed (E and L cleared)
    length_xor: int
    body: bytes  # the level-0 payload

    @classmethod
    def parse(cls, payload: bytes, ssrc: bytes) -> FecPacket:
        if len(payload) < FEC_HEADER + 4:
            raise ValueError("an FEC payload shorter than its headers")
        long_mask = bool(payload[0] & 0x40)
        mask_bytes = 6 if long_mask else 2
        (base,) = struct.unpack_from("!H", payload, 2)
        (length_xor,) = struct.unpack_from("!H", payload, 8)
        (length,) = struct.unpack_from("!H", payload, 10)
        mask = int.from_bytes(payload[12 : 12 + mask_bytes], "big")
        bits = 8 * mask_bytes
        protected = tuple((base + i) & 0xFFFF for i in range(bits) if mask >> (bits - 1 - i) & 1)
        body = payload[12 + mask_bytes : 12 + mask_bytes + length]
        if not protected or len(body) < length:
            raise ValueError("an FEC payload that protects nothing or is cut short")
        header_xor = bytes([payload[0] & 0x3F, payload[1]]) + payload[4:8]
        return cls(ssrc, protected, header_xor, length_xor, body)


def recover(fec: FecPacket, others: list[bytes], seq: int) -> bytes:
    """The packet ``seq`` that ``fec`` covers, rebuilt from ``others``: every other
    packet it covers."""
    first = bytearray(fec.header_xor)
    length = fec.length_xor
    body = bytearray(fec.body)
    for p in others:
        _xor_into(first, p[0:2] + p[4:8])
        length ^= len(p) - 12
        _xor_into(body, p[12 : 12 + len(body)])
    if length > len(body):
        raise ValueError("the FEC packet cannot rebuild a packet that long")
    byte0 = 0x80 | (first[0] & 0x3F)  # version 2
    return (
        bytes([byte0, first[1]])
        + struct.pack("!H", seq)
        + bytes(first[2:6])
        + fec.ssrc
        + bytes(body[:length])
    )


def protection_share(loss: float | None, on: bool) -> float:
    """FEC packets per media packet for a viewer whose NACKs show ``loss`` (the share
    of packets lost, smoothed), ``on`` if protection is on now (the hysteresis)."""
    if loss is None or loss < (OFF_LOSS if on else ON_LOSS):
        return 0.0
    return min(MAX_SHARE, 0.1 + 4.0 * loss)


@dataclass
class FecCounts:
    media_packets: int = 0
    media_bytes: int = 0
    fec_packets: int = 0
    fec_bytes: int = 0
    fec_padded: int = 0  # NACKed FEC numbers answered with padding
    retransmits: int = 0
    retransmits_unmapped: int = 0  # aiortc resent a packet we no longer map
    dropped_on_purpose: int = 0  # (``drop``: the tests' injected loss)
    too_long: int = 0  # FEC packets not sent: longer than SRTP takes
    unreadable: int = 0  # media sent unprotected: a header this could not read

    def as_dict(self) -> dict[str, float | int]:
        total = self.media_bytes + self.fec_bytes
        return {
            "media_packets": self.media_packets,
            "fec_packets": self.fec_packets,
            "fec_bytes": self.fec_bytes,
            "overhead": self.fec_bytes / total if total else 0.0,
            "fec_padded": self.fec_padded,
            "retransmits": self.retransmits,
            # (each packet lost on purpose counts again for each resend refused)
            "dropped_on_purpose": self.dropped_on_purpose,
            "too_long": self.too_long,
        }


class FecSender:
    """In front of one viewer's transport: RED and ULPFEC at ``share()`` FEC packets
    per media packet (0: media sent as it is). ``red_pt`` and ``ulpfec_pt`` are the
    negotiated payload types. ``drop(wire_seq)`` (tests only) says a media packet is
    lost on the way, its retransmissions too: only FEC can bring it back."""

    def __init__(
        self,
        send: Send,
        red_pt: int,
        ulpfec_pt: int,
        share: Callable[[], float],
        *,
        drop: Callable[[int], bool] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._send = send
        self._clock = clock
        self._sent_at: OrderedDict[int, float] = OrderedDict()  # ours → when sent
        self._asked: OrderedDict[int, None] = OrderedDict()  # ours, NACKed once already
        self.red_pt = red_pt
        self.ulpfec_pt = ulpfec_pt
        self._share = share
        self._drop = drop
        self._next: int | None = None  # our next sequence number
        self._last_theirs: int | None = None  # aiortc's newest
        self._to_sent: OrderedDict[int, int] = OrderedDict()  # aiortc's → ours
        self._from_sent: OrderedDict[int, int] = OrderedDict()  # ours → aiortc's
        # ours → the media's payload type, timestamp and SSRC, for FEC numbers
        self._fec_numbers: OrderedDict[int, bytes] = OrderedDict()
        self._dropped: set[int] = set()
        self._group: list[bytes] = []
        self._pending: list[tuple[bytes, bytes]] = []  # (header, FEC) for the frame's end
        self._group_frames = 0
        self.counts = FecCounts()

    def share(self) -> float:
        return self._share()

    def now(self) -> float:
        return self._clock()

    def to_sent(self, theirs: int) -> int | None:
        return self._to_sent.get(theirs)

    def feedback_s(self, lost: list[int]) -> float | None:
        """How long ago the packet after the newest of ``lost`` left: the receiver saw
        the gap when that one arrived, so this is the NACK's round trip, the link's
        queue included (receiver reports stop giving one once the queue holds them
        longer than a report interval). None if not known."""
        # Only the numbers asked for the first time: a receiver asks again for a gap a
        # round trip or more later, which says nothing of the link.
        fresh = [s for s in lost if s not in self._asked]
        for s in fresh:
            self._remember(self._asked, s, None)
        if not fresh:
            return None
        newest = max(fresh, key=lambda s: _seq_delta(s, fresh[0]))
        at = self._sent_at.get((newest + 1) & 0xFFFF)
        return None if at is None else self._clock() - at

    def nacked(self, seqs: list[int]) -> tuple[list[int], list[int]]:
        """A NACK's numbers (ours) → (aiortc's numbers of the media among them, our
        numbers of the FEC packets among them)."""
        media = [self._from_sent[s] for s in seqs if s in self._from_sent]
        fec = [s for s in seqs if s in self._fec_numbers]
        return media, fec

    async def pad_fec(self, seqs: list[int]) -> None:
        """Answer NACKed FEC numbers with padding-only packets (RFC 3550's P bit, the
        media's payload type, no payload): the receiver counts the number as come."""
        for s in seqs:
            head = self._fec_numbers.get(s)
            if head is None:
                continue
            self.counts.fec_padded += 1
            await self._send(bytes([0xA0, head[0]]) + s.to_bytes(2, "big") + head[1:] + PADDING)

    async def __call__(self, data: bytes) -> None:
        if is_rtcp(data) or len(data) < 12:
            await self._send(data)
            return
        theirs = seq_of(data)
        if self._last_theirs is not None and _seq_delta(theirs, self._last_theirs) <= 0:
            await self._retransmit(data, theirs)
            return
        self._last_theirs = theirs
        if self._next is None:
            self._next = theirs
        ours = self._take_seq()
        self._remember(self._sent_at, ours, self._clock())
        self._remember(self._to_sent, theirs, ours)
        self._remember(self._from_sent, ours, theirs)
        packet = with_seq(data, ours)
        share = self._share()
        self.counts.media_packets += 1
        self.counts.media_bytes += len(packet)
        end_of_frame = bool(packet[1] & 0x80)
        if share <= 0.0 and not self._group:
            await self._out(packet, packet, ours)
            if end_of_frame and self._pending:
                await self._send_fec()
            return
        try:
            wrapped = red_wrap(packet, self.red_pt)
        except ValueError:  # a header this cannot read (two-byte extensions): as it is
            self.counts.unreadable += 1
            await self._out(packet, packet, ours)
            return
        await self._out(wrapped, packet, ours)
        self._group.append(packet)
        self._group_frames += end_of_frame
        full = len(self._group) >= MAX_PROTECTED
        if full or (
            end_of_frame and (len(self._group) >= MIN_GROUP or self._group_frames >= GROUP_FRAMES)
        ):
            self._protect(max(share, 1.0 / MAX_PROTECTED))
        if end_of_frame:
            await self._send_fec()

    def _protect(self, share: float) -> None:
        """FEC for the group so far, sent at its frame's end (``_send_fec``): a key frame
        is longer than one group, and an FEC packet numbered inside a frame stops
        Chromium's decoder (its H.264 frames are the numbers between two timestamps)."""
        group, self._group, self._group_frames = self._group, [], 0
        count = min(len(group), max(1, math.ceil(len(group) * share)))
        last = group[-1]
        at = payload_start(last)
        for j in range(count):
            # Interleaved: packet i in FEC i mod count, so a burst of ``count`` losses
            # in a row is still rebuilt (each in its own FEC packet).
            self._pending.append((last[:at], ulpfec_payload(group[j::count])))

    async def _send_fec(self) -> None:
        pending, self._pending = self._pending, []
        for head, fec in pending:  # (the header of the group's last media packet)
            ours = self._take_seq()
            self._remember(self._sent_at, ours, self._clock())
            header = head[:1] + bytes([self.red_pt]) + ours.to_bytes(2, "big") + head[4:]
            packet = header + bytes([self.ulpfec_pt]) + fec
            if len(packet) > RTP_MAX:  # (media longer than MEDIA_PAYLOAD_MAX: unprotected)
                self.counts.too_long += 1
                continue
            self._remember(self._fec_numbers, ours, bytes([head[1] & 0x7F]) + head[4:12])
            self.counts.fec_packets += 1
            self.counts.fec_bytes += len(packet)
            await self._send(packet)

    async def _retransmit(self, data: bytes, theirs: int) -> None:
        ours = self._to_sent.get(theirs)
        if ours is None:
            self.counts.retransmits_unmapped += 1
            return
        self.counts.retransmits += 1
        if ours in self._dropped:
            self.counts.dropped_on_purpose += 1
            return
        await self._send(with_seq(data, ours))

    async def _out(self, wire: bytes, media: bytes, ours: int) -> None:
        if self._drop is not None and self._drop(ours):
            self._dropped.add(ours)
            if len(self._dropped) > SEQ_MAP_SIZE:
                self._dropped.discard(min(self._dropped, key=lambda s: _seq_delta(s, ours)))
            self.counts.dropped_on_purpose += 1
            return
        await self._send(wire)

    def _take_seq(self) -> int:
        assert self._next is not None
        ours = self._next
        self._next = (ours + 1) & 0xFFFF
        return ours

    @staticmethod
    def _remember(table: OrderedDict, key: int, value: object, size: int = SEQ_MAP_SIZE) -> None:  # type: ignore[type-arg]
        table[key] = value
        table.move_to_end(key)
        while len(table) > size:
            table.popitem(last=False)


@dataclass
class RxCounts:
    red: int = 0
    fec: int = 0
    recovered: int = 0
    fec_unusable: int = 0


class FecReceiver:
    """RED and ULPFEC undone on received RTP packets (as bytes): ``receive`` returns the
    packets to hand on, in the media's payload type: the media packet itself, or, for
    an FEC packet, an empty packet in its place (its number counts as received, as
    libwebrtc's receiver counts it as padding) and any packet it rebuilt. Packets in
    other payload types pass as they are."""

    def __init__(self, red_pt: int, ulpfec_pt: int) -> None:
        self.red_pt = red_pt
        self.ulpfec_pt = ulpfec_pt
        self._media: OrderedDict[int, bytes] = OrderedDict()  # seq → packet
        self._fec: list[FecPacket] = []
        self._media_pt: int | None = None
        self.counts = RxCounts()

    def receive(self, data: bytes) -> list[bytes]:
        if len(data) < 12 or (data[1] & 0x7F) != self.red_pt:
            if len(data) >= 12:
                self._keep(data)
                return [data, *self._recover()]
            return [data]
        self.counts.red += 1
        inner = red_unwrap(data)
        if inner is None:
            return []
        if (inner[1] & 0x7F) != self.ulpfec_pt:
            self._keep(inner)
            return [inner, *self._recover()]
        self.counts.fec += 1
        at = payload_start(inner)
        try:
            self._fec.append(FecPacket.parse(inner[at:], inner[8:12]))
        except ValueError:
            self.counts.fec_unusable += 1
        del self._fec[:-RX_FEC_KEPT]
        out = []
        if self._media_pt is not None:  # in its place, an empty packet of the media
            out.append(inner[:1] + bytes([self._media_pt]) + inner[2:at])
        return out + self._recover()

    def _keep(self, packet: bytes) -> None:
        self._media_pt = packet[1] & 0x7F
        seq = seq_of(packet)
        self._media[seq] = packet
        self._media.move_to_end(seq)
        while len(self._media) > RX_MEDIA_KEPT:
            self._media.popitem(last=False)

    def _recover(self) -> list[bytes]:
        rebuilt: list[bytes] = []
        progress = True
        while progress:
            progress = False
            for fec in list(self._fec):
                missing = [s for s in fec.protected if s not in self._media]
                if not missing:
                    self._fec.remove(fec)
                    continue
                if len(missing) > 1:
                    continue
                self._fec.remove(fec)
                others = [self._media[s] for s in fec.protected if s != missing[0]]
                try:
                    packet = recover(fec, others, missing[0])
                except ValueError:
                    self.counts.fec_unusable += 1
                    continue
                self._keep(packet)
                self.counts.recovered += 1
                rebuilt.append(packet)
                progress = True
        return rebuilt


def allow() -> None:
    """Let aiortc negotiate RED and ULPFEC for video (once per process). They carry no
    encoder: aiortc sends with the first codec agreed, which stays H.264 or VP8. (The
    media's payloads are cut to MEDIA_PAYLOAD_MAX per protected sender: ``protect_peer``.)"""
    for mime, pt in ((RED_MIME, RED_OFFER_PT), (ULPFEC_MIME, ULPFEC_OFFER_PT)):
        aiortc_compat.offer_video_codec(mime, pt)


def is_fec_codec(codec: object) -> bool:
    return str(getattr(codec, "mimeType", "")).lower() in (RED_MIME, ULPFEC_MIME)


def negotiated(pc: object) -> tuple[int, int] | None:
    """(RED's, ULPFEC's) payload types agreed on ``pc``'s video, or None if not both."""
    for transceiver in pc.getTransceivers():  # type: ignore[attr-defined]
        if transceiver.kind != "video":
            continue
        types = {
            c.mimeType.lower(): c.payloadType for c in aiortc_compat.agreed_codecs(transceiver)
        }
        if RED_MIME in types and ULPFEC_MIME in types:
            return types[RED_MIME], types[ULPFEC_MIME]
    return None


def protect_peer(
    pc: object, share: Callable[[], float], drop: Callable[[int], bool] | None = None
) -> FecSender | None:
    """Put a ``FecSender`` in front of the video sender's transport, if the peers agreed
    on RED and ULPFEC; None otherwise."""
    types = negotiated(pc)
    if types is None:
        return None
    for transceiver in pc.getTransceivers():  # type: ignore[attr-defined]
        transport = getattr(transceiver.sender, "transport", None)
        send = aiortc_compat.send_rtp_path(transport)
        if transceiver.kind != "video" or send is None or isinstance(send, FecSender):
            continue
        # Room for RED's and FEC's headers in every packet: this sender's payloads only
        aiortc_compat.limit_payload(transceiver, MEDIA_PAYLOAD_MAX)
        fec = FecSender(send, *types, share, drop=drop)
        aiortc_compat.put_in_rtp_path(transport, fec)
        return fec
    return None
