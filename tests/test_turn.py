"""Video through NAT: TURN (coturn) with the TURN REST API's time-limited credentials.

The credentials are checked against a real coturn (`turnserver`, tests/coturn.py), and
the whole path end to end: the server configured relay-only, an aiortc viewer that asks
the server for its ICE configuration (as the page does) and is relay-only too; frames
arrive, the selected candidate pair is relay ↔ relay, and coturn's own accounting shows
the video passed through its relays."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import httpx
import pytest
from aioice import stun, turn
from aiortc import (
    RTCConfiguration,
    RTCIceServer,
    RTCIceTransportPolicy,
    RTCPeerConnection,
    RTCSessionDescription,
)
from playwright.sync_api import Browser
from pydantic import ValidationError

from telerobot.drivers.camera import timecode
from telerobot.server.media.ice import IceConfig, IceConfigError, IceServer, turn_rest_credentials
from tests.support.coturn import Coturn, coturn
from tests.support.servers import serving

SECRET = "turn-test-shared-secret-0123456789"
TOOL = {"X-Telerobot-Client": "tests"}
SMALL = {
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_VIDEO_WIDTH": "640",
    "TELEROBOT_VIDEO_HEIGHT": "360",
    "TELEROBOT_VIDEO_FPS": "20",
}


# ------------------------------------------------------------------ credentials, unit
def test_minted_credentials_are_coturns_rest_api_format() -> None:
    user, credential = turn_rest_credentials("north-wind-shared-secret", "alice", 3600, 1000.9)
    assert user == "4600:alice"  # "<expiry, unix time>:<name>"
    # base64(HMAC-SHA1(secret, username)), as computed by OpenSSL:
    # printf 4600:alice | openssl dgst -sha1 -hmac north-wind-shared-secret -binary | base64
    assert credential == "BRUcmT59Lhs0aVHpH9J1U2inUYk="
    with pytest.raises(IceConfigError, match="':'"):
        turn_rest_credentials("secret", "a:b", 60, 0)


def test_the_ice_list_mints_turn_credentials_and_keeps_fixed_ones() -> None:
    ice = IceConfig(
        (
            "stun:stun.example.org:3478",
            "turn:turn.example.org:3478?transport=udp",
            "turns:turn.example.org:5349?transport=tcp",
            "turn:bob:p@ss:w@old.example.org",  # fixed credentials, as before
        ),
        turn_secret="s" * 16,
        credential_ttl_s=600,
        relay_only=True,
    )
    servers = ice.ice_servers("viewer", now=1_000)
    assert servers[0] == IceServer(("stun:stun.example.org:3478",))
    assert servers[1] == IceServer(("turn:old.example.org",), "bob", "p@ss:w")
    minted = servers[2]  # both minted URLs share one credential
    assert minted.urls == (
        "turn:turn.example.org:3478?transport=udp",
        "turns:turn.example.org:5349?transport=tcp",
    )
    assert (minted.username, minted.credential) == turn_rest_credentials(
        "s" * 16, "viewer", 600, 1_000
    )
    assert ice.expires_at(1_000) == 1_600 and ice.transport_policy == "relay"
    assert "s" * 16 not in repr(ice) and minted.credential not in repr(minted)
    assert IceConfig(("turn:u:p@h:3478",)).expires_at(0) is None  # nothing minted


def test_unusable_ice_settings_say_what_to_set() -> None:
    from telerobot.server.settings import Settings

    with pytest.raises(IceConfigError, match="TELEROBOT_TURN_SECRET"):
        IceConfig(("turn:turn.example.org",))
    with pytest.raises(IceConfigError, match="needs a TURN server"):
        IceConfig(("stun:stun.example.org",), relay_only=True)
    for bad in ("http://x", "turn:", "stun:u:p@h", "turn:h:99999", "turn:h?transport=sctp"):
        with pytest.raises(IceConfigError, match="ICE server"):
            IceConfig((bad,), turn_secret="s" * 16)
    with pytest.raises(ValidationError, match="TELEROBOT_TURN_SECRET"):
        Settings(ice_servers=["turn:turn.example.org"])
    with pytest.raises(ValidationError, match="at least 16"):
        Settings(ice_servers=["turn:turn.example.org"], turn_secret="short")
    ok = Settings(ice_servers=["turn:t.example.org"], turn_secret=SECRET, ice_relay_only=True)
    assert SECRET not in repr(ok) and ok.ice_config.relay_only


# ------------------------------------------------------------------ against coturn
async def allocate(server: Coturn, username: str, credential: str) -> turn.TurnTransport:
    transport, _ = await turn.create_turn_endpoint(
        asyncio.DatagramProtocol, (server.host, server.port), username, credential
    )
    return transport


async def refresh(transport: turn.TurnTransport) -> int:
    """Refresh the allocation now (aioice would at 5/6 of its lifetime): its new lifetime."""
    inner = transport._TurnTransport__inner_protocol  # type: ignore[attr-defined]
    request = stun.Message(message_method=stun.Method.REFRESH, message_class=stun.Class.REQUEST)
    request.attributes["LIFETIME"] = 600
    response, _ = await inner.request_with_retry(request)
    lifetime: int = response.attributes["LIFETIME"]
    return lifetime


def test_coturn_takes_minted_credentials_and_refuses_a_wrong_secret_or_an_expiry_passed() -> None:
    async def run(server: Coturn) -> None:
        now = time.time()
        good = await allocate(server, *turn_rest_credentials(SECRET, "probe", 2, now))
        assert good.get_extra_info("sockname")[0] == server.host  # a relay address
        wrong = turn_rest_credentials("another-secret-0123456789", "probe", 600, now)
        expired = turn_rest_credentials(SECRET, "probe", -1, now)
        for label, creds in (("wrong secret", wrong), ("expired", expired)):
            with pytest.raises(stun.TransactionFailed, match="401"):
                await allocate(server, *creds)
            assert f"user <{creds[0]}>" in server.log(), label
        # The expiry bounds when an allocation may start, not how long it lasts: coturn
        # keeps refreshing one made in time (a video session outlives its credentials).
        await asyncio.sleep(max(0.0, int(now + 2) + 1.2 - time.time()))
        assert await refresh(good) == 600
        good.close()

    with coturn(SECRET) as server:
        asyncio.run(run(server))


# ------------------------------------------------------------------ end to end
def relay_env(server: Coturn, secret: str = SECRET) -> dict[str, str]:
    return {
        **SMALL,
        "TELEROBOT_ICE_SERVERS": json.dumps([server.url]),
        "TELEROBOT_TURN_SECRET": secret,
        "TELEROBOT_TURN_CREDENTIAL_TTL_S": "300",
        "TELEROBOT_ICE_RELAY_ONLY": "true",
    }


def rtc_configuration(ice: dict[str, Any]) -> RTCConfiguration:
    """What the page does with GET /api/v1/video/ice (web/src/transport/video.ts)."""
    return RTCConfiguration(
        iceServers=[
            RTCIceServer(urls=s["urls"], username=s["username"], credential=s["credential"])
            for s in ice["ice_servers"]
        ],
        iceTransportPolicy=RTCIceTransportPolicy(ice["ice_transport_policy"]),
    )


def candidate_types(sdp: str) -> list[str]:
    return [line.split(" typ ")[1].split()[0] for line in sdp.splitlines() if " typ " in line]


async def watch_through_relay(base: str, frames: int) -> dict[str, Any]:
    async with httpx.AsyncClient(base_url=base, timeout=30) as http:
        asked = time.time()
        r = await http.get("api/v1/video/ice")
        answered = time.time()
        assert r.status_code == 200 and r.headers["cache-control"] == "no-store"
        assert SECRET not in r.text  # the shared secret stays on the server
        ice = r.json()
        pc = RTCPeerConnection(rtc_configuration(ice))
        pc.addTransceiver("video", direction="recvonly")
        tracks: asyncio.Queue[Any] = asyncio.Queue()
        pc.on("track", tracks.put_nowait)
        await pc.setLocalDescription(await pc.createOffer())
        offered = candidate_types(pc.localDescription.sdp)
        r = await http.post(
            "api/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp, "type": "offer"}
        )
        assert r.status_code == 200, r.text
        answer = r.json()
        await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
        track = await asyncio.wait_for(tracks.get(), 20)
        ages = []
        for _ in range(frames):
            frame = await asyncio.wait_for(track.recv(), 20)
            rgb = frame.to_ndarray(format="rgb24")
            code = timecode.read(rgb[:, : rgb.shape[1] // 2])
            assert code is not None
            ages.append(timecode.elapsed(code, time.monotonic()))
        # The pair ICE selected (aiortc has no candidate-pair stats: its ICE connection's).
        ice_transport = pc.getTransceivers()[0].receiver.transport.transport
        pair = ice_transport._connection._nominated[1]
        stats = await pc.getStats()
        received = sum(s.bytesReceived for s in stats.values() if s.type == "transport")
        closed = await http.delete(
            f"api/v1/webrtc/{answer['peer_id']}",
            headers={**TOOL, "X-Peer-Secret": answer["peer_secret"]},
        )
        assert closed.status_code == 200
        await pc.close()
    return {
        "ice": ice,
        "ice_asked_answered": (asked, answered),
        "offered": offered,
        "answered": candidate_types(answer["sdp"]),
        "pair": (pair.local_candidate.type, pair.remote_candidate.type),
        "pair_addresses": (pair.local_addr, pair.remote_addr),
        "ages": sorted(ages),
        "bytes_received": received,
    }


def wait_for_usage(server: Coturn, names: set[str], timeout: float = 60) -> list[dict[str, Any]]:
    """The usage lines of allocations by these names, once each has its "peer" line.
    coturn writes them when an allocation closes: the server's closes once it has seen
    its viewer go, which a machine with a core busy took longer than 15 s to do."""
    deadline = time.monotonic() + timeout
    while True:
        usage = [u for u in server.usage() if str(u["username"]).split(":")[1] in names]
        if {str(u["username"]).split(":")[1] for u in usage if u["side"] == "peer"} >= names:
            return usage
        assert time.monotonic() < deadline, f"no usage from coturn for {names}:\n{server.log()}"
        time.sleep(0.2)


def test_relay_only_video_reaches_an_aiortc_viewer_through_coturn() -> None:
    with coturn(SECRET) as server, serving(relay_env(server)) as base:
        seen = asyncio.run(watch_through_relay(base, frames=40))
        usage = wait_for_usage(server, {"telerobot-server", "telerobot-viewer"})
    ice = seen["ice"]
    assert ice["ice_transport_policy"] == "relay"
    [entry] = ice["ice_servers"]
    assert entry["urls"] == [server.url]
    expiry, name = entry["username"].split(":")
    assert name == "telerobot-viewer" and ice["expires_at"] == int(expiry)
    # Minted for the TTL (300 s) when asked: judged against when it was asked, not now
    # (watching and coturn's usage lines took over 10 s with a core busy).
    asked, answered = seen["ice_asked_answered"]
    assert int(asked + 300) <= int(expiry) <= int(answered + 300)
    # Only relay candidates on either side, so the only pair is relay ↔ relay.
    assert seen["offered"] and set(seen["offered"]) == {"relay"}
    assert seen["answered"] and set(seen["answered"]) == {"relay"}
    assert seen["pair"] == ("relay", "relay"), seen["pair_addresses"]
    assert seen["ages"][len(seen["ages"]) // 2] < 0.5  # capture → decoded, relayed
    # coturn carried the video: the server's relay sent it, the viewer's received it.
    peer = {str(u["username"]).split(":")[1]: u for u in usage if u["side"] == "peer"}
    sent, got = peer["telerobot-server"]["sb"], peer["telerobot-viewer"]["rb"]
    print(
        f"relay ↔ relay {seen['pair_addresses']}; 40 frames, age p50"
        f" {seen['ages'][20] * 1e3:.0f} ms; DTLS transport received {seen['bytes_received']} B;"
        f" coturn: server relay sent {sent} B, viewer relay received {got} B"
    )
    assert seen["bytes_received"] > 50_000
    assert got >= seen["bytes_received"] and sent >= seen["bytes_received"]


def test_a_wrong_shared_secret_gives_no_relay_and_a_message_that_says_so() -> None:
    with coturn(SECRET) as server, serving(relay_env(server, "not-the-coturn-secret-0123")) as base:
        ice = httpx.get(base + "api/v1/video/ice").json()
        [entry] = ice["ice_servers"]

        async def try_page_credentials() -> None:
            with pytest.raises(stun.TransactionFailed, match="401"):
                await allocate(server, entry["username"], entry["credential"])

        asyncio.run(try_page_credentials())
        # The server's own peer gets no relay address either: its offer is refused with
        # what to check, rather than answered with an SDP no viewer could ever reach.
        r = httpx.post(base + "api/v1/webrtc/server-offer", headers=TOOL, timeout=30)
        assert r.status_code == 503, r.text
        assert r.json()["title"] == "turn unavailable" or "TURN" in r.json()["detail"]
        assert "TELEROBOT_TURN_SECRET" in r.json()["detail"]
        assert "user <" in server.log() and ":telerobot-server>" in server.log()
        assert "Unauthorized" in server.log()
        status = httpx.get(base + "api/v1/video").json()
        assert status["stats"]["viewer_count"] == 0  # the refused peer was closed


# ------------------------------------------------------------------ the page, in Chromium
# Every RTCPeerConnection the page makes, kept where the test can ask it for its stats.
RECORD_PEERS = """
window.__peers = [];
const __RTCPeerConnection = window.RTCPeerConnection;
window.RTCPeerConnection = class extends __RTCPeerConnection {
  constructor(config) { super(config); this.__config = config; window.__peers.push(this); }
};
"""

# The selected candidate pair of the newest connected peer, its candidates' types.
SELECTED_PAIR = """async () => {
  const pc = window.__peers.filter((p) => p.connectionState === "connected").pop();
  if (!pc) return null;
  const stats = [...(await pc.getStats()).values()];
  const transport = stats.find((s) => s.type === "transport" && s.selectedCandidatePairId);
  const pair = stats.find((s) => s.id === transport.selectedCandidatePairId);
  const byId = (id) => stats.find((s) => s.id === id);
  return {
    policy: pc.__config.iceTransportPolicy,
    local: byId(pair.localCandidateId).candidateType,
    remote: byId(pair.remoteCandidateId).candidateType,
    bytesReceived: pair.bytesReceived,
  };
}"""


class PeerRecordingBrowser:
    """A browser whose pages record their RTCPeerConnections (for tests.webpage.open_page)."""

    def __init__(self, browser: Any) -> None:
        self.browser = browser

    def new_page(self, **options: Any) -> Any:
        page = self.browser.new_page(**options)
        page.add_init_script(RECORD_PEERS)
        return page


@pytest.mark.browser
def test_the_page_watches_relay_only_video_through_coturn(browser: Browser) -> None:
    from tests.support.browser import ENV, open_page

    with coturn(SECRET) as server, serving({**ENV, **relay_env(server)}) as base:
        page, errors = open_page(PeerRecordingBrowser(browser), base)  # type: ignore[arg-type]
        pair = page.evaluate(SELECTED_PAIR)
        page.close()
        usage = wait_for_usage(server, {"telerobot-server", "telerobot-viewer"})
    assert pair is not None and pair["policy"] == "relay", (pair, errors)
    assert (pair["local"], pair["remote"]) == ("relay", "relay"), pair
    peer = {str(u["username"]).split(":")[1]: u for u in usage if u["side"] == "peer"}
    print(f"Chromium: {pair}; coturn: viewer relay received {peer['telerobot-viewer']['rb']} B")
    assert peer["telerobot-viewer"]["rb"] >= pair["bytesReceived"] > 50_000


# ------------------------------------------------------------------ docker/compose.yaml
def compose_interpolate(text: str, env: dict[str, str]) -> str:
    """Compose's ${VAR}, ${VAR:-default}, ${VAR:?error} and $$ (enough for our file)."""
    import re

    def one(m: re.Match[str]) -> str:
        name, op, arg = m["name"], m["op"], m["arg"]
        if env.get(name):
            return env[name]
        assert op != ":?", f"compose would stop: {arg}"
        return arg if op == ":-" else ""

    out = re.sub(r"(?<!\$)\$\{(?P<name>\w+)(?:(?P<op>:[-?])(?P<arg>[^}]*))?\}", one, text)
    return out.replace("$$", "$")


