"""The ICE servers (STUN, TURN) every video peer uses: the page's RTCPeerConnection
(``GET /api/v1/video/ice``) and the media worker's aiortc peers alike, from one list.

Each entry of ``Settings.ice_servers`` is a URL: ``stun:host:port``;
``turn:user:pass@host:port`` (fixed credentials, given to every page as they are); or
``turn:host:port`` / ``turns:host:port?transport=tcp`` with no credentials, which are
then minted per peer from the TURN server's shared secret, as coturn's
``use-auth-secret`` + ``static-auth-secret`` expects (the "TURN REST API"):

    username   = "<expiry, unix time>:<name>"
    credential = base64(HMAC-SHA1(secret, username))

The secret never leaves the server; what a page gets stops working for new allocations
at the expiry (coturn refuses a timestamp in the past).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
from dataclasses import dataclass, field
from typing import Literal

# RFC 7064/7065 URIs (host, optional port, optional ?transport=udp|tcp), optionally with
# this project's "user:pass@" for fixed TURN credentials.
_URL = re.compile(
    r"(?P<scheme>stuns?|turns?):(?:(?P<creds>.*)@)?(?P<host>\[[0-9A-Fa-f:.]+\]|[^?:@\[\]]+)"
    r"(?::(?P<port>\d{1,5}))?(?:\?transport=(?P<transport>udp|tcp))?"
)
DEFAULT_TTL_S = 3600


class IceConfigError(ValueError):
    """An ICE server URL (or the settings around it) cannot be used; the text says why."""


@dataclass(frozen=True)
class IceServer:
    """One entry of ``RTCConfiguration.iceServers``, as browsers and aiortc take it."""

    urls: tuple[str, ...]
    username: str | None = None
    credential: str | None = field(default=None, repr=False)


def turn_rest_credentials(secret: str, name: str, ttl_s: float, now: float) -> tuple[str, str]:
    """coturn's time-limited credentials: valid for allocations until ``now + ttl_s``
    (unix time, whole seconds) for a TURN server run with ``static-auth-secret=secret``."""
    if ":" in name:
        raise IceConfigError(f"a TURN user name must not contain ':' (got {name!r})")
    username = f"{int(now + ttl_s)}:{name}"
    digest = hmac.new(secret.encode(), username.encode(), hashlib.sha1).digest()
    return username, base64.b64encode(digest).decode("ascii")


@dataclass(frozen=True)
class IceConfig:
    """The ICE servers as configured, and how to use them."""

    servers: tuple[str, ...] = ()
    turn_secret: str | None = field(default=None, repr=False)
    credential_ttl_s: float = DEFAULT_TTL_S
    relay_only: bool = False  # iceTransportPolicy "relay": media only through TURN

    def __post_init__(self) -> None:
        for url in self.servers:
            parse_url(url)  # a bad one says so at start-up, not at the first viewer
        minted = self.minted_urls
        if minted and not self.turn_secret:
            raise IceConfigError(
                f"TURN server {minted[0]!r} has no credentials: set TELEROBOT_TURN_SECRET to"
                " its static-auth-secret (coturn's use-auth-secret), or write them into the"
                " URL (turn:user:pass@host:port)"
            )
        if self.relay_only and not any(_is_turn(u) for u in self.servers):
            raise IceConfigError(
                "relay-only video (TELEROBOT_ICE_RELAY_ONLY) needs a TURN server in"
                " TELEROBOT_ICE_SERVERS, e.g. turn:turn.example.org:3478"
            )

    @property
    def minted_urls(self) -> list[str]:
        """The TURN URLs whose credentials are minted from the shared secret."""
        return [u for u in self.servers if _is_turn(u) and parse_url(u)[1] is None]

    @property
    def transport_policy(self) -> Literal["all", "relay"]:
        return "relay" if self.relay_only else "all"

    def ice_servers(self, name: str, now: float) -> list[IceServer]:
        """The list for one peer; TURN credentials minted now for ``name`` (``now``: unix
        time). TURN servers that share the secret share one entry (one credential)."""
        out: list[IceServer] = []
        shared: list[str] = []
        for url in self.servers:
            bare, creds = parse_url(url)
            if creds is not None:
                out.append(IceServer((bare,), *creds))
            elif _is_turn(bare):
                shared.append(bare)
            else:
                out.append(IceServer((bare,)))
        if shared:
            assert self.turn_secret is not None  # checked in __post_init__
            user, credential = turn_rest_credentials(
                self.turn_secret, name, self.credential_ttl_s, now
            )
            out.append(IceServer(tuple(shared), user, credential))
        return out

    def expires_at(self, now: float) -> int | None:
        """When credentials minted at ``now`` stop opening allocations (unix time)."""
        if self.minted_urls:
            return int(now + self.credential_ttl_s)
        return None


def parse_url(url: str) -> tuple[str, tuple[str, str] | None]:
    """``(url without credentials, (user, password) or None)``; a bad URL raises."""
    m = _URL.fullmatch(url.strip())
    if m is None:
        raise IceConfigError(
            f"cannot use ICE server {url!r}: expected stun:host[:port],"
            " turn:host[:port][?transport=udp|tcp] or turn:user:pass@host[:port]"
        )
    port = m["port"]
    if port is not None and not 0 < int(port) < 65536:
        raise IceConfigError(f"ICE server {url!r}: port {port} is out of range")
    if m["scheme"].startswith("stun") and (m["creds"] is not None or m["transport"]):
        raise IceConfigError(f"ICE server {url!r}: a STUN URL has no credentials or transport")
    bare = f"{m['scheme']}:{m['host']}" + (f":{port}" if port else "")
    if m["transport"]:
        bare += f"?transport={m['transport']}"
    if m["creds"] is None:
        return bare, None
    user, sep, password = m["creds"].partition(":")
    if not sep or not user:
        raise IceConfigError(f"ICE server {url!r}: credentials are written user:pass@host")
    return bare, (user, password)


def _is_turn(url: str) -> bool:
    return url.strip().startswith("turn")
