"""Observers' offers through the media server, shared fairly: one
address re-offering in loops cannot take every slot and lock out an observer at
another; each address gets a rate of offers, a few unanswered ones and a few viewers,
refused beyond with 429 ``relay_busy`` saying which limit (before any work on Janus).

A real server with a real Janus (as tests/test_media_server.py); the callers come from
distinct loopback addresses (127.0.0.x), each test its own."""

from __future__ import annotations

import asyncio
import shutil
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from harness.aiortc_viewers import answer_server_offer
from tests.support import until
from tests.support.servers import serving

CLIENT = {"X-Telerobot-Client": "test"}  # a request that changes something says who it is
OFFER = "api/v1/webrtc/server-offer"
ATTACKERS = 6  # bench.abuse's relay_offers: six tokenless workers at one address
ATTACK_S = 4.0
PER_ADDRESS_PENDING = 4  # the default
VIEWERS_PER_ADDRESS = 2


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    if shutil.which("janus") is None:
        pytest.fail("Debian's janus is missing: `make test` installs it (make media-server-deps)")
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_MEDIA_SERVER": "janus",
        "TELEROBOT_VIDEO_WIDTH": "320",  # the smallest picture: the relay, not the encoder
        "TELEROBOT_VIDEO_HEIGHT": "180",
        "TELEROBOT_VIDEO_FPS": "15",
        # 12 connecting at once in all; never answered, an offer is kept 10 s (past
        # each test: whatever one address holds, it holds throughout).
        "TELEROBOT_MEDIA_SERVER_MAX_PENDING": "12",
        "TELEROBOT_MEDIA_SERVER_PENDING_EXPIRY_S": "10",
        # 1 offer a second per address, after a burst of 4.
        "TELEROBOT_MEDIA_SERVER_OFFERS_PER_ADDRESS_PER_S": "1",
        "TELEROBOT_MEDIA_SERVER_MAX_VIEWERS_PER_ADDRESS": str(VIEWERS_PER_ADDRESS),
    }
    with serving(env, ready=False) as base:
        until(
            lambda: relay_stats(base) is not None,
            timeout=60,
            what="the media server running and its relay answering",
            poll=0.5,
        )
        yield base


def relay_stats(base: str) -> dict[str, Any] | None:
    try:
        video = httpx.get(base + "api/v1/video", timeout=10).json()
    except (httpx.HTTPError, ValueError):
        return None
    if (video.get("media_server") or {}).get("state") != "running":
        return None
    stats: dict[str, Any] | None = (video.get("stats") or {}).get("relay")
    return stats


def client_from(base: str, address: str) -> httpx.AsyncClient:
    return httpx.AsyncClient(
        base_url=base,
        timeout=30,
        headers=CLIENT,
        transport=httpx.AsyncHTTPTransport(local_address=address),
    )


async def close(http: httpx.AsyncClient, peer: dict[str, Any]) -> None:
    r = await http.delete(
        f"api/v1/webrtc/{peer['peer_id']}", headers={"X-Peer-Secret": peer["peer_secret"]}
    )
    assert r.status_code == 200, r.text


def detail(r: httpx.Response) -> str:
    body: dict[str, Any] = r.json()
    assert body["type"].endswith(":relay_busy"), body
    return str(body["detail"])


async def test_one_address_re_offering_cannot_lock_out_an_observer_at_another(
    server: str,
) -> None:
    """bench.abuse's relay_offers attack: six tokenless workers at one address re-offer
    in loops and never answer. Before, they held every connecting slot (the legitimate
    observer got 3 of 16); now that address holds its 4, is told why it gets no more,
    and an observer at another address gets every offer it asks for."""
    statuses: Counter[int] = Counter()
    details: set[str] = set()
    end = time.monotonic() + ATTACK_S

    async def attacker(http: httpx.AsyncClient) -> None:
        while time.monotonic() < end:
            r = await http.post(OFFER, json={})
            statuses[r.status_code] += 1
            if r.status_code == 429:
                details.add(detail(r).split(":")[0])

    async def observer(http: httpx.AsyncClient) -> list[int]:
        got = []
        await asyncio.sleep(0.5)  # the attack is under way
        for _ in range(4):  # within its own address's burst
            r = await http.post(OFFER, json={})
            got.append(r.status_code)
            if r.status_code == 200:
                await close(http, r.json())
            await asyncio.sleep(0.5)
        return got

    async with client_from(server, "127.0.0.3") as bad, client_from(server, "127.0.0.2") as good:
        results = await asyncio.gather(observer(good), *(attacker(bad) for _ in range(ATTACKERS)))
    served = results[0]
    assert served == [200] * 4, (served, statuses)
    assert set(statuses) <= {200, 429}, statuses
    assert statuses[200] <= PER_ADDRESS_PENDING and statuses[429] > 0, statuses
    assert any("too many offers from 127.0.0.3" in d for d in details) or any(
        "127.0.0.3 has 4 offers not yet answered" in d for d in details
    ), details
    relay = relay_stats(server)
    assert relay is not None and relay["refused_per_address"] >= statuses[429], relay
    assert relay["pending"] <= PER_ADDRESS_PENDING, relay  # the observer closed its own


