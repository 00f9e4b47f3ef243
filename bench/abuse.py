"""The server under attack: what one client without a token can do to everyone else.

Starts ``telerobot serve`` (simulation, no video, 1024 file descriptors as on a
default Linux login) and, for each attack, runs the attacker in a process of its own
while an observer (another process) receives every force sample and the 50 Hz state
over ``/ws``, an operator (another process, the token, the control lease) sends a
cartesian increment every 10 ms over ``/ws`` on the server's clock (HELLO's
SYNCED_CLOCK, as the page does), and the bench presses the e-stop over REST every
0.3 s (and resets it as the operator). Each attack is measured against a quiet period
of the same length in the same run; before each attack the bench waits (at most 30 s)
until the server works no harder than in the quiet period, so a read the previous
attacker left running in the server does not count against the next attack.

The attacks on requests and connections:

- ``big_body``: 50 MB JSON bodies to ``POST /api/v1/webrtc/offer``, back to back;
- ``priority_flood``: 4 unauthenticated connections to the priority channel sending
  3-byte frames as fast as they can;
- ``ws_flood``: malformed frames on ``/ws`` as fast as they can;
- ``fd_exhaustion``: connections to the priority channel until the server has no file
  descriptor left, held, then dropped; then health, ``/ws`` and the channel must answer.

The attacks on what came after: recordings, tasks, the relay and resumed sessions (the
attackers connect from 127.0.0.3, or from 127.0.1.x where said, so a per-address budget
is the attacker's alone: the operator, observer and e-stop come from 127.0.0.1):

- ``recordings_listing``: 4 tokenless loops on ``GET /api/v1/recordings`` with 220
  recordings in the server's folder (made before it starts): the listing's 200 newest
  include one with 10,000 episodes of 2,000-character labels (the most the recorder
  lets an operator make) and three with 10,000-character labels (a crafted file);
- ``timeline_reads``: 6 tokenless loops on ``GET /api/v1/recordings/{id}/timeline``
  of a 60 s recording (50 Hz state, 1 kHz force, 20 fps video);
- ``task_preview``: 4 tokenless loops on ``POST /api/v1/tasks/preview`` of that
  recording;
- ``forged_datagrams``: 4 tokenless priority-channel clients register keys for forces
  as UDP datagrams (DATAGRAMS on TCP), then DATAGRAMS packets with those keys come from
  another address, 127.0.0.2 (a socket bound there: on loopback as good as a forged
  source), once a second: whatever the server sends there lands on the victim;
- ``relay_offers``: six tokenless workers ``POST /api/v1/webrtc/server-offer`` in loops
  (never answering), while a legitimate observer (127.0.0.1) asks for an offer every
  0.25 s and closes each it gets. Needs a relay: this attack runs on a second server
  with video and a Janus media server (``--media-server janus``; its own quiet period
  is ``relay_quiet``); without Debian's ``janus`` it runs against the main server
  (video off) and only says what the route answers;
- ``resume_pileup``: one tokenless observer asks for a resume key (RESUMABLE) and
  resumes its session 700 times on new ``/ws`` connections, each with the newest key
  the server gave it, holding every connection open. The connections come from
  127.0.1.1, .2, … 40 each (below ``/ws``'s per-address connection burst, which is not
  what this attack probes: closing superseded connections and single-use keys are).
  The server's open sockets (psutil) are counted before, at the peak and after.

    python -m bench.abuse [--json] [--seconds 6] [--attacks a,b,c] [--attacker-nice 10]
                          [--client-priority 5]

The attackers run on the server's own 2 cores; ``--attacker-nice`` lowers their
priority, as attackers on other machines would not take the server's CPU. The
legitimate clients (the operator, the observer, the e-stop presser) stand for other
machines too: they run ``--client-priority`` nice steps above the bench (default 5, as
the server raises itself; needs root, else they run as started), the attackers at the
bench's own priority.

Figures, with their goals: ``stall_ms`` (the event loop's longest
stall while a 50 MB body arrives: the longest state gap at the observer beyond its
20 ms period; ≤ 50), ``estop_ms_under_attack_worst`` (worst e-stop round trip of any
attack; ≤ 20), ``operator_stale_dropped_worst`` (the operator's commands the server
refused as stale, "stale command: …" in its ERROR, both kinds: older than the
command-age limit, or waited on the way longer than the dead-man; worst attack;
= 0), ``force_p99_under_flood_ms`` (force inter-arrival p99 at the observer during
the priority-channel flood; ≤ 5), ``rss_growth_mb_worst`` (server RSS 1 s after each
attack vs before it; ≤ 20), ``amplification`` (bytes the server sent to the victim's
address ÷ bytes the datagram attacker sent, TCP and UDP payloads; ≤ 1),
``recovers_after_fd_exhaustion`` (true), ``relay_observer_served_share`` (the
legitimate observer's offers answered; ≥ 0.9) and ``resume_sockets_held`` (the
server's sockets at the pile-up's peak beyond before it; ≤ 16). Per attack,
``periods`` has the e-stop, force, state, RSS and socket figures, the operator's
(``operator``: sent, acknowledged, stale, refused while the e-stop was latched,
acknowledgement round trip), the server's CPU (share of a core) and what the attacker
saw (``attack``: statuses, bytes, request times; the victim's bytes; the resumes).
``goals`` says which goals hold; null where the attack was not run (``--attacks``).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import multiprocessing
import os
import queue
import resource
import selectors
import shutil
import socket
import statistics
import struct
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import psutil

from bench import nack_flood
from bench.common import emit, machine, parser
from harness.servers import serve_for_bench
from telerobot.protocol import messages as m
from telerobot.tuning import raise_thread_priority, thread_priority_raised

SERVER_FDS = 1024
STATE_PERIOD_MS = 20.0  # the server's default state rate (50 Hz)
OPERATOR_PERIOD_S = 0.01  # the operator's commands: 100 Hz, as the page's joystick
OPERATOR_STEP_M = 1e-4  # 0.1 mm a command (10 mm/s), back and forth: the arm stays put
ATTACKER_HOST = "127.0.0.3"  # the attackers' own address: a per-address budget is theirs alone
VICTIM_HOST = "127.0.0.2"  # where the forged datagrams say they come from
RECORDINGS = 220  # in the listing's folder (it shows the newest 200)
LONG_RECORDING_S = 60.0  # the timeline's and the preview's recording
DATAGRAM_CLIENTS = 4
FORGE_EVERY_S = 1.0  # the server keeps sending for 2 s after a DATAGRAMS packet
RELAY_WORKERS = 6
RELAY_TRY_EVERY_S = 0.25  # the legitimate observer
RESUMES = 700
RESUMES_PER_ADDRESS = 40  # /ws lets one address open 50 at once, then 10 a second
CLIENT_PRIORITY = 5  # nice steps, as the server's default cpu_priority
TOKEN = "abuse-bench-token-0123456789abcdef"
CLIENT = {"X-Telerobot-Client": "bench.abuse"}  # a request that changes something says who


@dataclass(frozen=True)
class Target:
    """Where the attacks go (handed to the attacker's process)."""

    host: str
    http_port: int
    priority_port: int
    recording: str = ""  # the long recording's file name
    attacker_nice: int = 0  # --attacker-nice
    client_priority: int = 0  # --client-priority

    @property
    def base(self) -> str:
        return f"http://{self.host}:{self.http_port}/"


def as_remote_client(steps: int) -> int:
    """Raise the calling thread's CPU priority by ``steps``, if allowed; its niceness now.

    Why: the operator, the observer and whoever presses the e-stop stand for people on
    other machines. Here they share the server's 2 cores with the attackers, and at the
    attackers' priority the scheduler made them wait tens of ms for a slice: an e-stop's
    worst case said more about the bench's own client than about the server. At the
    server's raised priority (its ``cpu_priority``) they wait no longer than it does."""
    return raise_thread_priority(steps)


# ---------------------------------------------------------------- attackers (own process)
def _raise_fd_limit() -> None:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


def attack_big_body(t: Target, seconds: float) -> None:
    host, port = t.host, t.http_port
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


def attack_priority_flood(t: Target, seconds: float) -> None:
    host, port = t.host, t.priority_port
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


def attack_ws_flood(t: Target, seconds: float) -> None:
    import websockets.sync.client as ws_client

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            with ws_client.connect(f"ws://{t.host}:{t.http_port}/ws", open_timeout=5) as ws:
                ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
                while time.monotonic() < end:
                    ws.send(b"\xff\x00\x01")
        except Exception:
            time.sleep(0.05)


def attack_fd_exhaustion(t: Target, seconds: float) -> None:
    _raise_fd_limit()
    held: list[socket.socket] = []
    end = time.monotonic() + seconds
    with contextlib.suppress(OSError):
        while len(held) < 3 * SERVER_FDS and time.monotonic() < end:
            held.append(socket.create_connection((t.host, t.priority_port), 1))
    while time.monotonic() < end:
        time.sleep(0.05)
    for s in held:
        s.close()


def http_loops(
    url: str,
    seconds: float,
    workers: int,
    *,
    method: str = "GET",
    body: Any = None,
    source: str = ATTACKER_HOST,
) -> dict[str, Any]:
    """``workers`` threads, each with its own connection from ``source``, repeating one
    request as fast as the server answers until ``seconds`` have passed. What came back:
    the statuses, the bytes, how long each took. A request still running at the end is
    left to the process's exit (its connection closes; the server may finish it)."""
    end = time.monotonic() + seconds
    lock = threading.Lock()
    statuses: Counter[str] = Counter()
    took: list[float] = []
    sizes: list[int] = []
    details: list[str] = []
    started = [0]

    def loop() -> None:
        transport = httpx.HTTPTransport(local_address=source)
        with httpx.Client(transport=transport, timeout=seconds + 30) as http:
            while time.monotonic() < end:
                t0 = time.perf_counter()
                with lock:
                    started[0] += 1
                try:
                    r = http.request(method, url, json=body)
                    status, size = str(r.status_code), len(r.content)
                    detail = r.text[:200] if r.status_code >= 400 else ""
                except httpx.HTTPError as exc:
                    status, size, detail = type(exc).__name__, 0, str(exc)[:200]
                with lock:
                    statuses[status] += 1
                    took.append(time.perf_counter() - t0)
                    sizes.append(size)
                    if detail and len(details) < 3 and detail not in details:
                        details.append(detail)

    threads = [threading.Thread(target=loop, daemon=True) for _ in range(workers)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(max(0.0, end - time.monotonic()) + 2.0)
    with lock:
        return {
            "workers": workers,
            "requests": len(took),
            "requests_unfinished": started[0] - len(took),
            "statuses": dict(statuses),
            "bytes_received": sum(sizes),
            "response_bytes_max": max(sizes, default=0),
            "request_ms_p50": statistics.median(took) * 1000.0 if took else None,
            "request_ms_max": max(took) * 1000.0 if took else None,
            "refusals": details,
        }


def attack_recordings_listing(t: Target, seconds: float) -> dict[str, Any]:
    return http_loops(t.base + "api/v1/recordings", seconds, 4)


def attack_timeline_reads(t: Target, seconds: float) -> dict[str, Any]:
    return http_loops(t.base + f"api/v1/recordings/{t.recording}/timeline", seconds, 6)


def attack_task_preview(t: Target, seconds: float) -> dict[str, Any]:
    url = t.base + "api/v1/tasks/preview"
    return http_loops(url, seconds, 4, method="POST", body={"recording": t.recording})


def attack_relay_offers(t: Target, seconds: float) -> dict[str, Any]:
    url = t.base + "api/v1/webrtc/server-offer"
    return http_loops(url, seconds, RELAY_WORKERS, method="POST", body={})


class FrameReader:
    """Length-framed messages off a priority-channel socket (blocking, with a deadline)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.rx = bytearray()

    def until(self, wanted: set[int], timeout: float = 5.0) -> bytes:
        """The first message of a type in ``wanted`` (an ERROR is returned too)."""
        deadline = time.monotonic() + timeout
        while True:
            while len(self.rx) >= m.LENGTH.size:
                (size,) = m.LENGTH.unpack_from(self.rx)
                if len(self.rx) < m.LENGTH.size + size:
                    break
                message = bytes(self.rx[m.LENGTH.size : m.LENGTH.size + size])
                del self.rx[: m.LENGTH.size + size]
                if message[0] in wanted or message[0] == m.ERROR.type_id:
                    return message
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no message of types {sorted(wanted)} within {timeout} s")
            self.sock.settimeout(left)
            data = self.sock.recv(65536)
            if not data:
                raise ConnectionError("the server closed the connection")
            self.rx += data


def attack_forged_datagrams(t: Target, seconds: float) -> dict[str, Any]:
    """Register keys on TCP from ATTACKER_HOST, then name them from VICTIM_HOST."""
    end = time.monotonic() + seconds
    victim = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    victim.bind((VICTIM_HOST, 0))
    victim.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    victim.setblocking(False)
    tcp_sent = udp_sent = victim_bytes = victim_packets = forged = 0
    registered: list[bytes] = []
    refusals: list[str] = []
    socks: list[socket.socket] = []
    for _ in range(DATAGRAM_CLIENTS):
        try:
            s = socket.create_connection(
                (t.host, t.priority_port), 5, source_address=(ATTACKER_HOST, 0)
            )
            socks.append(s)
            reader = FrameReader(s)
            hello = m.frame(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
            s.sendall(hello)
            tcp_sent += len(hello)
            welcome = reader.until({m.WELCOME.type_id})
            if welcome[0] != m.WELCOME.type_id:
                refusals.append(f"HELLO: {m.decode(welcome)[2]}")
                continue
            key = os.urandom(16)
            register = m.frame(m.encode(m.DATAGRAMS, 1, key, 1))
            s.sendall(register)
            tcp_sent += len(register)
            reply = reader.until({m.ACK.type_id})
            if reply[0] == m.ACK.type_id:
                registered.append(key)
            else:
                refusals.append(f"DATAGRAMS: {m.decode(reply)[2]}")
        except (OSError, TimeoutError) as exc:
            refusals.append(f"{type(exc).__name__}: {exc}")
    for s in socks:
        s.setblocking(False)
    first_at: float | None = None
    started = time.monotonic()
    next_forge = started
    sel = selectors.DefaultSelector()
    sel.register(victim, selectors.EVENT_READ)
    for s in socks:
        sel.register(s, selectors.EVENT_READ)
    while time.monotonic() < end:
        now = time.monotonic()
        if now >= next_forge:
            for key in registered:
                packet = m.encode(m.DATAGRAMS, 0, key, 1)
                with contextlib.suppress(OSError):
                    udp_sent += victim.sendto(packet, (t.host, t.priority_port))
                    forged += 1
            next_forge += FORGE_EVERY_S
        for sel_key, _ in sel.select(max(0.0, min(next_forge, end) - time.monotonic())):
            sock = sel_key.fileobj
            assert isinstance(sock, socket.socket)
            for _ in range(256):
                try:
                    data = sock.recv(65536)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    data = b""
                if sock is victim:
                    victim_bytes += len(data)
                    victim_packets += 1
                    first_at = first_at or time.monotonic()
                elif not data:
                    sel.unregister(sock)  # closed by the server
                    break
    sel.close()
    for s in socks:
        s.close()
    victim.close()
    sent = tcp_sent + udp_sent
    return {
        "clients": DATAGRAM_CLIENTS,
        "keys_registered": len(registered),
        "forged_packets": forged,
        "attacker_bytes_tcp": tcp_sent,
        "attacker_bytes_udp": udp_sent,
        "victim_bytes": victim_bytes,
        "victim_packets": victim_packets,
        "victim_packets_per_s": victim_packets / max(time.monotonic() - started, 1e-9),
        "first_datagram_after_s": None if first_at is None else first_at - started,
        "amplification": victim_bytes / sent if sent else None,
        "refusals": refusals[:3],
    }


def resume_sources() -> Iterator[str]:
    """127.0.1.1 RESUMES_PER_ADDRESS times, then 127.0.1.2, …, 127.0.1.250, 127.0.2.1, …"""
    n = 0
    while True:
        for _ in range(RESUMES_PER_ADDRESS):
            yield f"127.0.{1 + n // 250}.{1 + n % 250}"
        n += 1


def attack_resume_pileup(t: Target, seconds: float) -> dict[str, Any]:
    _raise_fd_limit()
    return asyncio.run(_resume_pileup(t, seconds))


async def _resume_pileup(t: Target, seconds: float) -> dict[str, Any]:
    import websockets
    from websockets.protocol import State

    from harness.wsclient import RealtimeClient

    end = time.monotonic() + seconds
    url = f"ws://{t.host}:{t.http_port}/ws"
    sources = resume_sources()
    held: list[Any] = []
    refusals: Counter[str] = Counter()

    async def open_from(source: str) -> Any:
        ws = await websockets.connect(
            url, max_size=None, compression=None, open_timeout=5, local_addr=(source, 0)
        )
        held.append(ws)
        return ws

    first = await RealtimeClient.hello(await open_from(next(sources)), "", m.HelloFlags.RESUMABLE)
    keys = [first.resume_key]
    resumed = 0
    reused_key_accepted = None  # the first key again, once the server gave another
    while resumed + sum(refusals.values()) < RESUMES and time.monotonic() < end:
        try:
            client = await RealtimeClient.resume(await open_from(next(sources)), keys[-1])
        except Exception as exc:  # refused: an ERROR, a close, a timeout
            refusals[f"{type(exc).__name__}: {str(exc)[:120]}"] += 1
            continue
        resumed += 1
        if client.resume_key and client.resume_key != keys[-1]:
            keys.append(client.resume_key)
        if len(keys) == 2 and reused_key_accepted is None:
            try:
                again = await RealtimeClient.resume(await open_from(next(sources)), keys[0])
                reused_key_accepted = True
                if again.resume_key:  # it superseded ours: go on with what it gave
                    keys.append(again.resume_key)
            except Exception:
                reused_key_accepted = False
    await asyncio.sleep(max(0.0, end - time.monotonic()))  # held, as by a client that never closes
    # Those the server has closed show as closing or closed on our side by now.
    open_at_end = sum(1 for ws in held if ws.state is State.OPEN)
    await asyncio.gather(*(ws.close() for ws in held), return_exceptions=True)
    return {
        "resumes_tried": resumed + sum(refusals.values()),
        "resumed": resumed,
        "refused": dict(refusals.most_common(3)),
        "key_rotated": len(keys) > 1,
        "keys_seen": len(keys),
        "reused_key_accepted": reused_key_accepted,
        "connections_opened": len(held),
        "connections_still_open_at_end": open_at_end,
    }


ATTACKS: dict[str, Callable[[Target, float], dict[str, Any] | None]] = {
    "big_body": attack_big_body,
    "priority_flood": attack_priority_flood,
    "ws_flood": attack_ws_flood,
    "fd_exhaustion": attack_fd_exhaustion,
    "recordings_listing": attack_recordings_listing,
    "timeline_reads": attack_timeline_reads,
    "task_preview": attack_task_preview,
    "forged_datagrams": attack_forged_datagrams,
    "relay_offers": attack_relay_offers,
    "resume_pileup": attack_resume_pileup,
}
RECORDING_ATTACKS = ("recordings_listing", "timeline_reads", "task_preview")


def _attacker(name: str, target: Target, seconds: float, out: Any) -> None:
    if target.attacker_nice:
        # --attacker-nice: a real attacker's CPU is not the server's. Here the attackers
        # share the server's 2 cores, and at the same priority the scheduler alone can
        # hold the server's loop for a slice of tens of ms (the e-stop's worst case
        # then says more about this machine than about the server's handling).
        os.nice(target.attacker_nice)
    try:
        out.put(ATTACKS[name](target, seconds) or {})
    except Exception as exc:  # the bench reports it; the other attacks still run
        out.put({"attacker_failed": f"{type(exc).__name__}: {exc}"})


# ---------------------------------------------------------------- observers (own process)
def _observer(host: str, port: int, seconds: float, steps: int, out: Any) -> None:
    as_remote_client(steps)
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


def _relay_viewer(base: str, seconds: float, steps: int, out: Any) -> None:
    """The legitimate observer of ``relay_offers``: an offer every RELAY_TRY_EVERY_S from
    127.0.0.1, closed at once (it holds no slot); served = answered 200."""
    as_remote_client(steps)
    statuses: Counter[str] = Counter()
    took: list[float] = []
    end = time.monotonic() + seconds
    with httpx.Client(base_url=base, timeout=10) as http:
        while time.monotonic() < end:
            t0 = time.monotonic()
            try:
                r = http.post("api/v1/webrtc/server-offer", json={})
                took.append(time.monotonic() - t0)
                statuses[str(r.status_code)] += 1
                if r.status_code == 200:
                    peer = r.json()
                    http.delete(
                        f"api/v1/webrtc/{peer['peer_id']}",
                        headers={"X-Peer-Secret": peer["peer_secret"], **CLIENT},
                    )
            except httpx.HTTPError as exc:
                statuses[type(exc).__name__] += 1
            time.sleep(max(0.0, RELAY_TRY_EVERY_S - (time.monotonic() - t0)))
    tries = sum(statuses.values())
    out.put(
        {
            "tries": tries,
            "served": statuses["200"],
            "statuses": dict(statuses),
            "offer_ms_p50": statistics.median(took) * 1000.0 if took else None,
            "offer_ms_max": max(took) * 1000.0 if took else None,
        }
    )


def _operator(host: str, port: int, seconds: float, steps: int, ids: Any, out: Any) -> None:
    as_remote_client(steps)
    out.put(asyncio.run(_operate(host, port, seconds, ids)))


async def _operate(host: str, port: int, seconds: float, ids: Any) -> dict[str, Any]:
    """Join with the token on the server's clock, take the lease, hand the bench the
    client id (it resets the e-stop as this client) and send a cartesian increment
    every OPERATOR_PERIOD_S; count what the server answered."""
    from harness.wsclient import RealtimeClient, open_socket

    client = await RealtimeClient.hello(
        await open_socket(f"ws://{host}:{port}/ws"), TOKEN, m.HelloFlags.SYNCED_CLOCK
    )
    await client.sync_clock(20)
    await client.take_lease()
    ids.put(client.client_id)
    sent_at: dict[int, float] = {}
    acks: list[float] = []
    errors: Counter[str] = Counter()
    other: list[str] = []
    retakes = 0
    last_retake = -1.0
    offset = client.offset
    finished, answered = asyncio.Event(), asyncio.Event()  # sending; every answer in

    async def receive() -> None:
        nonlocal retakes, last_retake
        while True:
            data = await client.ws.recv()
            if data[0] == m.ACK.type_id:
                seq = m.ACK.struct.unpack_from(data)[1]
                t0 = sent_at.pop(seq, None)
                if t0 is not None:
                    acks.append(time.monotonic() - t0)
            elif data[0] == m.ERROR.type_id:
                _, fields, text = m.decode(data)
                if sent_at.pop(int(fields["seq"]), None) is None:
                    continue  # (a LEASE's)
                if text.startswith("stale command"):
                    errors["stale"] += 1
                elif "e-stop is latched" in text:
                    errors["estop_latched"] += 1
                elif "lease" in text:  # lapsed in a stall: take it again
                    errors["no_lease"] += 1
                    now = time.monotonic()
                    if now - last_retake > 0.1:
                        last_retake = now
                        retakes += 1
                        msg = m.encode(m.LEASE, client.next_seq(), m.LeaseAction.TAKE)
                        await client.ws.send(msg)
                else:
                    errors["other"] += 1
                    if len(other) < 3 and text not in other:
                        other.append(text)
            if finished.is_set() and not sent_at:
                answered.set()

    receiver = asyncio.create_task(receive())
    sent = 0
    start = time.monotonic()
    end = start + seconds
    try:
        while (now := time.monotonic()) < end:
            sign = 1.0 if (sent // 20) % 2 == 0 else -1.0
            seq = client.next_seq()
            sent_at[seq] = now
            dx = sign * OPERATOR_STEP_M
            zero = (0.0, 0.0, 0.0, 0.0, 0.0)
            await client.ws.send(m.encode(m.CART_INC, seq, now + offset, m.Frame.BASE, dx, *zero))
            sent += 1
            late = time.monotonic() - (start + sent * OPERATOR_PERIOD_S)
            if late > OPERATOR_PERIOD_S:  # this process stalled: no burst to catch up
                start += late
            await asyncio.sleep(max(0.0, -late))
        finished.set()
        if sent_at:
            with contextlib.suppress(TimeoutError):  # the last answers
                await asyncio.wait_for(answered.wait(), 1.0)
    finally:
        receiver.cancel()
        with contextlib.suppress(BaseException):
            await receiver
        await client.close()
    ack_ms = np.array(acks) * 1000.0
    return {
        "sent": sent,
        "acked": len(acks),
        "stale_dropped": errors["stale"],
        "estop_latched_refused": errors["estop_latched"],
        "lease_lost_refused": errors["no_lease"],
        "lease_retakes": retakes,
        "other_refused": errors["other"],
        "other_refusals": other,
        "unanswered": len(sent_at),
        "ack_ms_p50": float(np.percentile(ack_ms, 50)) if len(ack_ms) else None,
        "ack_ms_p99": float(np.percentile(ack_ms, 99)) if len(ack_ms) else None,
    }


def gaps_ms(times: list[float]) -> np.ndarray:
    return np.diff(np.array(times)) * 1000.0 if len(times) > 1 else np.array([float("inf")])


# ---------------------------------------------------------------- the bench
def press_estop(http: httpx.Client, base: str) -> float:
    t0 = time.perf_counter()
    r = http.post(base + "api/v1/safety/estop", json={}, timeout=120)
    elapsed = (time.perf_counter() - t0) * 1000.0
    r.raise_for_status()
    return elapsed


def reset_estop(http: httpx.Client, base: str, operator: str) -> bool:
    """Reset as the operator's client (its lease; taken again if it lapsed)."""
    h = {"Authorization": f"Bearer {TOKEN}", "X-Client-Id": operator}
    if http.post(base + "api/v1/safety/reset", headers=h, timeout=60).status_code == 200:
        return True
    http.post(base + "api/v1/lease", json={"name": "bench", "force": True}, headers=h, timeout=60)
    return http.post(base + "api/v1/safety/reset", headers=h, timeout=60).status_code == 200


def server_sockets(server: psutil.Process) -> int | None:
    try:
        return len(server.net_connections(kind="inet"))
    except psutil.Error:
        return None


def period(
    name: str | None, target: Target, seconds: float, server: psutil.Process
) -> dict[str, Any]:
    ctx = multiprocessing.get_context("spawn")
    seen_q: Any = ctx.Queue()
    op_q: Any = ctx.Queue()
    ids: Any = ctx.Queue()
    attack_q: Any = ctx.Queue()
    viewer_q: Any = ctx.Queue()
    host, port, base = target.host, target.http_port, target.base
    rss_before = server.memory_info().rss
    sockets_before = server_sockets(server)
    cpu_before = sum(server.cpu_times()[:2])
    t0 = time.monotonic()
    steps = target.client_priority
    observer = ctx.Process(target=_observer, args=(host, port, seconds, steps, seen_q))
    operator = ctx.Process(target=_operator, args=(host, port, seconds, steps, ids, op_q))
    observer.start()
    operator.start()
    try:  # connected, on the server's clock, holding the lease
        operator_id = ids.get(timeout=60)
    except queue.Empty:
        raise RuntimeError("the operator did not join and take the lease within 60 s") from None
    time.sleep(max(0.0, t0 + 1.0 - time.monotonic()))  # the observer is receiving
    attack_s = seconds - 1.5
    helpers = []
    if name is not None:
        helpers.append(ctx.Process(target=_attacker, args=(name, target, attack_s, attack_q)))
    if name == "relay_offers":
        helpers.append(ctx.Process(target=_relay_viewer, args=(base, attack_s, steps, viewer_q)))
    for p in helpers:
        p.start()
    estops: list[float] = []
    resets_failed = 0
    sockets_peak = sockets_before
    # Only this thread, and only now: the attackers' processes, started above, keep
    # the bench's own priority.
    with thread_priority_raised(steps) as clients_niceness, httpx.Client() as http:
        t_end = time.monotonic() + seconds - 2.0
        while time.monotonic() < t_end:
            time.sleep(0.3)
            estops.append(press_estop(http, base))
            resets_failed += not reset_estop(http, base, operator_id)
            n = server_sockets(server)
            if n is not None and (sockets_peak is None or n > sockets_peak):
                sockets_peak = n
    attack = None
    deadline = time.monotonic() + seconds + 120
    while name is not None and attack is None:  # the sockets, up to the attack's end
        n = server_sockets(server)
        if n is not None and (sockets_peak is None or n > sockets_peak):
            sockets_peak = n
        with contextlib.suppress(queue.Empty):
            attack = attack_q.get(timeout=0.2)
        if attack is None and time.monotonic() > deadline:
            raise RuntimeError(f"the {name} attacker never reported")
    if name == "relay_offers":
        assert attack is not None
        attack["observer"] = viewer_q.get(timeout=seconds + 60)
    for p in helpers:
        p.join(60)
    seen = seen_q.get(timeout=seconds + 60)
    op = op_q.get(timeout=seconds + 60)
    observer.join(10)
    operator.join(10)
    cpu_share = (sum(server.cpu_times()[:2]) - cpu_before) / (time.monotonic() - t0)
    time.sleep(1.0)  # what the attack left behind, after it has gone
    rss_after = server.memory_info().rss
    f, s = gaps_ms(seen["forces"]), gaps_ms(seen["states"])
    return {
        "estop_ms_p50": statistics.median(estops) if estops else None,
        "estop_ms_max": max(estops) if estops else None,
        "estops": len(estops),
        "estop_resets_failed": resets_failed,
        "force_p99_ms": float(np.percentile(f, 99)),
        "force_max_ms": float(f.max()),
        "forces_received": len(seen["forces"]),
        "state_gap_max_ms": float(s.max()),
        "rss_growth_mb": (rss_after - rss_before) / 1e6,
        "server_cpu_share": cpu_share,  # of one core, over the period
        "clients_niceness": clients_niceness,
        "server_sockets": {
            "before": sockets_before,
            "peak": sockets_peak,
            "after": server_sockets(server),
        },
        "operator": op,
        "attack": attack,
    }


def settle(server: psutil.Process, quiet_share: float, timeout: float = 30.0) -> float:
    """Wait (at most ``timeout``) until the server works no harder than in the quiet
    period (+10 % of a core) over half a second: a read an attack started and left
    running must not weigh on the next period. Returns the seconds waited."""
    t0 = time.monotonic()
    server.cpu_percent(None)
    while time.monotonic() - t0 < timeout:
        time.sleep(0.5)
        if server.cpu_percent(None) / 100.0 <= quiet_share + 0.1:
            break
    return time.monotonic() - t0


def run_periods(
    names: list[str], target: Target, seconds: float, server: psutil.Process, quiet: str
) -> dict[str, dict[str, Any]]:
    """The quiet period, then each attack's once the server has settled."""
    results = {quiet: period(None, target, seconds, server)}
    for name in names:
        waited = settle(server, results[quiet]["server_cpu_share"])
        results[name] = period(name, target, seconds, server)
        results[name]["settled_before_s"] = waited
        if name == "fd_exhaustion":
            results[name]["recovered"] = recovers(target)
    return results


def recovers(target: Target) -> bool:
    """Health, a /ws HELLO and a priority-channel HELLO all answered within 10 s."""
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            ok = httpx.get(target.base + "api/v1/health", timeout=2).status_code == 200
            ok = ok and asyncio.run(_ws_welcomed(target.host, target.http_port))
            ok = ok and _priority_welcomed(target.host, target.priority_port)
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


def _priority_welcomed(host: str, port: int) -> bool:
    hello = m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, TOKEN.encode())
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


def make_recordings(folder: Path) -> str:
    """RECORDINGS small ones for the listing (see the module's docstring) and the long
    one; returns the long one's file name."""
    from harness.recordings import build, build_listed, listed_episodes

    for i in range(RECORDINGS):
        episodes: list[dict[str, Any]] = []
        if i == RECORDINGS - 1:  # the newest: 10,000 episodes, 2,000-character labels
            episodes = listed_episodes(10_000, 2_000, duration=60.0)
        elif i >= RECORDINGS - 4:  # crafted: beyond the recorder's 2,000
            episodes = listed_episodes(5, 10_000)
        else:
            episodes = listed_episodes(2, 40)
        stamp = f"20260101-{i // 60:02d}{i % 60:02d}00"
        build_listed(
            folder / f"{stamp}-bench-{i:03d}.mcap",
            name=f"bench {i}",
            episodes=episodes,
            episode_events=len(episodes) <= 5,
        )
    long = build(folder / "20251231-235900-long.mcap", duration=LONG_RECORDING_S)
    return long.path.name


@contextlib.contextmanager
def bench_server(
    env: dict[str, str], state: Path | None = None
) -> Iterator[tuple[Target, psutil.Process]]:
    # serve_for_bench makes a throw-away state folder; a second --state-dir (the later
    # one wins) puts the server on ours, so the recordings are there before it starts.
    args = ("--state-dir", str(state)) if state is not None else ()
    with serve_for_bench(
        *args,
        env={"TELEROBOT_OPERATOR_TOKEN": TOKEN, **env},
        prefix=("prlimit", f"--nofile={SERVER_FDS}:{SERVER_FDS}"),
    ) as (proc, base):
        http_port = int(base.rstrip("/").rsplit(":", 1)[1])
        priority_port = httpx.get(base + "api/v1/force/channel").json()["port"]
        time.sleep(2.0)  # the arm initialises
        yield Target("127.0.0.1", http_port, priority_port), psutil.Process(proc.pid)


RELAY_ENV = {
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_MEDIA_SERVER": "janus",
    "TELEROBOT_VIDEO_WIDTH": "320",  # the smallest picture: the relay, not the encoder
    "TELEROBOT_VIDEO_HEIGHT": "180",
    "TELEROBOT_VIDEO_FPS": "15",
}


def relay_running(base: str, timeout: float = 60.0) -> str:
    """The media server's state once it runs (or the last seen after ``timeout``)."""
    deadline = time.monotonic() + timeout
    state = "no answer"
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError, KeyError, TypeError):
            state = httpx.get(base + "api/v1/video", timeout=5).json()["media_server"]["state"]
            if state == "running":
                break
        time.sleep(0.5)
    return state


