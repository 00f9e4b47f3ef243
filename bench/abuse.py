"""The server under attack: what one client without a token can do to everyone else.

Starts ``telerobot serve`` (simulation, no video, 1024 file descriptors as on a
default Linux login) and, for each attack, runs the attacker in a process of its own
while an observer (another process) receives every force sample and the 50 Hz state
over ``/ws``, and the bench presses the e-stop over REST every 0.3 s:

- ``big_body``: 50 MB JSON bodies to ``POST /api/v1/webrtc/offer``, back to back;
- ``priority_flood``: 4 unauthenticated connections to the priority channel sending
  3-byte frames as fast as they can;
- ``ws_flood``: malformed frames on ``/ws`` as fast as they can;
- ``fd_exhaustion``: connections to the priority channel until the server has no file
  descriptor left, held, then dropped; then health, ``/ws`` and the channel must answer.

Each is measured against a quiet period of the same length in the same run.

    python -m bench.abuse [--json] [--seconds 6]

Figures (issue 11's goals): ``stall_ms`` (the event loop's longest stall while a
50 MB body arrives: the longest state gap at the observer beyond its 20 ms period;
≤ 50), ``estop_ms_under_attack`` (worst e-stop round trip per attack; ≤ 20),
``force_p99_under_flood_ms`` (force inter-arrival p99 at the observer during the
priority-channel flood; ≤ 5), ``rss_growth_mb`` (server RSS after each attack vs
before; ≤ 20), ``recovers_after_fd_exhaustion`` (true).
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import resource
import socket
import statistics
import struct
import time
from typing import Any

import httpx
import numpy as np
import psutil

from backend.realtime import messages as m
from bench.common import emit, machine, parser, serve_for_bench

SERVER_FDS = 1024
STATE_PERIOD_MS = 20.0  # the server's default state rate (50 Hz)


# ---------------------------------------------------------------- attackers (own process)
def _raise_fd_limit() -> None:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


def attack_big_body(host: str, port: int, seconds: float) -> None:
    size = 50 * 1024 * 1024
    body = b'{"sdp": "' + b"v" * (size - 30) + b'", "type": "offer"}'
    head = (
        f"POST /api/v1/webrtc/offer HTTP/1.1\r\nHost: {host}\r\n"
        f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n"
    ).encode()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with contextlib.suppress(OSError), socket.create_connection((host, port), 5) as s:
            s.sendall(head + body)
            s.recv(4096)


def attack_priority_flood(host: str, port: int, seconds: float) -> None:
    frames = struct.pack("<H", 1) + b"\x07"  # a 3-byte frame, again and again
    burst = frames * 20_000
    end = time.monotonic() + seconds
    socks: list[socket.socket | None] = [None] * 4
    while time.monotonic() < end:
        for i, s in enumerate(socks):
            try:
                if s is None:
                    s = socks[i] = socket.create_connection((host, port), 2)
                    s.setblocking(False)
                s.send(burst)
            except BlockingIOError:
                pass
            except OSError:
                if s is not None:
                    s.close()
                socks[i] = None
        time.sleep(0.0005)
    for s in socks:
        if s is not None:
            s.close()


def attack_ws_flood(host: str, port: int, seconds: float) -> None:
    import websockets.sync.client as ws_client

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            with ws_client.connect(f"ws://{host}:{port}/ws", open_timeout=5) as ws:
                ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
                while time.monotonic() < end:
                    ws.send(b"\xff\x00\x01")
        except Exception:
            time.sleep(0.05)


def attack_fd_exhaustion(host: str, port: int, seconds: float) -> None:
    _raise_fd_limit()
    held: list[socket.socket] = []
    end = time.monotonic() + seconds
    with contextlib.suppress(OSError):
        while len(held) < 3 * SERVER_FDS and time.monotonic() < end:
            held.append(socket.create_connection((host, port), 1))
    while time.monotonic() < end:
        time.sleep(0.05)
    for s in held:
        s.close()


ATTACKS = {
    "big_body": attack_big_body,
    "priority_flood": attack_priority_flood,
    "ws_flood": attack_ws_flood,
    "fd_exhaustion": attack_fd_exhaustion,
}


def _attacker(name: str, host: str, http_port: int, priority_port: int, seconds: float) -> None:
    port = priority_port if name in ("priority_flood", "fd_exhaustion") else http_port
    ATTACKS[name](host, port, seconds)


# ---------------------------------------------------------------- observer (own process)
def _observer(host: str, port: int, seconds: float, out: Any) -> None:
    out.put(asyncio.run(_observe(host, port, seconds)))


async def _observe(host: str, port: int, seconds: float) -> dict[str, Any]:
    import websockets

    forces: list[float] = []
    states: list[float] = []
    async with websockets.connect(f"ws://{host}:{port}/ws", max_size=None) as ws:
        await ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, m.HelloFlags.EVERY_FORCE_SAMPLE, b""))
        end = time.monotonic() + seconds
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(seconds + 5):
                while time.monotonic() < end:
                    data = await ws.recv()
                    now = time.monotonic()
                    if data[0] == m.FORCE.type_id:
                        forces.extend(now for _ in m.decode_force(data))
                    elif data[0] == m.STATE.type_id:
                        states.append(now)
    return {"forces": forces, "states": states}


def gaps_ms(times: list[float]) -> np.ndarray:
    return np.diff(np.array(times)) * 1000.0 if len(times) > 1 else np.array([float("inf")])


# ---------------------------------------------------------------- the bench
def press_estop(http: httpx.Client, base: str) -> float:
    t0 = time.perf_counter()
    r = http.post(base + "api/v1/safety/estop", json={}, timeout=120)
    elapsed = (time.perf_counter() - t0) * 1000.0
    r.raise_for_status()
    return elapsed


def reset_estop(http: httpx.Client, base: str, token: str) -> None:
    auth = {"Authorization": f"Bearer {token}"}
    lease = http.post(base + "api/v1/lease", json={"name": "bench"}, headers=auth, timeout=60)
    h = {**auth, "X-Client-Id": lease.json()["client_id"]}
    http.post(base + "api/v1/safety/reset", headers=h, timeout=60)
    http.delete(base + "api/v1/lease", headers=h, timeout=60)


def period(
    name: str | None,
    host: str,
    http_port: int,
    priority_port: int,
    seconds: float,
    base: str,
    token: str,
    server: psutil.Process,
) -> dict[str, Any]:
    ctx = multiprocessing.get_context("spawn")
    out: Any = ctx.Queue()
    rss_before = server.memory_info().rss
    observer = ctx.Process(target=_observer, args=(host, http_port, seconds, out))
    observer.start()
    time.sleep(1.0)  # the observer is connected and receiving
    attacker = None
    if name is not None:
        attacker = ctx.Process(
            target=_attacker, args=(name, host, http_port, priority_port, seconds - 1.5)
        )
        attacker.start()
    estops: list[float] = []
    with httpx.Client() as http:
        t_end = time.monotonic() + seconds - 2.0
        while time.monotonic() < t_end:
            time.sleep(0.3)
            estops.append(press_estop(http, base))
            reset_estop(http, base, token)
    if attacker is not None:
        attacker.join(seconds + 60)
    seen = out.get(timeout=seconds + 60)
    observer.join(10)
    time.sleep(1.0)  # what the attack left behind, after it has gone
    rss_after = server.memory_info().rss
    f, s = gaps_ms(seen["forces"]), gaps_ms(seen["states"])
    return {
        "estop_ms_p50": statistics.median(estops) if estops else None,
        "estop_ms_max": max(estops) if estops else None,
        "estops": len(estops),
        "force_p99_ms": float(np.percentile(f, 99)),
        "force_max_ms": float(f.max()),
        "forces_received": len(seen["forces"]),
        "state_gap_max_ms": float(s.max()),
        "rss_growth_mb": (rss_after - rss_before) / 1e6,
    }


def recovers(base: str, host: str, http_port: int, priority_port: int, token: str) -> bool:
    """Health, a /ws HELLO and a priority-channel HELLO all answered within 10 s."""
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            ok = httpx.get(base + "api/v1/health", timeout=2).status_code == 200
            ok = ok and asyncio.run(_ws_welcomed(host, http_port))
            ok = ok and _priority_welcomed(host, priority_port, token)
            if ok:
                return True
        except (httpx.HTTPError, OSError, TimeoutError):
            pass
        time.sleep(0.5)
    return False


async def _ws_welcomed(host: str, port: int) -> bool:
    import websockets

    async with websockets.connect(f"ws://{host}:{port}/ws", open_timeout=3) as ws:
        await ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
        async with asyncio.timeout(3):
            while True:
                data = await ws.recv()
                if data[0] == m.WELCOME.type_id:
                    return True


def _priority_welcomed(host: str, port: int, token: str) -> bool:
    hello = m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, token.encode())
    with socket.create_connection((host, port), 3) as s:
        s.settimeout(3)
        s.sendall(struct.pack("<H", len(hello)) + hello)
        data = b""
        while len(data) < 3:
            chunk = s.recv(4096)
            if not chunk:
                return False
            data += chunk
        return data[2] == m.WELCOME.type_id


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=6.0, help="length of each period")
    args = p.parse_args()
    token = "abuse-bench-token-0123456789abcdef"
    with serve_for_bench(
        env={"TELEROBOT_OPERATOR_TOKEN": token, "TELEROBOT_VIDEO": "false"},
        prefix=("prlimit", f"--nofile={SERVER_FDS}:{SERVER_FDS}"),
    ) as (proc, base):
        server = psutil.Process(proc.pid)
        http_port = int(base.rstrip("/").rsplit(":", 1)[1])
        host = "127.0.0.1"
        priority_port = httpx.get(base + "api/v1/force/channel").json()["port"]
        time.sleep(2.0)  # the arm initialises
        results: dict[str, dict[str, Any]] = {}
        results["quiet"] = period(
            None, host, http_port, priority_port, args.seconds, base, token, server
        )
        recovered = None
        for name in ATTACKS:
            results[name] = period(
                name, host, http_port, priority_port, args.seconds, base, token, server
            )
            if name == "fd_exhaustion":
                recovered = recovers(base, host, http_port, priority_port, token)
        quiet = results["quiet"]
        figures: dict[str, Any] = {
            "stall_ms": max(0.0, results["big_body"]["state_gap_max_ms"] - STATE_PERIOD_MS),
            "stall_ms_quiet": max(0.0, quiet["state_gap_max_ms"] - STATE_PERIOD_MS),
            "estop_ms_under_attack": {
                k: v["estop_ms_max"] for k, v in results.items() if k != "quiet"
            },
            "estop_ms_under_attack_worst": max(
                v["estop_ms_max"] or 0.0 for k, v in results.items() if k != "quiet"
            ),
            "estop_ms_quiet_max": quiet["estop_ms_max"],
            "estop_ms_quiet_p50": quiet["estop_ms_p50"],
            "force_p99_under_flood_ms": results["priority_flood"]["force_p99_ms"],
            "force_p99_quiet_ms": quiet["force_p99_ms"],
            "force_p99_ratio_flood_vs_quiet": results["priority_flood"]["force_p99_ms"]
            / quiet["force_p99_ms"],
            "rss_growth_mb": {k: v["rss_growth_mb"] for k, v in results.items()},
            "rss_growth_mb_worst": max(
                v["rss_growth_mb"] for k, v in results.items() if k != "quiet"
            ),
            "recovers_after_fd_exhaustion": recovered,
            "periods": results,
            "seconds_per_period": args.seconds,
            "server_fd_limit": SERVER_FDS,
            "machine": machine(),
            "load_average": list(psutil.getloadavg()),
        }
    emit(figures, args.json)


if __name__ == "__main__":
    main()
