"""The HTTP edge against a real server process over real sockets: what an attacker or
a careless client sends is refused before any work is done, with a clear error, and
the e-stop keeps answering."""

from __future__ import annotations

import base64
import logging
import socket
import subprocess
import threading
from collections.abc import Iterator
from urllib.parse import urlsplit

import httpx
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from harness.servers import telerobot_process
from telerobot.protocol import messages as m
from telerobot.server.accesslog import MAX_ADDRESSES, REFUSALS_PER_WINDOW, RefusalLogLimit
from telerobot.server.app import create_app
from telerobot.server.edge import BODY_LIMITS, DEFAULT_BODY_LIMIT
from telerobot.server.realtime.ratelimit import (
    MALFORMED_COST,
    MALFORMED_IN_A_ROW,
    PeerLimits,
    TokenBucket,
)
from telerobot.server.security import redact_query_tokens
from telerobot.server.settings import Settings
from tests.support import TOKEN

AUTH = {"Authorization": f"Bearer {TOKEN}"}
JSON = {"Content-Type": "application/json"}


class Server:
    def __init__(self, proc: subprocess.Popen[str], base: str) -> None:
        self.proc = proc
        self.base = base
        split = urlsplit(base)
        self.host, self.port = split.hostname or "127.0.0.1", split.port or 80
        self.output: list[str] = []

    def raw(self, request: bytes, *, read: bool = True, timeout: float = 10.0) -> bytes:
        """Send ``request`` as it is on a new connection; the server's answer."""
        with socket.create_connection((self.host, self.port), timeout=timeout) as s:
            s.sendall(request)
            if not read:
                return b""
            chunks = []
            while True:
                try:
                    data = s.recv(65536)
                except (ConnectionResetError, TimeoutError):
                    break
                if not data:
                    break
                chunks.append(data)
            return b"".join(chunks)

    def safety(self) -> dict[str, object]:
        r = httpx.get(self.base + "api/v1/safety")
        result: dict[str, object] = r.json()
        return result

    def reset_estop(self) -> None:
        lease = httpx.post(self.base + "api/v1/lease", json={"name": "edge test"}, headers=AUTH)
        h = {**AUTH, "X-Client-Id": lease.json()["client_id"]}
        httpx.post(self.base + "api/v1/safety/reset", headers=h)
        httpx.delete(self.base + "api/v1/lease", headers=h)


@pytest.fixture(scope="module")
def server() -> Iterator[Server]:
    with telerobot_process(
        "serve",
        "--http-port",
        "0",
        wait_for=r"(http://localhost:\d+/)",
        env={"TELEROBOT_OPERATOR_TOKEN": TOKEN},
        drain=False,
    ) as (proc, match):
        s = Server(proc, match.group(1).replace("localhost", "127.0.0.1"))
        assert proc.stdout is not None
        stdout = proc.stdout

        def collect() -> None:
            for line in stdout:
                s.output.append(line)

        threading.Thread(target=collect, daemon=True).start()
        yield s


def status_of(response: bytes) -> int:
    return int(response.split(b" ", 2)[1])


def test_a_50_mb_body_is_refused_before_it_is_read(server: Server) -> None:
    # Only the head and 1 kB of the 50 MB are sent: the answer comes without the rest.
    head = (
        b"POST /api/v1/webrtc/offer HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: application/json\r\nContent-Length: 52428800\r\n\r\n"
    )
    answer = server.raw(head + b'{"sdp": "' + b"v" * 1000)
    assert status_of(answer) == 413
    assert b"body_too_large" in answer and len(answer) < 2000
    assert httpx.post(server.base + "api/v1/safety/estop", json={}).json()["estop"] is True
    server.reset_estop()