def test_the_compose_file_runs_coturn_beside_the_server_with_one_secret() -> None:
    """No Docker engine here: the file parses, and what it gives the server is valid."""
    from pathlib import Path

    import yaml  # PyYAML: a dependency of schemathesis (dev)

    from telerobot.server.settings import Settings

    path = Path(__file__).resolve().parents[1] / "docker" / "compose.yaml"
    env = {"TURN_HOST": "robot.example.org", "TURN_SECRET": SECRET, "MEDIA_SERVER_SECRET": SECRET}
    compose = yaml.safe_load(compose_interpolate(path.read_text(), env))
    server, turn_server = compose["services"]["telerobot"], compose["services"]["coturn"]
    assert server["network_mode"] == turn_server["network_mode"] == "host"  # UDP media
    given = {k.removeprefix("TELEROBOT_").lower(): v for k, v in server["environment"].items()}
    settings = Settings.model_validate({**given, "ice_servers": json.loads(given["ice_servers"])})
    assert settings.ice_config.minted_urls == [
        "turn:robot.example.org:3478?transport=udp",
        "turn:robot.example.org:3478?transport=tcp",
    ]
    assert settings.turn_secret == turn_server["environment"]["TURN_SECRET"] == SECRET
    command = turn_server["command"][0]
    for option in ("--use-auth-secret", '--static-auth-secret="$TURN_SECRET"', "--no-cli"):
        assert option in command
    with pytest.raises(AssertionError, match="set TURN_SECRET"):
        compose_interpolate(path.read_text(), {"TURN_HOST": "robot.example.org"})


