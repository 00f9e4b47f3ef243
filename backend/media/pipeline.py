"""Camera → one encoder → every WebRTC peer, plus the peers themselves. Capture and
encoding are ``Encoding`` (encoding.py); here are the peers: signalling, their limits,
their links (layer, FEC, playout delay, pacing) and the figures of both.

Runs inside the media worker process (``backend/media/worker.py``) so that capture,
encoding and packetising can never stall the server's event loop; tests also run it
in-process. Capture and encoding each have a thread of their own; the event loop
only moves packets and talks to peers.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from aiortc import (
    RTCConfiguration,
    RTCIceServer,
    RTCIceTransportPolicy,
    RTCPeerConnection,
    RTCRtpSender,
    RTCSessionDescription,
)

from telerobot.drivers.base import StereoCamera, TelerobotError
from telerobot.drivers.clock import Clock, MonotonicClock
from telerobot.protocol.netprio import mark_low_priority
from telerobot.server.media import aiortc_compat
from telerobot.server.media import fec as ulpfec
from telerobot.server.media.encoding import IDLE_POLL_S as IDLE_POLL_S
from telerobot.server.media.encoding import Encoding
from telerobot.server.media.encoding import no_signal_frame as no_signal_frame
from telerobot.server.media.fanout import SharedVideoTrack
from telerobot.server.media.ice import IceConfig, parse_url
from telerobot.server.media.layers import (
    LOW_BITRATE,
    LOW_SCALE,
    OPERATOR,
    Layer,
    LayerChoice,
    LayerMode,
)
from telerobot.server.media.pacer import Pacer, pace_peer
from telerobot.server.media.playout import AdaptivePlayout, stamp_playout_delay
from telerobot.server.media.playout import allow as allow_playout_delay
from telerobot.server.media.rate_control import RateControl
from telerobot.server.media.resend_budget import ResendBudget
from telerobot.server.media.supervisor import MediaUnavailable
from telerobot.server.media.viewer_link import Protection, ViewerLink, follow_link
from telerobot.server.security import token_matches

if TYPE_CHECKING:
    from telerobot.server.settings import Settings

log = logging.getLogger(__name__)


class BadOffer(TelerobotError):
    """The session description cannot be used; the reason says why."""

    code = "bad_offer"
    http_status = 400


class ViewerLimitReached(MediaUnavailable):
    """Every viewer place (or every place for a viewer still connecting) is taken."""

    code = "viewer_limit"


class TurnUnavailable(MediaUnavailable):
    """Relay-only video, and the TURN server gave this peer no relay address."""

    code = "turn_unavailable"


class NotYourPeer(TelerobotError):
    """The peer secret does not match: only the viewer that opened a peer may use it
    (or the operator, with the operator token). The server answers 403."""

    code = "not_your_peer"
    http_status = 403


# Limits on the peers one media worker holds (docs/architecture.md, rule 18). Each peer costs
# ~0.6 MB of worker memory and, once connected, its share of the uplink (up to the
# bitrate, 8 Mbit/s by default) and of packetising; the lab's use is an operator and a
# few observers (the benchmark runs 6 viewers).
MAX_VIEWERS = 16  # peers in all, connected or connecting
MAX_PENDING = 8  # peers still connecting: page loads at the same moment
# A peer that has not connected by then is closed: ICE with host candidates takes well
# under a second, through TURN a few; an unanswered server offer is dropped.
PENDING_EXPIRY_S = 10.0
EXPIRY_CHECK_S = 1.0  # how often the worker looks for expired peers
PEER_SECRET_BYTES = 16  # 128 bits, sent back once with the answer
PACE_MAX_LOSS = 0.05  # a viewer's link losing this much is not paced (_layer_bps)
FEC_MODES = ("auto", "off", "on")
# A new operator's peer this soon after the last one's rate was known starts from that
# rate (the page re-negotiates after a stall: bench.wan saw each new peer start at 8
# Mbit/s on a 2 Mbit/s link, twice a run).
OPERATOR_RATE_KEPT_S = 30.0


def _declared(name: str) -> Any:
    """A video setting's default as the server's ``Settings`` declares it (rule 20: a
    setting is declared once; imported late, the settings import this package)."""
    from telerobot.server.settings import Settings

    return Settings.model_fields[name].default


def _default(name: str) -> Any:
    return field(default_factory=lambda: _declared(name))


@dataclass(frozen=True)
class VideoSettings:
    """What the pipeline needs of the settings (``of``), each default the ``Settings``
    field's (backend/settings.py, where each is explained)."""

    fps: float = _default("video_fps")
    fps_auto: bool = _default("video_fps_auto")  # down to 30 when it cannot keep it
    bitrate: int = _default("video_bitrate")
    keyframe_interval: float = _default("keyframe_interval_s")  # 0: only when asked
    cbr: bool = _default("video_cbr")
    low_scale: float = LOW_SCALE  # the low layer's size, of each side (not a setting)
    low_bitrate: int = LOW_BITRATE
    pacing: bool = _default("video_pacing")  # backend/media/pacer.py
    zero_playout_delay: bool = _default("video_zero_playout_delay")  # media/playout.py
    adaptive_playout: bool = _default("video_adaptive_playout")
    playout_max_ms: int = _default("video_playout_max_ms")  # media/playout.py
    fec: str = _default("video_fec")  # RED + ULPFEC (backend/media/fec.py)
    operator_encoder: bool = _default("video_operator_encoder")  # media/rate_control.py
    drop_every: int = _default("video_drop_every")  # tests and demos: lost for good
    ice: IceConfig = field(default_factory=IceConfig)  # STUN/TURN (backend/media/ice.py)

    @classmethod
    def of(cls, settings: Settings) -> VideoSettings:
        """The server's settings for the video."""
        return cls(
            fps=settings.video_fps,
            fps_auto=settings.video_fps_auto,
            bitrate=settings.video_bitrate,
            keyframe_interval=settings.keyframe_interval_s,
            cbr=settings.video_cbr,
            pacing=settings.video_pacing,
            zero_playout_delay=settings.video_zero_playout_delay,
            adaptive_playout=settings.video_adaptive_playout,
            playout_max_ms=settings.video_playout_max_ms,
            fec=settings.video_fec,
            operator_encoder=settings.video_operator_encoder,
            drop_every=settings.video_drop_every,
            ice=settings.ice_config,
        )


