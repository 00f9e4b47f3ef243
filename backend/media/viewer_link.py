"""One viewer's link as the media worker follows it (docs/architecture.md, "Media"):
what its receiver reports over RTCP (``ViewerLink``: loss, round trips, its NACKs and
their queue), the FEC protection that follows them (``Protection``), and the one place
that reaches into aiortc's sender to hear those reports and answer NACKs
(``follow_link``: rule 24, other projects' internals behind one adapter). Time is
passed in (``now``): the policy is tested on made-up clocks."""

from __future__ import annotations

import contextlib
import math
import statistics
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from aiortc import RTCRtpSender
from aiortc.rtp import (
    RTCP_PSFB_APP,
    RTCP_RTPFB_NACK,
    RTP_HISTORY_SIZE,
    RtcpPsfbPacket,
    RtcpRrPacket,
    RtcpRtpfbPacket,
    RtcpSrPacket,
    unpack_remb_fci,
)

from telerobot.server.media import aiortc_compat
from telerobot.server.media import fec as ulpfec
from telerobot.server.media.resend_budget import ResendBudget
from telerobot.server.telemetry.stats import DriftingFloor

NACKED_KEPT = 1024  # media packets a viewer NACKed, remembered to count each once
# The loss a viewer's NACKs show: the packets NACKed over those sent in the last
# LOSS_WINDOWS seconds, a cut link's seconds left out (its burst of NACKs is not FEC's
# to help). It was the median of each second's share: at 1 % random loss and ~90
# packets a second most seconds NACK nothing, the median was 0 and FEC stayed off on
# `wan` (bench.wan, Chromium: 174 packets lost, protection's loss 0).
LOSS_WINDOWS = 5
# FEC adds bytes: on a link whose queue already holds this much (the NACKs' round trip
# above their floor), more would only lengthen it, and every frame, force and command
# behind it waits longer. Protection pauses there (bench.netem's `bad` link, 2 Mbit/s
# shared with the forces: with FEC its queue grew to 2 s in one run of two).
QUEUED_NO_FEC_S = 0.1
# …seen QUEUED_SECONDS seconds in a row (a cut link's backlog is one), and stays paused
# FEC_PAUSE_S after: a queue the FEC's own bytes built drains once it pauses, and would
# build again as soon as it resumed (on `bad` the forces' p99 went from ~0.3 s to
# 0.7-3.8 s with a pause of a second at a time).
QUEUED_SECONDS = 2
# A new viewer's FEC waits this many seconds of its link's figures (the queue is judged
# from its NACKs): on `bad` FEC from the first second, with the first key frames, filled
# the link's 1000-packet queue (5 s) before the queue could be seen.
FEC_AFTER_S = 3
FEC_PAUSE_S = 15.0
# A second in which the viewer NACKed this share of the packets was a cut link: the
# backlog after it (resends, the forces held up) is not a queue of FEC's making, and is
# not judged for CUT_SETTLE_S (on `mobile` it paused FEC for the rest of a run).
CUT_LOSS = 0.5
CUT_SETTLE_S = 5.0
NACK_RTTS_KEPT = 16
NACK_RTT_FRESH_S = 10.0  # a NACK's round trip says how the link is for this long
# A key frame sent for NACKs replaces the packets before it for this long: a receiver
# asks again for a gap for up to 10 round trips (libwebrtc), a few seconds.
KEYFRAME_COVERS_S = 5.0
# …and a viewer's NACKs ask for a key frame at most this often: a viewer NACKing the
# oldest packets the sender keeps, again and again, forced one every 0.5 s (the fan-out
# gate's most) for every viewer. A receiver that still misses a picture asks with a PLI.
KEYFRAME_AGAIN_S = 2.0
FLOOR_DRIFT = 0.01  # s per s
# A NACKed number this far behind the newest sent, or ahead of it, was never sent to
# this viewer (or so long ago that no receiver still waits for it): it is not loss, and
# asks for no resend and no key frame (a flood of NACKs from a random base did).
NACK_AGE_MAX = 3000
RTP_OVERHEAD = 20  # bytes a resent packet adds to its payload (header, extensions)