def test_a_body_without_a_length_is_cut_at_the_limit(server: Server) -> None:
    limit = DEFAULT_BODY_LIMIT
    chunk = b"x" * 4096
    body = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(limit // 4096 + 2))
    head = (
        b"POST /api/v1/safety/estop HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    )
    answer = server.raw(head + body + b"0\r\n\r\n")
    assert status_of(answer) == 413
    assert server.safety()["estop"] is False  # nothing was done


def test_the_token_is_checked_before_the_body_is_read(server: Server) -> None:
    big = b"x" * (BODY_LIMITS["/api/v1/calibration/fit"] * 4)
    r = httpx.post(server.base + "api/v1/calibration/fit", content=big, headers=JSON)
    assert r.status_code == 403 and "operator token" in r.json()["detail"]


def test_a_validation_error_never_echoes_the_input(server: Server) -> None:
    junk = "A" * 7_000  # two of them: just under the 16 kB limit
    r = httpx.post(
        server.base + "api/v1/robot/move",
        json={"space": junk, "mode": junk},
        headers={**AUTH, "X-Client-Id": "nobody"},
    )
    # The lease check or the validation: either way the body is not sent back.
    assert r.status_code in (403, 422)
    assert junk[:100] not in r.text and len(r.content) < 2000
    lease = httpx.post(server.base + "api/v1/lease", json={"name": "v"}, headers=AUTH).json()
    h = {**AUTH, "X-Client-Id": lease["client_id"]}
    r = httpx.post(server.base + "api/v1/robot/move", json={"space": junk, "mode": 1}, headers=h)
    httpx.delete(server.base + "api/v1/lease", headers=h)
    assert r.status_code == 422 and r.json()["errors"]
    assert junk[:100] not in r.text and len(r.content) < 2000


def test_a_foreign_host_name_is_refused_on_http_and_ws(server: Server) -> None:
    answer = server.raw(
        b"POST /api/v1/safety/estop HTTP/1.1\r\nHost: evil.example\r\n"
        b"Origin: http://evil.example\r\nContent-Type: application/json\r\n"
        b"Content-Length: 2\r\n\r\n{}"
    )
    assert status_of(answer) == 400 and b"host" in answer
    answer = server.raw(
        b"GET /ws HTTP/1.1\r\nHost: evil.example:8000\r\nOrigin: http://evil.example:8000\r\n"
        b"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n"
        b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
    )
    assert status_of(answer) != 101
    assert server.safety()["estop"] is False


def test_a_cross_site_post_cannot_latch_the_estop(server: Server) -> None:
    # What a form or a fetch with no preflight on another site can send.
    r = httpx.post(
        server.base + "api/v1/safety/estop",
        content="{}",
        headers={"Content-Type": "text/plain", "Origin": "http://evil.example"},
    )
    assert r.status_code == 403
    r = httpx.post(
        server.base + "api/v1/safety/estop", content="{}", headers={"Content-Type": "text/plain"}
    )
    assert r.status_code == 415 and "application/json" in r.json()["detail"]
    assert server.safety()["estop"] is False
    # This server's own page, or a script: it latches.
    own = f"http://{server.host}:{server.port}"
    r = httpx.post(server.base + "api/v1/safety/estop", json={}, headers={"Origin": own})
    assert r.status_code == 200 and server.safety()["estop"] is True
    server.reset_estop()
    r = httpx.post(server.base + "api/v1/safety/estop", headers={"X-Telerobot-Client": "curl"})
    assert r.status_code == 200 and server.safety()["estop"] is True
    server.reset_estop()


def test_the_token_never_reaches_the_log(server: Server) -> None:
    r = httpx.get(server.base + f"?token={TOKEN}&view=anaglyph")
    assert r.status_code == 200
    httpx.get(server.base + "api/v1/health")  # a later line: the first one has been written
    for _ in range(50):
        if any("/api/v1/health" in line for line in server.output):
            break
        threading.Event().wait(0.1)
    log = "".join(server.output)
    assert "view=anaglyph" in log  # the request was logged…
    assert TOKEN not in log  # …without the token


def access_lines(server: Server, needle: str, wait_for: str) -> list[str]:
    """The server's access-log lines with ``needle``, once a line with ``wait_for``
    (logged after them) has come."""
    for _ in range(100):
        if any(wait_for in line for line in server.output):
            break
        threading.Event().wait(0.1)
    return [line for line in server.output if needle in line]


def test_a_flood_of_refused_requests_logs_a_bounded_number_of_lines(server: Server) -> None:
    # One address repeats a request refused (404) 60 times: 20 lines, the last saying
    # that more are counted, not logged; answered requests and other addresses are
    # logged as before (on the old server: 60 lines).
    flood = httpx.Client(transport=httpx.HTTPTransport(local_address="127.0.0.3"))
    with flood:
        for _ in range(60):
            assert flood.get(server.base + "api/v1/no-such-thing").status_code == 404
        assert flood.get(server.base + "api/v1/health").status_code == 200
    httpx.get(server.base + "api/v1/no-such-thing-either")  # another address: logged
    lines = access_lines(server, "/api/v1/no-such-thing ", "/api/v1/no-such-thing-either")
    assert len(lines) == REFUSALS_PER_WINDOW, lines
    assert any(
        "refusals from 127.0.0.3" in line and "counted, not logged" in line
        for line in server.output
    )
    assert any("127.0.0.3" in line and "/api/v1/health" in line for line in server.output)


def test_the_refusals_not_logged_are_said_with_the_next_window(
    caplog: pytest.LogCaptureFixture,
) -> None:
    now = [0.0]
    limit = RefusalLogLimit(per_window=2, window_s=10.0, clock=lambda: now[0])

    def refused(address: str = "10.0.0.5:4242", status: int = 429) -> logging.LogRecord:
        args = (address, "GET", "/api/v1/recordings", "1.1", status)
        return logging.LogRecord(
            "uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d', args, None
        )

    kept = [limit.filter(refused()) for _ in range(5)]
    assert kept == [True, True, False, False, False] and limit.held_total == 3
    assert limit.filter(refused(status=200)) and limit.filter(refused(status=500))
    assert limit.filter(refused("10.0.0.6:1"))  # another machine: its own budget
    now[0] = 10.0  # the next window: logged again, saying what was not
    with caplog.at_level(logging.WARNING, logger="telerobot.server.accesslog"):
        assert limit.filter(refused())
    assert "3 more refused requests from 10.0.0.5 were not logged" in caplog.text


def test_the_refusal_windows_are_bounded_in_addresses() -> None:
    # Every address heard from gets a window: at most MAX_ADDRESSES are kept, the one
    # heard from longest ago going first.
    limit = RefusalLogLimit()
    for i in range(MAX_ADDRESSES + 50):
        args = (f"10.{i // 65536}.{i // 256 % 256}.{i % 256}:1", "GET", "/x", "1.1", 404)
        limit.filter(logging.LogRecord("uvicorn.access", logging.INFO, "", 0, "%s", args, None))
    assert len(limit._windows) == MAX_ADDRESSES
    assert "10.0.0.0" not in limit._windows and "10.0.4.49" in limit._windows


def test_redaction_keeps_the_rest_of_the_query() -> None:
    assert redact_query_tokens("/?a=1&token=s3cret&b=2") == "/?a=1&token=[redacted]&b=2"
    assert redact_query_tokens("/ws?TOKEN=x") == "/ws?TOKEN=[redacted]"
    assert redact_query_tokens("/?tokens=1") == "/?tokens=1"


@pytest.fixture(scope="module")
def client() -> Iterator[TestClient]:
    with TestClient(create_app(Settings(operator_token=TOKEN)), base_url="http://localhost") as c:
        yield c


def test_a_get_on_a_post_only_path_is_405_and_unknown_api_paths_404(client: TestClient) -> None:
    assert client.get("/api/v1/safety/estop").status_code == 405
    assert client.get("/api/v1/no-such-thing").status_code == 404
    assert client.get("/").status_code in (200, 404)  # the page, when built


def test_booleans_are_not_numbers(client: TestClient) -> None:
    fit = {"camera": "left", "points": [[True, 0, 0]] * 6, "pixels": [[0, 0]] * 6}
    r = client.post("/api/v1/calibration/fit", json=fit, headers=AUTH)
    assert r.status_code == 422 and "a number is expected" in r.json()["detail"]
    r = client.put("/api/v1/force", json={"rate_hz": True}, headers=AUTH)
    assert r.status_code == 422


def test_ragged_fiducials_and_empty_images_get_422s(client: TestClient) -> None:
    r = client.post(
        "/api/v1/calibration/fit",
        json={"camera": "left", "points": [[0, 0, 0], [1, 0]] * 3, "pixels": [[0, 0]] * 6},
        headers=AUTH,
    )
    assert r.status_code == 422 and "[x, y, z]" in r.json()["detail"]
    r = client.post(
        "/api/v1/calibration/fit",
        json={"camera": "left", "points": [[0, 0, 0]] * 6, "pixels": [[0, 0, 1]] * 6},
        headers=AUTH,
    )
    assert r.status_code == 422 and "[u, v]" in r.json()["detail"]
    for image in ("", base64.b64encode(b"").decode(), base64.b64encode(b"\x00" * 10).decode()):
        r = client.post(
            "/api/v1/calibration/intrinsics/views",
            json={"camera": "left", "images": [image] * 4},
            headers=AUTH,
        )
        assert r.status_code == 422, r.text


def test_a_hello_of_another_protocol_version_is_refused(client: TestClient) -> None:
    with client.websocket_connect("ws://localhost/ws") as ws:
        ws.send_bytes(m.encode(m.HELLO, 999, 0, b""))
        reply = ws.receive_bytes()
        msg, _fields, text = m.decode(reply)
        assert msg is m.ERROR and "version 999" in text
        with pytest.raises(WebSocketDisconnect):
            ws.receive_bytes()


def test_a_client_sending_only_garbage_on_ws_is_closed(client: TestClient) -> None:
    with client.websocket_connect("ws://localhost/ws") as ws:
        ws.send_bytes(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
        for _ in range(MALFORMED_IN_A_ROW):
            ws.send_bytes(b"\xff\x00\x01")
        texts = []
        with pytest.raises(WebSocketDisconnect) as closed:
            while True:
                data = ws.receive_bytes()
                if data[0] == m.ERROR.type_id:
                    texts.append(m.decode(data)[2])
        assert closed.value.code == 1008
        assert any("malformed messages in a row" in t for t in texts)


def test_good_messages_between_bad_ones_keep_a_client_connected(client: TestClient) -> None:
    with client.websocket_connect("ws://localhost/ws") as ws:
        ws.send_bytes(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
        for i in range(3 * MALFORMED_IN_A_ROW):
            ws.send_bytes(b"\xff\x00\x01" if i % 2 else m.encode(m.PING, i, 0.0))
        ws.send_bytes(m.encode(m.PING, 99_999, 0.0))
        while True:
            msg, fields, _ = m.decode(ws.receive_bytes())
            if msg is m.PONG and fields["seq"] == 99_999:
                break


def test_the_token_bucket_makes_a_flood_wait_and_lets_a_burst_through() -> None:
    bucket = TokenBucket(rate=1000.0, burst=10)
    assert all(bucket.take(0.0) == 0.0 for _ in range(10))  # the burst
    assert bucket.take(0.0) == pytest.approx(0.001)  # the 11th waits a token's time
    assert bucket.throttled == 1
    assert bucket.take(1.0) == 0.0  # a second later it is full again
    flood = [bucket.take(2.0) for _ in range(1000)]
    assert flood[-1] == pytest.approx((1000 - 10) / 1000.0, rel=0.01)  # 1000 msg/s at most


def test_numbers_enums_and_tuples_are_read_as_json_gives_them() -> None:
    from telerobot.server.api.robot import MoveRequest

    move = MoveRequest.model_validate(
        {"space": "cartesian", "mode": "incremental", "position": [1, 0, 0.5], "frame": "tool"}
    )
    assert move.position == [1.0, 0.0, 0.5] and move.frame is not None
    with pytest.raises(ValueError, match="a number is expected"):
        MoveRequest.model_validate(
            {"space": "cartesian", "mode": "incremental", "position": [True, 0, 0]}
        )
    assert MoveRequest.model_validate({"space": "joint", "mode": "absolute", "wait": False})


def test_every_error_class_says_its_http_status_and_code_once() -> None:
    from telerobot.drivers.base import (
        DeviceError,
        InvalidCommand,
        JointLimitError,
        NotReady,
        TelerobotError,
    )
    from telerobot.server.control.errors import NotAllowed, StillMoving
    from telerobot.server.errors import http_status
    from telerobot.server.media.pipeline import NotYourPeer, ViewerLimitReached
    from telerobot.server.media.supervisor import MediaRequestFailed

    assert (http_status(NotAllowed("x")), http_status(StillMoving("x"))) == (403, 504)
    assert http_status(ViewerLimitReached("x")) == 503  # a MediaUnavailable
    # The drivers' errors get theirs from the server (drivers know no HTTP), heirs too.
    assert [http_status(e("x")) for e in (InvalidCommand, JointLimitError, NotReady)] == [
        422,
        422,
        409,
    ]
    assert (http_status(DeviceError("x")), http_status(TelerobotError("x"))) == (503, 500)
    assert TelerobotError.with_code("not_your_peer") is NotYourPeer
    assert TelerobotError.with_code("viewer_limit") is ViewerLimitReached
    assert TelerobotError.with_code("invalid_command") is InvalidCommand
    assert TelerobotError.with_code("no such code") is None
    assert TelerobotError.with_code("telerobot_error") is TelerobotError  # not its heirs
    assert http_status(MediaRequestFailed("media_error", "x")) == 502
    for code in ("malformed", "not_allowed", "safety_stop", "limit_exceeded"):
        assert code in m.ERROR_CODES  # the wire's numbers for the classes' codes


def test_an_address_shares_one_budget_and_reconnecting_in_a_loop_is_refused() -> None:
    limits = PeerLimits(connections_per_s=10.0, connection_burst=5, max_peers=3)
    first = limits.connect("10.0.0.1", 0.0)
    assert first is not None
    assert limits.connect("10.0.0.1", 0.0) is first  # a new connection: the same budget
    for _ in range(3):
        assert limits.connect("10.0.0.1", 0.0) is not None
    assert limits.connect("10.0.0.1", 0.0) is None  # the 6th at once
    assert limits.refused_connections == 1
    assert limits.connect("10.0.0.1", 0.1) is not None  # a token back after 0.1 s
    for host in ("a", "b", "c"):  # the table keeps the 3 heard from last
        limits.connect(host, 1.0)
    assert limits.connect("10.0.0.1", 1.0) is not first  # forgotten: a fresh budget


def test_the_operator_is_not_slowed_by_a_flood_from_its_own_address(client: TestClient) -> None:
    """An address's budget is shared by its tokenless connections, but the token's holder
    has one of its own: a flood from the same address (a NAT, the same machine) leaves
    the address in debt, and the operator's commands must not wait behind it."""
    services = client.app.state.services  # type: ignore[attr-defined]
    with client.websocket_connect("ws://localhost/ws") as flooder:
        flooder.send_bytes(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
        assert m.decode(flooder.receive_bytes())[0] is m.WELCOME
        # The address's budget, deep in debt (a flood of 1000 s, at its rate).
        address = services.ws_limits.connect("testclient", services.hub.clock.now())
        address.tokens = -1000.0 * address.rate
        with client.websocket_connect("ws://localhost/ws") as operator:
            operator.send_bytes(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, TOKEN.encode()))
            for seq in range(1, 4):  # each PING is read at once: PONGs come back
                operator.send_bytes(m.encode(m.PING, seq, 0.0))
                while True:
                    msg, fields, _ = m.decode(operator.receive_bytes())
                    if msg is m.PONG:
                        assert fields["seq"] == seq
                        break
        assert address.tokens < 0  # the flood's debt is still the address's


def test_garbage_costs_more_of_the_budget_than_commands() -> None:
    bucket = TokenBucket(rate=1000.0, burst=100)
    for _ in range(10):
        bucket.take(0.0, MALFORMED_COST)
    assert bucket.take(0.0) == pytest.approx(0.001)  # 10 malformed emptied a 100 burst


def test_a_ws_message_over_64_kib_closes_the_connection(server: Server) -> None:
    import websockets.sync.client as ws_client
    from websockets.exceptions import ConnectionClosed

    from telerobot.server.cli import WS_MAX_MESSAGE

    url = f"ws://{server.host}:{server.port}/ws"
    with ws_client.connect(url, open_timeout=5) as ws:
        ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
        ws.send(b"\x06" * (WS_MAX_MESSAGE + 1))
        with pytest.raises(ConnectionClosed) as closed:
            while True:
                ws.recv(timeout=5)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009  # too big
    assert httpx.get(server.base + "api/v1/health").status_code == 200


def test_a_fit_takes_at_most_100_fiducials(client: TestClient) -> None:
    from telerobot.server.api.calibration import MAX_FIDUCIALS

    n = MAX_FIDUCIALS + 1
    fit = {"camera": "left", "points": [[0, 0, 0]] * n, "pixels": [[0, 0]] * n}
    r = client.post("/api/v1/calibration/fit", json=fit, headers=AUTH)
    assert r.status_code == 422 and "points" in r.json()["detail"]
