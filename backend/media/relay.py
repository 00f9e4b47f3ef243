"""The media worker's side of the media server: observers watch through Janus,
so the robot's computer sends the one encoded stream once, whoever watches.

- **The feed**: while anyone watches through it, the full layer's H.264 packets (a tap
  on the pipeline, the same bytes the direct viewers get, no second encode) go as RTP
  to the mountpoint's port (``RtpFeed``). An RTCP sender report a second goes to its
  RTCP port: Janus latches that address and sends the viewers' key frame requests
  (PLI) back to it, and the encoder makes a key frame only when asked.
- **Signalling**: the server's ``/webrtc/server-offer`` for an observer comes here. A
  session on Janus's HTTP API watches the mountpoint and gives Janus's SDP offer; the
  answer starts it; a DELETE (or the viewer's peer failing: Janus's ``hangup``)
  destroys it. Each session's events are long-polled, which also keeps it alive.
- **Limits**: at most ``max_viewers`` sessions and ``max_pending`` not yet answered
  (answered within ``pending_expiry_s`` or destroyed): a flood of connects costs
  sessions on the media server, refused beyond the limits, and never reaches the
  control plane (which is in another process).
- **Per address**: those limits are shared by everyone, so one address alone could
  take them all and lock every other observer out. Each address (the caller's IP, as
  the server saw it) gets a rate of offers (``offers_per_address_per_s``, a burst of
  ``OFFER_BURST_S`` seconds' worth), at most ``max_pending_per_address`` unanswered
  and ``max_viewers_per_address`` watching, refused (429, ``RelayBusy``) before
  any request to the media server.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import httpx

from telerobot.drivers.base import TelerobotError
from telerobot.server.media.encoder import EncodedFrame
from telerobot.server.media.janus import MOUNTPOINT, RtpFeed
from telerobot.server.realtime.ratelimit import PeerLimits
from telerobot.server.security import token_matches

if TYPE_CHECKING:
    from telerobot.server.settings import Settings

log = logging.getLogger(__name__)

RELAY_PREFIX = "relay-"  # the peer ids of viewers through the media server
REPORT_INTERVAL_S = 1.0  # RTCP sender reports to the mountpoint (and the address latch)
OFFER_TIMEOUT_S = 10.0
POLL_RETRIES = 3  # failed long polls in a row before a session is given up
OFFER_BURST_S = 4.0  # the burst of offers per address: this many seconds' worth, at least 1
HTTP_CONNECTIONS = 64  # to Janus's HTTP API, shared by every session's requests


class RelayUnavailable(TelerobotError):
    code = "relay_unavailable"
    http_status = 503


class RelayFull(TelerobotError):
    code = "relay_full"
    http_status = 503


class RelayBusy(TelerobotError):
    """This address asks for more than its share of the media server."""

    code = "relay_busy"
    http_status = 429


class RelayPeerUnknown(TelerobotError):
    code = "relay_peer_unknown"
    http_status = 404


@dataclass
class RelaySession:
    peer_id: str
    session: int
    handle: int
    created: float
    secret: str = field(default_factory=lambda: secrets.token_urlsafe(16))
    started: bool = False
    destroyed: bool = False
    poller: asyncio.Task[None] | None = None
    viewer: str | None = None  # the one viewer name whose alignment this peer may save
    seen: float = 0.0  # its page last said it is alive (monotonic)
    address: str = ""  # who asked for it (the caller's IP)

    def owned_by(self, secret: str | None) -> bool:
        return token_matches(secret, self.secret)


@dataclass(frozen=True)
class RelayLimits:
    """How many observers the media server takes, and how fast: read from the server's
    settings (``media_server_*``, where each is declared once with its default and why)."""

    max_viewers: int
    max_pending: int  # offered, not yet answered
    pending_expiry_s: float
    # A watching viewer whose page has not said it is alive for this long is dropped:
    # Janus 1.1.2 does not notice a viewer that vanished without closing (a laptop shut, a
    # crash; not within 75 s here, ICE keep-alive checks on), and would send it video.
    viewer_timeout_s: float
    # Per address. A page makes one offer when it opens and one per renegotiation (after
    # backoff); a few a second is a page reloading in a loop, more is a flood.
    offers_per_address_per_s: float
    max_pending_per_address: int  # a few pages (or tabs) of one machine connecting
    max_viewers_per_address: int  # watching, from one address

    @classmethod
    def of(cls, settings: Settings) -> RelayLimits:
        return cls(
            max_viewers=settings.media_server_max_viewers,
            max_pending=settings.media_server_max_pending,
            pending_expiry_s=settings.media_server_pending_expiry_s,
            viewer_timeout_s=settings.media_server_viewer_timeout_s,
            offers_per_address_per_s=settings.media_server_offers_per_address_per_s,
            max_pending_per_address=settings.media_server_max_pending_per_address,
            max_viewers_per_address=settings.media_server_max_viewers_per_address,
        )


class JanusRelay:
    """Observers' peers on Janus, and the RTP feed they watch."""

    def __init__(
        self,
        api: str,
        rtp_port: int,
        rtcp_port: int | None,
        request_keyframe: Any,
        start_feed: Any,
        stop_feed: Any,
        *,
        limits: RelayLimits,
        api_secret: str | None = None,
        host: str = "127.0.0.1",
        mountpoint: int = MOUNTPOINT,
    ) -> None:
        self.api = api.rstrip("/")
        self._secret = {"apisecret": api_secret} if api_secret else {}
        self.mountpoint = mountpoint
        self.limits = limits
        # Offers a second per address: the /ws table's kind (bounded, oldest dropped).
        self.offer_limits = PeerLimits(
            connections_per_s=limits.offers_per_address_per_s,
            connection_burst=max(1.0, limits.offers_per_address_per_s * OFFER_BURST_S),
        )
        self.feed = RtpFeed(rtp_port, host=host, rtcp_port=rtcp_port)
        self._request_keyframe = request_keyframe
        self._start_feed, self._stop_feed = start_feed, stop_feed
        self.sessions: dict[str, RelaySession] = {}
        self.http = httpx.AsyncClient(
            timeout=httpx.Timeout(OFFER_TIMEOUT_S, read=40.0),
            limits=httpx.Limits(max_connections=HTTP_CONNECTIONS),
        )
        # Every session's long poll holds a connection for up to 30 s: on a pool of
        # their own (one each), so they never keep a new viewer's requests waiting.
        self.polls = httpx.AsyncClient(
            timeout=httpx.Timeout(OFFER_TIMEOUT_S, read=40.0),
            limits=httpx.Limits(max_connections=limits.max_viewers, max_keepalive_connections=64),
        )
        self._n = 0
        self._tasks: list[asyncio.Task[None]] = []
        self.feeding = False
        self.plis = 0  # key frame requests from the media server
        self.refused = 0  # connects refused by the limits
        self.refused_per_address = 0  # connects refused by an address's share
        self.expired = 0  # connects never answered within pending_expiry_s
        self.pending_peak = 0  # the most connecting at once (never above max_pending)
        self.ended = 0  # sessions ended by the media server (the viewer's peer failed)
        self.silent = 0  # watching sessions dropped: their page stopped saying it is alive
        self.errors = 0  # requests the media server failed

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        loop = asyncio.get_running_loop()
        loop.add_reader(self.feed.fileno(), self._feedback)
        self._tasks = [
            asyncio.create_task(self._report_loop(), name="relay-reports"),
            asyncio.create_task(self._expire_loop(), name="relay-expiry"),
        ]

    async def shutdown(self) -> None:
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        with contextlib.suppress(Exception):
            asyncio.get_running_loop().remove_reader(self.feed.fileno())
        await asyncio.gather(
            *(self._destroy(s) for s in list(self.sessions.values())), return_exceptions=True
        )
        self._set_feeding()
        await self.http.aclose()
        await self.polls.aclose()
        self.feed.close()

    def send(self, encoded: EncodedFrame) -> None:
        """The pipeline's tap: one access unit to the mountpoint (never blocks: UDP)."""
        self.feed.send(encoded.packet)

    def _feedback(self) -> None:
        if self.feed.read_feedback():
            self.plis += 1
            self._request_keyframe()  # shared and spaced by the fan-out's gate

    async def _report_loop(self) -> None:
        while True:
            self.feed.send_report()
            await asyncio.sleep(REPORT_INTERVAL_S)

    async def _expire_loop(self) -> None:
        while True:
            await asyncio.sleep(1.0)
            now = time.monotonic()
            for s in list(self.sessions.values()):
                if not s.started and now - s.created > self.limits.pending_expiry_s:
                    self.expired += 1
                    await self._destroy(s)
                elif s.started and now - s.seen > self.limits.viewer_timeout_s:
                    self.silent += 1
                    await self._destroy(s)

    def _set_feeding(self) -> None:
        """Encode and send only while someone watches (or is about to) through Janus."""
        want = bool(self.sessions)
        if want and not self.feeding:
            self._start_feed()
        elif not want and self.feeding:
            self._stop_feed()
        self.feeding = want

    # ------------------------------------------------------------ Janus's HTTP API
    async def _post(self, url: str, body: dict[str, Any]) -> dict[str, Any]:
        self._n += 1
        try:
            response = await self.http.post(
                url, json={**body, **self._secret, "transaction": str(self._n)}
            )
            reply: dict[str, Any] = response.json()
        except (httpx.HTTPError, ValueError) as exc:
            self.errors += 1
            raise RelayUnavailable(
                f"the media server does not answer ({type(exc).__name__}): it is restarting"
                " or down; try again in a few seconds"
            ) from exc
        if reply.get("janus") == "error":
            self.errors += 1
            reason = reply.get("error", {}).get("reason", reply)
            raise RelayUnavailable(f"the media server refused: {reason}")
        return reply

    async def _message(
        self, s: RelaySession, body: dict[str, Any], jsep: dict[str, Any] | None = None
    ) -> dict[str, Any]:
        payload: dict[str, Any] = {"janus": "message", "body": body}
        if jsep is not None:
            payload["jsep"] = jsep
        return await self._post(f"{self.api}/{s.session}/{s.handle}", payload)

    # ------------------------------------------------------------ signalling
    def _check_address(self, address: str) -> None:
        """Refuse an offer beyond ``address``'s share (before any work for it)."""
        if self.offer_limits.connect(address, time.monotonic()) is None:
            self.refused_per_address += 1
            limits = self.offer_limits
            raise RelayBusy(
                f"too many offers from {address or 'your address'}: at most"
                f" {limits.connection_burst:g} at once, then {limits.connections_per_s:g} a"
                " second; try again in a few seconds"
            )
        mine = [s for s in self.sessions.values() if s.address == address]
        waiting = sum(1 for s in mine if not s.started)
        if waiting >= self.limits.max_pending_per_address:
            self.refused_per_address += 1
            raise RelayBusy(
                f"{address or 'your address'} has {waiting} offers not yet answered, the"
                f" most one address may have: answer them (POST /api/v1/webrtc/answer) or"
                f" close them (DELETE /api/v1/webrtc/{{peer_id}}); unanswered ones expire"
                f" after {self.limits.pending_expiry_s:g} s"
            )
        watching = len(mine) - waiting
        if watching >= self.limits.max_viewers_per_address:
            self.refused_per_address += 1
            raise RelayBusy(
                f"{address or 'your address'} already has {watching} viewers watching"
                " through the media server, the most one address may have: close one first"
                " (DELETE /api/v1/webrtc/{peer_id})"
            )

    async def offer(self, address: str = "") -> dict[str, Any]:
        """A new observer at ``address`` (its IP): Janus's SDP offer for the mountpoint,
        with the peer's id and secret (for ``accept`` and ``close``)."""
        self._check_address(address)
        pending = sum(1 for s in self.sessions.values() if not s.started)
        if len(self.sessions) >= self.limits.max_viewers or pending >= self.limits.max_pending:
            self.refused += 1
            raise RelayFull(
                f"the media server has {len(self.sessions)} viewers ({pending} connecting):"
                f" the limit is {self.limits.max_viewers}"
                f" ({self.limits.max_pending} connecting); try later"
            )
        # Counted from now, before the first request to Janus: connects arriving at once
        # all see each other.
        s = RelaySession(
            RELAY_PREFIX + secrets.token_urlsafe(9), 0, 0, time.monotonic(), address=address
        )
        self.sessions[s.peer_id] = s
        self.pending_peak = max(self.pending_peak, pending + 1)
        try:
            session = (await self._post(self.api, {"janus": "create"}))["data"]["id"]
            if s.destroyed:  # expired (or shut down) while Janus made it: undo it there
                await self._post(f"{self.api}/{session}", {"janus": "destroy"})
                raise RelayUnavailable("the media server took too long to answer; try again")
            s.session = session
            attached = await self._post(
                f"{self.api}/{s.session}", {"janus": "attach", "plugin": "janus.plugin.streaming"}
            )
            s.handle = attached["data"]["id"]
            self._set_feeding()
            await self._message(s, {"request": "watch", "id": self.mountpoint})
            jsep = await self._next_offer(s)
            if s.destroyed:
                raise RelayUnavailable("the media server took too long to answer; try again")
        except BaseException:
            await self._destroy(s)
            raise
        s.poller = asyncio.create_task(self._poll(s), name=f"relay-{s.peer_id}")
        return {"peer_id": s.peer_id, "peer_secret": s.secret, "sdp": jsep["sdp"], "type": "offer"}

    async def _next_offer(self, s: RelaySession) -> dict[str, Any]:
        deadline = time.monotonic() + OFFER_TIMEOUT_S
        while time.monotonic() < deadline:
            for event in await self._events(s):
                if "jsep" in event:
                    jsep: dict[str, Any] = event["jsep"]
                    return jsep
                if event.get("janus") == "event" and "error" in str(event.get("plugindata")):
                    raise RelayUnavailable(f"the media server refused to watch: {event}")
        raise RelayUnavailable(f"the media server sent no offer within {OFFER_TIMEOUT_S:g} s")

    async def _events(self, s: RelaySession) -> list[dict[str, Any]]:
        try:
            params = {"maxev": "5", **self._secret}
            got = (await self.polls.get(f"{self.api}/{s.session}", params=params)).json()
        except (httpx.HTTPError, ValueError) as exc:
            raise RelayUnavailable(f"the media server's events failed: {exc!r}") from exc
        events = got if isinstance(got, list) else [got]
        if any(e.get("janus") == "error" for e in events):
            raise RelayUnavailable(f"the media server lost the session: {events}")
        return events

    async def _poll(self, s: RelaySession) -> None:
        """The session's events until it ends: a ``hangup`` (its peer failed or closed)
        or the media server gone ends it here too. Each poll keeps it alive."""
        failures = 0
        try:
            while s.peer_id in self.sessions:
                try:
                    events = await self._events(s)
                except RelayUnavailable as exc:
                    # A dropped keep-alive connection is no reason to end a viewer; a
                    # session Janus no longer knows (or Janus gone for good) is.
                    failures += 1
                    if "lost the session" in str(exc) or failures >= POLL_RETRIES:
                        break
                    await asyncio.sleep(0.2 * failures)
                    continue
                failures = 0
                if any(e.get("janus") in ("hangup", "detached", "timeout") for e in events):
                    self.ended += 1
                    break
        except asyncio.CancelledError:
            return
        await self._destroy(s, poller=False)

    def claim_viewer(self, peer_id: str, secret: str | None, viewer: str) -> None:
        """May this peer save ``viewer``'s alignment? One viewer name per peer."""
        s = self._own(peer_id, secret)
        if s.viewer is not None and s.viewer != viewer:
            raise RelayPeerUnknown(f"this peer saves the alignment of viewer {s.viewer!r} only")
        s.viewer = viewer

    async def accept(self, peer_id: str, secret: str | None, sdp: str) -> None:
        s = self._own(peer_id, secret)
        await self._message(
            s, {"request": "start"}, {"type": "answer", "sdp": sdp, "trickle": False}
        )
        s.started, s.seen = True, time.monotonic()

    def alive(self, peer_id: str, secret: str | None) -> None:
        """Its page is still there (every ~15 s; see ``RelayLimits.viewer_timeout_s``)."""
        self._own(peer_id, secret).seen = time.monotonic()

    async def close_viewer(self, peer_id: str, secret: str | None, operator: bool = False) -> None:
        s = self.sessions.get(peer_id)
        if s is None:
            return  # already gone (its peer failed): nothing to do
        if not operator:
            self._own(peer_id, secret)
        await self._destroy(s)

    def _own(self, peer_id: str, secret: str | None) -> RelaySession:
        s = self.sessions.get(peer_id)
        if s is None or not s.owned_by(secret):
            # The same answer for an unknown id and a wrong secret: ids are not probed.
            raise RelayPeerUnknown(f"no viewer {peer_id!r} with this secret on the media server")
        return s

    async def _destroy(self, s: RelaySession, poller: bool = True) -> None:
        if s.destroyed:
            return
        s.destroyed = True
        self.sessions.pop(s.peer_id, None)
        self._set_feeding()  # at once: the count is right before Janus answers
        if poller and s.poller is not None:
            s.poller.cancel()
        if s.session:
            with contextlib.suppress(RelayUnavailable):
                await self._post(f"{self.api}/{s.session}", {"janus": "destroy"})

    def stats(self) -> dict[str, Any]:
        return {
            "viewers": sum(1 for s in self.sessions.values() if s.started),
            "pending": sum(1 for s in self.sessions.values() if not s.started),
            "max_viewers": self.limits.max_viewers,
            "max_pending": self.limits.max_pending,
            "feeding": self.feeding,
            "rtp_packets": self.feed.packets,
            "key_frame_requests": self.plis,
            "refused": self.refused,
            "refused_per_address": self.refused_per_address,
            "max_pending_per_address": self.limits.max_pending_per_address,
            "max_viewers_per_address": self.limits.max_viewers_per_address,
            "expired": self.expired,
            "pending_peak": self.pending_peak,
            "ended_by_media_server": self.ended,
            "dropped_silent": self.silent,
            "viewer_timeout_s": self.limits.viewer_timeout_s,
            "errors": self.errors,
        }