@dataclass
class ViewerLink:
    """What this viewer's receiver reports of its link (RTCP): its bandwidth estimate
    (REMB), the loss in its last receiver report, the round trip. The figures a layer
    choice per viewer needs; None until reported."""

    estimated_bps: int | None = None
    fraction_lost: float | None = None  # of the packets in the last report interval
    packets_lost: int | None = None  # cumulative
    rtt_s: float | None = None
    reports: int = 0
    # NACKed packets the sender no longer had (older than its history): their frames
    # can only be replaced, so each such NACK asks for a key frame.
    nacks_unservable: int = 0
    # The newest packet sent when such a NACK last asked for a key frame: that key frame
    # goes out after it, so it replaces every packet up to it. A receiver NACKs a gap
    # again and again (libwebrtc up to 10 times): those repeats ask for nothing more,
    # where each had cost a key frame (every 0.5 s for 4 s after a 1.5 s cut on
    # `mobile`, each queueing the link for ~250 ms).
    keyframe_covers_through: int | None = None
    keyframe_covers_at: float = -math.inf  # (monotonic) when: it holds KEYFRAME_COVERS_S
    nacks_superseded: int = 0
    # Packets a NACK asked for that were not resent: the key frame it brought (or the
    # one on its way) replaces them.
    resends_spared: int = 0
    jitter_s: float | None = None  # the receiver's interarrival jitter
    # NACKed numbers never sent to this viewer (ahead of the newest, or NACK_AGE_MAX
    # behind it): ignored.
    nacks_never_sent: int = 0
    # What its resends may cost (resend_budget.py); set by the pipeline.
    budget: ResendBudget | None = None
    # The NACKs' own round trips (fec.FecSender.feedback_s: the queue included), the
    # newest few, and their floor (the link without a queue), which drifts up by
    # FLOOR_DRIFT so that a link whose delay grew for good is followed.
    nack_rtts: deque[tuple[float, float]] = field(  # (when, round trip)
        default_factory=lambda: deque(maxlen=NACK_RTTS_KEPT)
    )
    nack_rtt_floor: DriftingFloor = field(default_factory=lambda: DriftingFloor(FLOOR_DRIFT))

    def nack_rtt(self, rtt: float, now: float) -> None:
        self.nack_rtts.append((now, rtt))
        self.nack_rtt_floor.update(rtt, now)

    def fresh_rtt(self, now: float) -> float | None:
        """The median round trip of the NACKs of the last NACK_RTT_FRESH_S."""
        fresh = [rtt for at, rtt in self.nack_rtts if now - at <= NACK_RTT_FRESH_S]
        return statistics.median(fresh) if fresh else None

    def queued_s(self, now: float) -> float | None:
        """How much longer the recent NACKs took than the floor: the link's queue (None
        without a recent NACK: a clean link says nothing of its queue)."""
        rtt = self.fresh_rtt(now)
        if rtt is None or self.nack_rtt_floor.value is None:
            return None
        return rtt - self.nack_rtt_floor.value

    def repair_s(self, now: float) -> float | None:
        """What a repair takes now: the recent NACKs' round trip (else the reports')."""
        rtt = self.fresh_rtt(now)
        return self.rtt_s if rtt is None else rtt

    # Media packets NACKed (each once): the loss before any repair, which receiver
    # reports hide (a resent packet counts as received in them).
    nacked: int = 0
    nacked_recent: dict[int, None] = field(default_factory=dict)

    def count_nacked(self, seqs: list[int]) -> None:
        for seq in seqs:
            if seq not in self.nacked_recent:
                self.nacked += 1
                self.nacked_recent[seq] = None
        while len(self.nacked_recent) > NACKED_KEPT:
            del self.nacked_recent[next(iter(self.nacked_recent))]

    def as_dict(self, now: float) -> dict[str, Any]:
        return {
            "estimated_kbps": None if self.estimated_bps is None else self.estimated_bps / 1000,
            "loss": self.fraction_lost,
            "packets_lost": self.packets_lost,
            "rtt_ms": None if self.rtt_s is None else self.rtt_s * 1000,
            "reports": self.reports,
            "nacks_unservable": self.nacks_unservable,
            "nacks_superseded": self.nacks_superseded,
            "resends_spared": self.resends_spared,
            "nacks_never_sent": self.nacks_never_sent,
            "resends": None if self.budget is None else self.budget.as_dict(),
            "jitter_ms": None if self.jitter_s is None else self.jitter_s * 1000,
            "packets_nacked": self.nacked,
            "nack_rtt_ms": None if (r := self.fresh_rtt(now)) is None else r * 1000,
            "queued_ms": None if (q := self.queued_s(now)) is None else q * 1000,
        }