async def test_offers_from_one_address_are_rate_limited_with_the_reason(server: str) -> None:
    """Eight at once from one address: its burst (4) is offered, the rest refused as
    too many, before any request to the media server."""
    async with client_from(server, "127.0.0.4") as http:
        replies = await asyncio.gather(*(http.post(OFFER, json={}) for _ in range(8)))
        offered = [r.json() for r in replies if r.status_code == 200]
        refused = [detail(r) for r in replies if r.status_code == 429]
        try:
            assert len(offered) + len(refused) == 8, [r.status_code for r in replies]
            assert 1 <= len(offered) <= 5, len(offered)  # the burst, and a token refilled
            said = [d for d in refused if d.startswith("too many offers from 127.0.0.4")]
            assert said and "at most 4 at once, then 1 a second" in said[0], refused
        finally:
            for peer in offered:
                await close(http, peer)


async def test_unanswered_offers_per_address_are_bounded_with_the_reason(server: str) -> None:
    """An address may have 4 offers not yet answered; the fifth is refused, saying what
    to do (answer or close them, or wait for them to expire)."""
    async with client_from(server, "127.0.0.5") as http:
        held = []
        for _ in range(PER_ADDRESS_PENDING):
            r = await http.post(OFFER, json={})
            assert r.status_code == 200, r.text
            held.append(r.json())
        await asyncio.sleep(1.2)  # its rate allows another offer by now
        r = await http.post(OFFER, json={})
        try:
            assert r.status_code == 429, r.text
            said = detail(r)
            assert said.startswith("127.0.0.5 has 4 offers not yet answered"), said
            assert "DELETE /api/v1/webrtc/{peer_id}" in said and "expire after 10 s" in said
        finally:
            for peer in held:
                await close(http, peer)
        # Closed, they no longer count.
        await asyncio.sleep(1.2)
        again = await http.post(OFFER, json={})
        assert again.status_code == 200, again.text
        await close(http, again.json())


async def test_viewers_per_address_are_bounded_with_the_reason(server: str) -> None:
    """Two viewers (answered offers) from one address here; a third offer is refused."""
    from aiortc import RTCPeerConnection

    pcs = [RTCPeerConnection() for _ in range(VIEWERS_PER_ADDRESS)]
    async with client_from(server, "127.0.0.6") as http:
        peers = []
        try:
            for pc in pcs:
                peers.append(await answer_server_offer(http, pc))
            r = await http.post(OFFER, json={})
            assert r.status_code == 429, r.text
            said = detail(r)
            assert said.startswith("127.0.0.6 already has 2 viewers watching through"), said
        finally:
            for peer in peers:
                await close(http, peer)
            for pc in pcs:
                await pc.close()


def test_the_relays_limits_are_the_settings_declared_once() -> None:
    """Every limit the relay applies is read from its ``media_server_*`` setting (no
    second default in backend/media/relay.py to drift from the first)."""
    from dataclasses import fields

    from telerobot.server.media.relay import RelayLimits
    from telerobot.server.settings import Settings

    names = [f.name for f in fields(RelayLimits)]
    given = {
        f"media_server_{n}": Settings.model_fields[f"media_server_{n}"].default * 2 for n in names
    }
    limits = RelayLimits.of(Settings(**given))
    assert {n: getattr(limits, n) for n in names} == {n: given[f"media_server_{n}"] for n in names}