@dataclass
class Peer:
    pc: RTCPeerConnection
    track: SharedVideoTrack
    created: float
    link: ViewerLink = field(default_factory=ViewerLink)
    secret: str = field(default_factory=lambda: secrets.token_urlsafe(PEER_SECRET_BYTES))
    connected: bool = False
    viewer: str | None = None  # the one viewer name whose alignment this peer may save
    mode: LayerMode = "auto"  # "auto": the layer follows this viewer's link
    choice: LayerChoice = field(default_factory=LayerChoice)
    pacer: Pacer | None = None  # in front of its transport's RTP, once connected
    fec: ulpfec.FecSender | None = None  # likewise, if RED and ULPFEC were agreed
    playout: AdaptivePlayout = field(default_factory=AdaptivePlayout)
    protection: Protection = field(default_factory=Protection)  # its FEC share
    operator: bool = False  # opened with the operator token
    # The operator's own stream's rate (rate_control.py), while this peer has it
    rate: RateControl | None = None

    def owned_by(self, secret: str | None) -> bool:
        return token_matches(secret, self.secret)


# The name in the TURN credentials the server's own peers mint ("<expiry>:telerobot-server"
# in the TURN server's log; a page's are "…:telerobot-viewer").
SERVER_TURN_NAME = "telerobot-server"


def _ice(config: IceConfig, now: float | None = None) -> RTCConfiguration:
    """aiortc's configuration for one peer: the same servers as the page's, TURN
    credentials minted now (unix time). aiortc uses the first STUN and the first TURN
    URL it can (turn: over UDP or TCP, turns: over TCP)."""
    servers = config.ice_servers(SERVER_TURN_NAME, time.time() if now is None else now)
    policy = RTCIceTransportPolicy.RELAY if config.relay_only else RTCIceTransportPolicy.ALL
    return RTCConfiguration(
        iceServers=[
            RTCIceServer(urls=list(s.urls), username=s.username, credential=s.credential)
            for s in servers
        ],
        iceTransportPolicy=policy,
    )