@dataclass
class Protection:
    """A viewer's FEC share and what it is judged from, about once a second: the loss
    its NACKs show (over the last LOSS_WINDOWS seconds, cuts left out), paused while
    its link's queue builds (``judge``)."""

    loss: float | None = None  # the share of packets its NACKs show lost (LOSS_WINDOWS)
    # each second's (packets sent, NACKed), a cut second's as (0, 0)
    losses: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=LOSS_WINDOWS))
    fec_share: float = 0.0  # FEC packets per media packet now
    counted: tuple[int, int] = (0, 0)  # (packets sent, NACKed) when loss was last judged
    fec_paused: int = 0  # seconds protection paused: the link's queue was building
    fec_paused_until: float = 0.0
    queued_seconds: int = 0  # seconds in a row the link was seen queuing
    cut_at: float | None = None  # when its link was last seen cut

    def judge(
        self, sent: int, link: ViewerLink, mode: str, now: float, budgeted: bool = False
    ) -> None:
        """A second more of the viewer's link: ``sent`` media packets so far, ``link``'s
        NACKs; ``mode`` the setting ("auto", "on", "off"). ``budgeted``: this viewer's
        encoder makes room for the FEC inside its link's estimate (the operator's own
        stream, rate_control.py), so a queue is the rate's to answer, not a reason to
        pause the FEC."""
        nacked = link.nacked
        d_sent, d_nacked = sent - self.counted[0], nacked - self.counted[1]
        if d_sent <= 0:
            return
        self.counted = (sent, nacked)
        cut = d_nacked / d_sent >= CUT_LOSS
        if cut:
            self.cut_at = now
        self.losses.append((0, 0) if cut else (d_sent, d_nacked))
        sent_all = sum(n for n, _ in self.losses)
        self.loss = min(1.0, sum(k for _, k in self.losses) / sent_all) if sent_all else 0.0
        queued = link.queued_s(now)
        if mode == "on":
            self.fec_share = ulpfec.MAX_SHARE
        if mode != "auto":
            return
        settled = self.cut_at is None or now - self.cut_at > CUT_SETTLE_S
        queuing = settled and not budgeted and queued is not None and queued > QUEUED_NO_FEC_S
        self.queued_seconds = self.queued_seconds + 1 if queuing else 0
        if self.queued_seconds >= QUEUED_SECONDS:
            self.fec_paused_until = now + FEC_PAUSE_S
        if now < self.fec_paused_until:
            self.fec_share = 0.0
            self.fec_paused += 1
        elif len(self.losses) >= FEC_AFTER_S:
            self.fec_share = ulpfec.protection_share(self.loss, self.fec_share > 0)


def seq_newer(a: int, b: int) -> bool:
    """RTP sequence number ``a`` comes after ``b`` (16 bits, wrapping)."""
    return 0 < (a - b) % 65536 < 32768


def newest_sent(history: dict[int, Any]) -> int | None:
    """The newest sequence number in aiortc's RTP history (128 packets, all close)."""
    seqs: list[int] = [p.sequence_number for p in history.values()]
    if not seqs:
        return None
    return max(seqs, key=lambda s: (s - seqs[0] + 32768) % 65536)


def sent_ever(seq: int, newest: int | None) -> bool:
    """Whether ``seq`` can have been sent: not ahead of the newest number sent, nor more
    than NACK_AGE_MAX behind it."""
    return newest is not None and (newest - seq) % 65536 <= NACK_AGE_MAX


def _lost(packet: Any, lost: list[int]) -> RtcpRtpfbPacket:
    """The NACK ``packet`` naming only ``lost``."""
    return RtcpRtpfbPacket(
        fmt=packet.fmt, ssrc=packet.ssrc, media_ssrc=packet.media_ssrc, lost=lost
    )