def worst(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return max(known) if known else None


def summarise(results: dict[str, dict[str, Any]], relay: str, seconds: float) -> dict[str, Any]:
    quiet = results["quiet"]
    recovered = results.get("fd_exhaustion", {}).get("recovered")
    attacks = {k: v for k, v in results.items() if k not in ("quiet", "relay_quiet")}

    def attack(name: str) -> dict[str, Any] | None:
        a = results.get(name)
        return None if a is None else a.get("attack")

    big, flood = results.get("big_body"), results.get("priority_flood")
    stall = None if big is None else max(0.0, big["state_gap_max_ms"] - STATE_PERIOD_MS)
    flood_p99 = None if flood is None else flood["force_p99_ms"]
    datagrams, relay_a, resume = (
        attack("forged_datagrams"),
        attack("relay_offers"),
        results.get("resume_pileup"),
    )
    amplification = None if datagrams is None else datagrams.get("amplification")
    served = None
    if relay_a is not None and relay_a.get("observer", {}).get("tries"):
        served = relay_a["observer"]["served"] / relay_a["observer"]["tries"]
    held = None
    if resume is not None:
        sk = resume["server_sockets"]
        if sk["peak"] is not None and sk["before"] is not None:
            held = sk["peak"] - sk["before"]
    stale = {k: (v["operator"] or {}).get("stale_dropped") for k, v in results.items()}
    estop_worst = worst([v["estop_ms_max"] for v in attacks.values()])
    stale_worst = worst([stale[k] for k in attacks])
    rss_worst = worst([v["rss_growth_mb"] for v in attacks.values()])

    def goal(value: float | bool | None, ok: Callable[[Any], bool]) -> bool | None:
        return None if value is None else bool(ok(value))

    return {
        "stall_ms": stall,
        "stall_ms_quiet": max(0.0, quiet["state_gap_max_ms"] - STATE_PERIOD_MS),
        "estop_ms_under_attack": {k: v["estop_ms_max"] for k, v in attacks.items()},
        "estop_ms_under_attack_worst": estop_worst,
        "estop_ms_quiet_max": quiet["estop_ms_max"],
        "estop_ms_quiet_p50": quiet["estop_ms_p50"],
        "operator_stale_dropped": stale,
        "operator_stale_dropped_worst": stale_worst,
        "operator_stale_dropped_quiet": stale["quiet"],
        "operator_ack_ms_p50": {
            k: (v["operator"] or {}).get("ack_ms_p50") for k, v in results.items()
        },
        "force_p99_under_flood_ms": flood_p99,
        "force_p99_quiet_ms": quiet["force_p99_ms"],
        "force_p99_ratio_flood_vs_quiet": None
        if flood_p99 is None
        else flood_p99 / quiet["force_p99_ms"],
        "rss_growth_mb": {k: v["rss_growth_mb"] for k, v in results.items()},
        "rss_growth_mb_worst": rss_worst,
        "amplification": amplification,
        "relay": relay,
        "relay_observer_served_share": served,
        "resume_sockets_held": held,
        "recovers_after_fd_exhaustion": recovered,
        "goals": {
            "stall_ms_le_50": goal(stall, lambda v: v <= 50.0),
            "estop_ms_under_attack_worst_le_20": goal(estop_worst, lambda v: v <= 20.0),
            "operator_stale_dropped_worst_eq_0": goal(stale_worst, lambda v: v == 0),
            "force_p99_under_flood_ms_le_5": goal(flood_p99, lambda v: v <= 5.0),
            "rss_growth_mb_worst_le_20": goal(rss_worst, lambda v: v <= 20.0),
            "amplification_le_1": goal(amplification, lambda v: v <= 1.0),
            "recovers_after_fd_exhaustion": recovered,
            "relay_observer_served_share_ge_0_9": goal(served, lambda v: v >= 0.9),
            "resume_sockets_held_le_16": goal(held, lambda v: v <= 16),
        },
        "periods": results,
        "seconds_per_period": seconds,
        "server_fd_limit": SERVER_FDS,
        "machine": machine(),
        "load_average": list(psutil.getloadavg()),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=6.0, help="length of each period")
    p.add_argument(
        "--attacks",
        default=",".join(ATTACKS),
        help=f"which, comma-separated (default all: {','.join(ATTACKS)})",
    )
    p.add_argument(
        "--attacker-nice",
        type=int,
        default=0,
        help="run the attackers' processes at this niceness (0: the server's priority, the"
        " harsher case on one machine; 10: closer to attackers on other machines)",
    )
    p.add_argument(
        "--client-priority",
        type=int,
        default=CLIENT_PRIORITY,
        help="raise the legitimate clients' CPU priority (the operator, the observer, the"
        " e-stop) by this many nice steps, as the server raises its own (cpu_priority):"
        " they stand for other machines (0: the attackers' priority, the harsher case)",
    )
    p.add_argument(
        "--nack-flood-seconds",
        type=float,
        default=20.0,
        help="bench.nack_flood's flood (a server with video, two tokenless viewers; 0: none)",
    )
    args = p.parse_args()
    chosen = [a.strip() for a in args.attacks.split(",") if a.strip()]
    unknown = sorted(set(chosen) - set(ATTACKS))
    if unknown:
        p.error(f"unknown attacks {unknown}: choose from {', '.join(ATTACKS)}")
    if args.seconds < 2.0:
        p.error("--seconds must be at least 2 (1 s before the attack, 0.5 s after, the rest)")
    has_janus = shutil.which("janus") is not None
    here = [a for a in chosen if a != "relay_offers" or not has_janus]
    results: dict[str, dict[str, Any]] = {}
    relay = "not run"
    with tempfile.TemporaryDirectory(prefix="abuse-bench-") as state:
        recording = ""
        if any(a in RECORDING_ATTACKS for a in chosen):
            recording = make_recordings(Path(state) / "recordings")
        with bench_server({"TELEROBOT_VIDEO": "false"}, Path(state)) as (target, server):
            target = dataclasses.replace(
                target,
                recording=recording,
                attacker_nice=args.attacker_nice,
                client_priority=args.client_priority,
            )
            results = run_periods(here, target, args.seconds, server, "quiet")
        if "relay_offers" in chosen and not has_janus:
            relay = "none: no janus here; the main server (video off) answered, see statuses"
    if "relay_offers" in chosen and has_janus:
        with bench_server(RELAY_ENV) as (target, server):
            target = dataclasses.replace(
                target, attacker_nice=args.attacker_nice, client_priority=args.client_priority
            )
            relay = f"janus: {relay_running(target.base)}"
            results |= run_periods(["relay_offers"], target, args.seconds, server, "relay_quiet")
    summary = summarise(results, relay, args.seconds)
    summary["attacker_nice"] = args.attacker_nice
    summary["client_priority"] = args.client_priority
    if args.nack_flood_seconds > 0:
        summary["nack_flood"] = nack_flood.run(args.nack_flood_seconds)
    emit(summary, args.json)


if __name__ == "__main__":
    main()