class VideoPipeline:
    def __init__(
        self,
        camera: StereoCamera,
        settings: VideoSettings | None = None,
        *,
        clock: Clock | None = None,
        max_viewers: int = MAX_VIEWERS,
        max_pending: int = MAX_PENDING,
        pending_expiry_s: float = PENDING_EXPIRY_S,
    ) -> None:
        self.camera = camera
        self.settings = settings or VideoSettings()
        if self.settings.zero_playout_delay:
            allow_playout_delay()  # negotiated with each viewer from now on
        if self.settings.fec not in FEC_MODES:
            raise ValueError(f"video fec must be one of {FEC_MODES}, not {self.settings.fec!r}")
        if self.settings.fec != "off":
            ulpfec.allow()
        aiortc_compat.check()  # the internals the video uses are where they were
        self.clock: Clock = clock or MonotonicClock()
        self.max_viewers = max_viewers
        self.max_pending = max_pending
        self.pending_expiry_s = pending_expiry_s
        self.encoding = Encoding(camera, self.settings, self.clock)
        self.peers: dict[str, Peer] = {}
        # The operator's last rate and when (a new operator's peer within
        # OPERATOR_RATE_KEPT_S starts from it: the same link)
        self._operator_rate_was: tuple[float, float] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._closing: set[asyncio.Task[None]] = set()  # expired peers' connections

    @property
    def viewers(self) -> int:
        return self.encoding.viewers

    # ------------------------------------------------------------ its tasks
    def start(self) -> None:
        self.camera.start()
        self._tasks = [
            asyncio.create_task(self.encoding.run(), name="video-pipeline"),
            asyncio.create_task(self._expire_loop(), name="video-peer-expiry"),
        ]

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        await asyncio.gather(
            *(p.pc.close() for p in self.peers.values()), *self._closing, return_exceptions=True
        )
        self.peers.clear()
        await self.encoding.close()

    # ------------------------------------------------------------ peers and their limits
    @property
    def pending(self) -> int:
        return sum(1 for p in self.peers.values() if not p.connected)

    async def _expire_loop(self) -> None:
        while True:
            await self.clock.sleep(EXPIRY_CHECK_S)
            self.expire_pending()
            self.adapt_layers()
            self.adapt_protection()
            self.adapt_operator_rate()

    def operator_peer(self) -> Peer | None:
        """The peer that gets the operator's own stream: the newest connected one
        opened with the operator token, on H.264 and "auto" (a layer asked for by name
        is kept); None if there is none or the setting is off. One at most: each is an
        encode of its own."""
        if not self.settings.operator_encoder:
            return None
        candidates = [
            p
            for p in self.peers.values()
            if p.operator and p.connected and p.mode == "auto" and self._codec_of(p) == "H264"
        ]
        return max(candidates, key=lambda p: p.created, default=None)

    def adapt_layers(self) -> None:
        """Each connected viewer on "auto" gets the layer its link carries (called about
        once a second; the decision and its hysteresis are ``LayerChoice``'s), the
        operator's peer its own stream (``operator_peer``)."""
        now = self.clock.now()
        full_bps = self.encoding.layer_rate["full"].bps(now)
        chosen = self.operator_peer()
        for peer in self.peers.values():
            if not peer.connected or peer.mode != "auto":
                continue
            if peer is chosen:
                if peer.rate is None:
                    self._follow_operator(peer)
                continue  # its own rate decides (adapt_operator_rate), not the layers
            if peer.rate is not None:  # another operator's peer is newer: back to sharing
                peer.rate = None
                if self._layer_of(peer) == OPERATOR or peer.track.joining is not None:
                    self.set_layer(peer, "full")
            before = peer.choice.layer
            layer = peer.choice.decide(peer.link, full_bps, now)
            if layer != before:
                log.info("a viewer moves to the %s layer: %s", layer, peer.choice.why)
                self.set_layer(peer, layer)

    def _follow_operator(self, peer: Peer) -> None:
        """Follow ``peer``'s link with a rate of its own, starting at the configured
        bitrate; it stays on the shared full layer until the rate falls below that
        (``adapt_operator_rate``)."""
        s, encoding = self.settings, self.encoding
        full, low = encoding.layer_size("full"), encoding.layer_size("low")
        peer.rate = RateControl(s.bitrate, 2 * full[0] * full[1], 2 * low[0] * low[1], encoding.fps)
        was = self._operator_rate_was
        if was is not None and self.clock.now() - was[1] < OPERATOR_RATE_KEPT_S:
            peer.rate.carry_on_from(was[0], "the operator's previous video peer's rate")

    def _remember_operator_rate(self, peer: Peer) -> None:
        if peer.rate is not None:
            self._operator_rate_was = (peer.rate.target_bps, self.clock.now())

    def adapt_protection(self) -> None:
        """Each connected viewer's loss (from its NACKs, about once a second) and the
        FEC share that follows it (``Protection.judge``, backend/media/viewer_link.py);
        the operator's FEC fits inside its rate (``budgeted``)."""
        now = self.clock.now()
        for peer in self.peers.values():
            if peer.connected:
                peer.protection.judge(
                    _packets_sent(peer),
                    peer.link,
                    self.settings.fec,
                    now,
                    budgeted=peer.rate is not None and self._layer_of(peer) == OPERATOR,
                )

    def adapt_operator_rate(self) -> None:
        """The operator's rate follows its link's latest report (``RateControl``); below
        the configured bitrate the operator gets its own encoder, whose bitrate is that
        rate less FEC's share of it, and shares the full layer again once the rate has
        been back at the top for a while (``needs_own_stream``)."""
        peer = next((p for p in self.peers.values() if p.rate is not None), None)
        if peer is None or peer.rate is None:
            return
        rate, encoding, now = peer.rate, self.encoding, self.clock.now()
        rate.fps = encoding.fps  # (30 while the machine cannot keep 60: frame_rate.py)
        share = peer.protection.fec_share
        changed = rate.update(peer.link, peer.protection.loss, now)
        self._remember_operator_rate(peer)
        own = self._layer_of(peer) == OPERATOR or (
            peer.track.joining is not None
            and peer.track.joining is encoding.broadcasters.get(("H264", OPERATOR))
        )
        if rate.needs_own_stream(now) and not own:
            encoding.operator_rate = rate
            encoding.follow_operator_rate(share)
            log.info("the operator's viewer gets its own stream: %s", rate.why)
            self.set_layer(peer, OPERATOR)
        elif not rate.needs_own_stream(now) and self._layer_of(peer) != "full":
            if peer.track.joining is None:  # (a move already asked for: its key frame)
                log.info("the operator's link carries the full layer again: shared")
                self.set_layer(peer, "full")
        elif own and (changed or share != encoding.operator_fec_share):
            log.debug("the operator's stream: %s", rate.why)
            encoding.follow_operator_rate(share)

    def _repair_asked(self, peer: Peer) -> None:
        """The viewer NACKed media: a repair it waits for a round trip (and the
        jitter) plus the frame interval in which it saw the gap."""
        if not self.settings.adaptive_playout or not self.settings.zero_playout_delay:
            return
        rtt = peer.link.repair_s(self.clock.now())
        if rtt is None:
            return
        repair = rtt + 2 * (peer.link.jitter_s or 0.0) + 1.0 / self.encoding.fps
        peer.playout.repair(self.clock.now(), repair)

    def set_layer(self, peer: Peer, layer: Layer) -> None:
        """Move ``peer`` to ``layer`` (from that layer's next keyframe, asked for now)."""
        codec = self._codec_of(peer)
        self.encoding.encoder_for(codec, layer)
        peer.track.move_to(self.encoding.broadcasters[(codec, layer)])

    def expire_pending(self) -> list[str]:
        """Drop the peers that have not connected within ``pending_expiry_s``: they
        leave ``peers`` (and their tracks the fan-out) at once; their connections close
        in the background."""
        now = self.clock.now()
        expired = [
            pid
            for pid, p in self.peers.items()
            if not p.connected and now - p.created >= self.pending_expiry_s
        ]
        for pid in expired:
            peer = self._detach(pid)
            if peer is not None:
                task = asyncio.create_task(peer.pc.close(), name=f"video-peer-expired-{pid}")
                self._closing.add(task)
                task.add_done_callback(self._closing.discard)
        if expired:
            log.info("dropped %d peer(s) that did not connect in time", len(expired))
        return expired

    def _make_room(self) -> None:
        """Refuse a new peer (before any work) when the limits are reached."""
        self.expire_pending()
        if len(self.peers) >= self.max_viewers:
            raise ViewerLimitReached(
                f"all {self.max_viewers} viewer places are taken: close a video page"
                " (or ask the operator to) and try again"
            )
        if self.pending >= self.max_pending:
            raise ViewerLimitReached(
                f"{self.max_pending} viewers are connecting right now: try again in a few"
                f" seconds (a viewer that does not connect within {self.pending_expiry_s:g} s"
                " is dropped)"
            )

    def _own(self, peer_id: str, secret: str | None) -> Peer | None:
        """The peer, if ``secret`` is its own; None if there is no such peer."""
        peer = self.peers.get(peer_id)
        if peer is not None and not peer.owned_by(secret):
            raise NotYourPeer(
                "this is not your peer: send the peer_secret your offer's answer carried"
                " (header X-Peer-Secret), or the operator token"
            )
        return peer

    # ------------------------------------------------------------ signalling
    def _new_peer(
        self, codec: str = "H264", mode: LayerMode = "auto", operator: bool = False
    ) -> tuple[str, Peer]:
        pc = RTCPeerConnection(_ice(self.settings.ice))
        layer: Layer = "low" if mode == "low" else "full"
        self.encoding.encoder_for(codec, layer)
        track = self.encoding.broadcasters[(codec, layer)].new_track()
        transceiver = pc.addTransceiver(track, direction="sendonly")
        wanted = f"video/{codec}"
        caps = RTCRtpSender.getCapabilities("video").codecs
        # The codec first (aiortc sends with the first agreed), then RED and ULPFEC.
        fec_codecs = [c for c in caps if ulpfec.is_fec_codec(c) and self.settings.fec != "off"]
        transceiver.setCodecPreferences([c for c in caps if c.mimeType == wanted] + fec_codecs)
        sender = transceiver.sender
        # A viewer's PLI or FIR: pre-encoded video needs its encoder told
        aiortc_compat.on_keyframe_request(sender, track.keyframe_requested)
        peer_id = secrets.token_hex(8)
        peer = Peer(pc, track, created=self.clock.now(), mode=mode, operator=operator)
        peer.playout = AdaptivePlayout(self.settings.playout_max_ms)
        peer.choice.layer = layer
        # Its resends within a budget of its own layer's rate (a flood of NACKs from one
        # viewer took the shared encoder's time from every other: resend_budget.py).
        peer.link.budget = ResendBudget(lambda: self._layer_rate_bps(peer))
        follow_link(
            sender, peer.link, lambda: peer.fec, lambda: self._repair_asked(peer), self.clock.now
        )
        self.peers[peer_id] = peer

        @pc.on("connectionstatechange")
        async def on_state() -> None:
            if pc.connectionState == "connected":
                peer.connected = True  # no longer pending: it stays until it closes
                for sock in aiortc_compat.peer_sockets(pc):
                    mark_low_priority(sock)  # video: forces and commands go first
                self._wrap_transport(peer)
            if pc.connectionState in ("failed", "closed"):
                await self.close_peer(peer_id)

        return peer_id, peer

    def _wrap_transport(self, peer: Peer) -> None:
        """What each RTP packet to this viewer passes on its way out, from aiortc to
        the socket: the playout-delay stamp, then RED and FEC (over the packets as they
        will leave), then the pacer. Each goes in front of the transport's RTP path,
        so the last put there is the first passed."""
        pc = peer.pc
        if self.settings.pacing and peer.pacer is None:
            # Spread each frame's packets (a key frame's burst would queue the
            # forces behind it on a narrow link): backend/media/pacer.py.
            peer.pacer = pace_peer(pc, lambda: self._layer_bps(peer))
        if self.settings.fec != "off" and peer.fec is None:
            every = self.settings.drop_every
            drop = (lambda seq: seq % every == 0) if every > 0 else None
            peer.fec = ulpfec.protect_peer(pc, lambda: peer.protection.fec_share, drop)
            if self.settings.fec == "on":
                peer.protection.fec_share = ulpfec.MAX_SHARE
        if self.settings.zero_playout_delay:
            stamp_playout_delay(pc, lambda: peer.playout.current(self.clock.now()))

    def _detach(self, peer_id: str) -> Peer | None:
        peer = self.peers.pop(peer_id, None)
        if peer is not None:
            if peer.rate is not None and self.encoding.operator_rate is peer.rate:
                self.encoding.operator_rate = None
            peer.track.stop()
            if peer.pacer is not None:
                peer.pacer.close()
        return peer

    async def close_peer(self, peer_id: str) -> None:
        peer = self._detach(peer_id)
        if peer is not None:
            await peer.pc.close()

    async def close_own_peer(self, peer_id: str, secret: str | None) -> None:
        """A viewer closes its peer (with the secret it got); a gone peer is no error."""
        if self._own(peer_id, secret) is not None:
            await self.close_peer(peer_id)

    def claim_viewer(self, peer_id: str, secret: str | None, viewer: str) -> None:
        """May this live peer save ``viewer``'s alignment? One viewer name per peer."""
        peer = self._own(peer_id, secret)
        if peer is None:
            raise NotYourPeer(
                f"no live peer {peer_id!r}: the alignment is saved with the peer_id and"
                " peer_secret of this page's video connection"
            )
        if peer.viewer is not None and peer.viewer != viewer:
            raise NotYourPeer(f"this peer saves the alignment of viewer {peer.viewer!r} only")
        peer.viewer = viewer

    async def answer(
        self, sdp: str, kind: str, layer: LayerMode = "auto", operator: bool = False
    ) -> dict[str, str]:
        """The browser offers, we answer (the usual way). ``operator``: the offer came
        with the operator token (its peer may get the operator's own stream)."""
        if kind != "offer":
            raise BadOffer(f"expected an SDP of type 'offer', got {kind!r}")
        if "m=video" not in sdp:
            raise BadOffer("the offer has no video section: add a recvonly video transceiver")
        upper = sdp.upper()
        if "H264" in upper:
            codec = "H264"
        elif "VP8" in upper:
            codec = "VP8"  # the fallback: a second encoder, only while such viewers watch
        else:
            raise BadOffer("the offer accepts neither H.264 nor VP8 video")
        self._make_room()
        peer_id, peer = self._new_peer(codec, layer, operator)
        try:
            await peer.pc.setRemoteDescription(RTCSessionDescription(sdp=sdp, type="offer"))
            await peer.pc.setLocalDescription(await peer.pc.createAnswer())
        except Exception as exc:
            await self.close_peer(peer_id)
            raise BadOffer(f"cannot use this offer: {exc}") from None
        await self._check_relay(peer_id, peer)
        return self._description(peer_id, peer)

    async def offer(self, layer: LayerMode = "auto", operator: bool = False) -> dict[str, str]:
        """We offer (for browsers that need the server to): answer with ``accept``."""
        self._make_room()
        peer_id, peer = self._new_peer("H264", layer, operator)
        await peer.pc.setLocalDescription(await peer.pc.createOffer())
        await self._check_relay(peer_id, peer)
        return self._description(peer_id, peer)

    async def _check_relay(self, peer_id: str, peer: Peer) -> None:
        """Relay-only, and no relay candidate: no viewer could ever connect; say why now."""
        ice = self.settings.ice
        if ice.relay_only and " typ relay" not in peer.pc.localDescription.sdp:
            await self.close_peer(peer_id)
            turn = next(u for u in ice.servers if u.startswith("turn"))
            raise TurnUnavailable(
                f"video is relay-only and the TURN server {parse_url(turn)[0]} gave no relay"
                " address: is it running and reachable from the server, and is"
                " TELEROBOT_TURN_SECRET its static-auth-secret (or the URL's user:pass right)?"
            )

    @staticmethod
    def _description(peer_id: str, peer: Peer) -> dict[str, str]:
        local = peer.pc.localDescription
        return {
            "peer_id": peer_id,
            "peer_secret": peer.secret,
            "sdp": local.sdp,
            "type": local.type,
        }

    async def accept(
        self, peer_id: str, sdp: str, kind: str, secret: str | None = None
    ) -> dict[str, str]:
        peer = self._own(peer_id, secret)
        if peer is None:
            raise BadOffer(
                f"no pending offer {peer_id!r} (it may have expired: answer within"
                f" {self.pending_expiry_s:g} s)"
            )
        if kind != "answer":
            raise BadOffer(f"expected an SDP of type 'answer', got {kind!r}")
        try:
            await peer.pc.setRemoteDescription(RTCSessionDescription(sdp=sdp, type="answer"))
        except Exception as exc:
            await self.close_peer(peer_id)
            raise BadOffer(f"cannot use this answer: {exc}") from None
        return {"peer_id": peer_id}

    # ------------------------------------------------------------ telemetry
    def stats(self, peer_ids: bool = False) -> dict[str, Any]:
        """Figures for everyone; the peers' ids only if ``peer_ids`` (the operator's)."""
        now = self.clock.now()
        return {
            **self.encoding.stats(now),
            "viewer_count": len(self.peers),
            "pending": self.pending,
            "max_viewers": self.max_viewers,
            "max_pending": self.max_pending,
            "viewers": [
                {
                    **({"peer_id": pid} if peer_ids else {}),
                    "state": p.pc.connectionState,
                    "frames": p.track.sent_frames,
                    "bytes": p.track.sent_bytes,
                    "mbps": p.track.sent_bytes * 8 / 1e6 / max(now - p.created, 1e-3),
                    "resyncs": p.track.resyncs,
                    # The layer it gets now ("auto": chosen by its link, as the receiver
                    # reports it), how often it moved and why it last did.
                    "layer": self._layer_of(p),
                    "layer_mode": p.mode,
                    "layer_switches": p.track.switches,
                    "layer_why": p.choice.why,
                    # The operator's rate (None: a watcher): its link's estimate now,
                    # the size and frame rate it carries, why it last changed (its own
                    # stream while below the configured bitrate: layer "operator").
                    "rate": None if p.rate is None else p.rate.as_dict(),
                    "link": p.link.as_dict(now),
                    # FEC (None: not agreed with this viewer): the share now, the loss
                    # it follows, what was sent.
                    "fec": None
                    if p.fec is None
                    else {
                        "share": p.protection.fec_share,
                        "loss": p.protection.loss,
                        "paused_s": p.protection.fec_paused,
                        **p.fec.counts.as_dict(),
                    },
                    "playout_delay_ms": p.playout.current(now),
                    # its cap, and the repairs not waited for (longer than the cap)
                    "playout_max_ms": p.playout.max_ms,
                    "repairs_too_slow": p.playout.too_slow,
                    # The pacer (None: not pacing): its rate now, and how many packets
                    # waited for it, how long in all.
                    "pacing": None
                    if p.pacer is None
                    else {
                        "kbps": None if (r := p.pacer.rate()) is None else r / 1000,
                        "packets_waited": p.pacer.paced,
                        "waited_ms": p.pacer.waited_s * 1000,
                        "restamps_abs_send_time": p.pacer.abs_send_time_id is not None,
                    },
                }
                for pid, p in self.peers.items()
            ],
            "camera_running": self.encoding.camera_running,
        }

    def _layer_bps(self, peer: Peer) -> float | None:
        """The measured rate of the layer this peer gets now; None (do not pace) if not
        known, or while its receiver reports PACE_MAX_LOSS or more lost: there the
        delay a pacer adds to every packet, resends included, cost more than the queue
        it saves (bench.wan on `bad`: frozen 72–85 % paced against 20–45 % not, 3
        runs against 2; on `mobile`, 2 % lost, pacing cut the forces' p99 from 334 to
        222–244 ms and left the video as it was)."""
        lost = peer.link.fraction_lost
        if lost is not None and lost >= PACE_MAX_LOSS:
            return None
        return self._layer_rate_bps(peer)

    def _layer_rate_bps(self, peer: Peer) -> float | None:
        """The measured rate of the layer this peer gets now (None: not known)."""
        try:
            return self.encoding.layer_rate[self._layer_of(peer)].bps(self.clock.now())
        except StopIteration:  # (between two layers)
            return None

    def _codec_of(self, peer: Peer) -> str:
        return next(c for (c, _), b in self.encoding.broadcasters.items() if b is peer.track.source)

    def _layer_of(self, peer: Peer) -> Layer:
        return next(x for (_, x), b in self.encoding.broadcasters.items() if b is peer.track.source)


def _packets_sent(peer: Peer) -> int:
    """Media packets sent to this viewer so far (FEC's count, else aiortc's own)."""
    if peer.fec is not None:
        return peer.fec.counts.media_packets
    for transceiver in peer.pc.getTransceivers():
        return aiortc_compat.packets_sent(transceiver.sender)
    return 0