def follow_link(
    sender: RTCRtpSender,
    link: ViewerLink,
    fec: Callable[[], ulpfec.FecSender | None] = lambda: None,
    on_repair: Callable[[], None] = lambda: None,
    now: Callable[[], float] = time.monotonic,
) -> None:
    """Copy what the receiver reports over RTCP into ``link`` (aiortc keeps REMB and the
    loss to itself: its handler is replaced, through aiortc_compat). With FEC
    on (``fec()``), a NACK names the wire's sequence numbers: aiortc gets its own
    numbers for the media, the FEC packets are resent here. ``on_repair`` hears of
    each NACK for media (a repair the viewer waits for). Numbers never sent are
    ignored, and resends are kept within ``link.budget`` (resend_budget.py)."""

    async def on_nack(packet: Any) -> None:
        protection = fec()
        fec_seqs: list[int] = []
        if protection is not None:
            rtt = protection.feedback_s(packet.lost)
            if rtt is not None:
                link.nack_rtt(rtt, now())
            media, fec_seqs = protection.nacked(packet.lost)
            packet = _lost(packet, media)
        history = aiortc_compat.rtp_history(sender)
        newest = newest_sent(history)
        if packet.lost:
            sent = [seq for seq in packet.lost if sent_ever(seq, newest)]
            link.nacks_never_sent += len(packet.lost) - len(sent)
            packet = _lost(packet, sent)
        link.count_nacked(packet.lost)
        if packet.lost:
            on_repair()
        # After a cut or a burst of loss the receiver asks for packets older than the
        # sender's history: nothing can resend them, and a receiver would wait seconds
        # for its next periodic key frame (or its own give-up). Send one now (the
        # fan-out gate shares it and spaces them out), unless the one already asked
        # for replaces these packets. Either way the key frame replaces every packet
        # sent before it, so none of those is resent: after a cut, the resends (a
        # history's worth, FEC's too) took the link for a second and the key frame
        # waited. The key frame's own packets, and any after it, are.
        at = now()
        if at - link.keyframe_covers_at > KEYFRAME_COVERS_S:
            # The key frame went out long ago (and a 16-bit number compared with one
            # far back would read as older half the time): forget it
            link.keyframe_covers_through = None
        gone = [
            seq
            for seq in packet.lost
            if getattr(history.get(seq % RTP_HISTORY_SIZE), "sequence_number", None) != seq
        ]
        covered = link.keyframe_covers_through
        if gone and covered is not None and not any(seq_newer(s, covered) for s in gone):
            link.nacks_superseded += len(gone)
        elif gone:
            link.nacks_unservable += len(gone)
            if at - link.keyframe_covers_at >= KEYFRAME_AGAIN_S:
                link.keyframe_covers_through = newest
                link.keyframe_covers_at = at
                aiortc_compat.request_keyframe(sender)
        covered = link.keyframe_covers_through
        if covered is not None:
            media = [s for s in packet.lost if seq_newer(s, covered)]
            wire = None if protection is None else protection.to_sent(covered)
            later_fec = [s for s in fec_seqs if wire is None or seq_newer(s, wire)]
            # What the key frame replaces and could have been resent (not the gone ones)
            spared_media = len(packet.lost) - len(gone) - len(media)
            link.resends_spared += spared_media + len(fec_seqs) - len(later_fec)
            packet = _lost(packet, media)
            fec_seqs = later_fec
        budget = link.budget
        if budget is not None:
            rtt = link.repair_s(at)
            kept = []
            for seq in packet.lost:
                p = history.get(seq % RTP_HISTORY_SIZE)
                if p is None or p.sequence_number != seq:
                    continue  # gone (above)
                if budget.allow(seq, len(p.payload) + RTP_OVERHEAD, rtt, at):
                    kept.append(seq)
            packet = _lost(packet, kept)
            fec_seqs = [s for s in fec_seqs if budget.allow(("fec", s), RTP_OVERHEAD, rtt, at)]
        if packet.lost:
            await handle(packet)  # the media first: the repairs the viewer waits for
        if protection is not None:
            await protection.pad_fec(fec_seqs)

    async def on_rtcp(packet: Any) -> None:
        if isinstance(packet, RtcpRtpfbPacket) and packet.fmt == RTCP_RTPFB_NACK:
            await on_nack(packet)
            return
        await handle(packet)
        if isinstance(packet, RtcpRrPacket | RtcpSrPacket):
            for report in packet.reports:
                if report.ssrc == aiortc_compat.ssrc(sender):
                    link.fraction_lost = report.fraction_lost / 256
                    link.packets_lost = report.packets_lost
                    link.rtt_s = aiortc_compat.rtt_s(sender)
                    link.jitter_s = report.jitter / 90000  # (video's clock)
                    link.reports += 1
        elif isinstance(packet, RtcpPsfbPacket) and packet.fmt == RTCP_PSFB_APP:
            with contextlib.suppress(ValueError):
                bitrate, ssrcs = unpack_remb_fci(packet.fci)
                if aiortc_compat.ssrc(sender) in ssrcs:
                    link.estimated_bps = bitrate

    # (aiortc's own handler: the on_* above call it for what aiortc still does)
    handle = aiortc_compat.handle_rtcp(sender, on_rtcp)
