"""The messages between the server (``MediaSupervisor``) and its media worker, typed:
one frozen dataclass per request, so mypy checks every field where a request is made
and the worker's ``match`` covers every kind (``assert_never``). They cross the pipe
pickled, inside an ``Envelope`` carrying the id its ``Reply`` comes back with.

Replies stay a ``dict`` of the request's own fields (an SDP answer, stats, counts):
each is read in one place, next to the request that asked for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from telerobot.server.media.layers import LayerMode


@dataclass(frozen=True)
class Answer:
    """A viewer's SDP offer, answered by a new peer (``peer_id``, ``peer_secret``, SDP)."""

    sdp: str
    type: str
    layer: LayerMode = "auto"
    operator: bool = False  # the server checked the operator token (its own stream)


@dataclass(frozen=True)
class Offer:
    """The server offers first: a new peer's SDP offer (``peer_id``, ``peer_secret``)."""

    layer: LayerMode = "auto"
    operator: bool = False


@dataclass(frozen=True)
class Accept:
    """A viewer's answer to the server's offer."""

    peer_id: str
    sdp: str
    type: str
    peer_secret: str | None = None


@dataclass(frozen=True)
class ClosePeer:
    """Close a peer: the operator any (the server checked the token), others their own."""

    peer_id: str
    peer_secret: str | None = None
    operator: bool = False


@dataclass(frozen=True)
class ClaimViewer:
    """Tie a peer (or a relay viewer) to the realtime client ``viewer`` watching it."""

    peer_id: str
    peer_secret: str | None
    viewer: str


@dataclass(frozen=True)
class Stats:
    """The pipeline's figures (and the relay's); ``peer_ids``: list the peers."""

    peer_ids: bool = False


@dataclass(frozen=True)
class RelayOffer:
    """An observer's offer through the media server, from ``address``."""

    address: str = ""


@dataclass(frozen=True)
class RelayAccept:
    peer_id: str
    peer_secret: str | None
    sdp: str


@dataclass(frozen=True)
class RelayAlive:
    peer_id: str
    peer_secret: str | None


@dataclass(frozen=True)
class RelayClose:
    peer_id: str
    peer_secret: str | None
    operator: bool = False


@dataclass(frozen=True)
class Keyframe:
    """A key frame as soon as the encoder may (shared and rate-limited like any)."""


@dataclass(frozen=True)
class Record:
    """Start (``on``) or stop sending the encoded video to the recording's pipe."""

    on: bool


@dataclass(frozen=True)
class Board:
    """Show the ChArUco board in the simulated camera at calibration pose ``view``
    (None: hide it)."""

    view: int | None


@dataclass(frozen=True)
class Shutdown:
    """Stop the worker (also what a closed pipe means)."""


MediaRequest = (
    Answer
    | Offer
    | Accept
    | ClosePeer
    | ClaimViewer
    | Stats
    | RelayOffer
    | RelayAccept
    | RelayAlive
    | RelayClose
    | Keyframe
    | Record
    | Board
    | Shutdown
)
RELAY_REQUESTS = (RelayOffer, RelayAccept, RelayAlive, RelayClose)


@dataclass(frozen=True)
class Envelope:
    """A request on its way to the worker; ``id`` None: nobody waits for the reply."""

    id: int | None
    request: MediaRequest


@dataclass(frozen=True)
class Reply:
    """The worker's answer to the request ``id``: ``result`` if ``ok``, else the error's
    ``code`` (a ``TelerobotError``'s, rebuilt as its class by the server) and text."""

    id: int | None
    ok: bool
    result: dict[str, Any] = field(default_factory=dict)
    code: str = ""
    error: str = ""


@dataclass(frozen=True)
class Ready:
    """The worker is up (sent once, first): requests may come."""

    time: float