def test_the_compose_files_media_server_is_the_one_the_server_is_pointed_at() -> None:
    """The janus service runs `telerobot media-server` on the ports and with the secret
    the telerobot service's settings name."""
    from pathlib import Path

    import yaml

    from telerobot.server.cli import main as _  # noqa: F401  (the command exists)
    from telerobot.server.settings import Settings

    path = Path(__file__).resolve().parents[1] / "docker" / "compose.yaml"
    env = {"TURN_HOST": "robot.example.org", "TURN_SECRET": SECRET, "MEDIA_SERVER_SECRET": SECRET}
    services = yaml.safe_load(compose_interpolate(path.read_text(), env))["services"]
    server, janus = services["telerobot"], services["janus"]
    assert janus["network_mode"] == "host" and "janus" in server["depends_on"]
    given = {k.removeprefix("TELEROBOT_").lower(): v for k, v in server["environment"].items()}
    settings = Settings.model_validate({**given, "ice_servers": json.loads(given["ice_servers"])})
    command = janus["command"]
    assert command[:2] == ["telerobot", "media-server"]
    option = dict(zip(command[2::2], command[3::2], strict=True))
    assert settings.media_server == "janus"
    assert settings.media_server_url == f"http://127.0.0.1:{option['--http-port']}/janus"
    assert settings.media_server_rtp_port == int(option["--rtp-port"])
    assert settings.media_server_rtcp_port == int(option["--rtcp-port"])
    assert settings.media_server_data_port == int(option["--data-port"])
    assert settings.media_server_secret == janus["environment"]["TELEROBOT_MEDIA_SERVER_SECRET"]
    with pytest.raises(AssertionError, match="set MEDIA_SERVER_SECRET"):
        compose_interpolate(path.read_text(), {k: v for k, v in env.items() if "MEDIA" not in k})
