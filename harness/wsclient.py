"""A minimal client of the binary protocol, for the benchmarks and the tests: hello, lease,
clock sync, commands, force reception."""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from typing import Any

import websockets

from telerobot.protocol import messages as m
from telerobot.protocol.clock import ClockSync
from telerobot.protocol.typed import HelloMessage, LeaseMessage, PingMessage


async def open_socket(url: str) -> Any:
    return await websockets.connect(url, max_size=None, compression=None)


class RealtimeClient:
    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.offset = 0.0  # server clock − client clock, seconds
        self.seq = 0
        self.client_id = ""
        self.resume_key = ""  # with HELLO's RESUMABLE flag: continue the session elsewhere
        self.arms: dict[str, int] = {}  # each arm's name → its index (the ARMs after WELCOME)

    @classmethod
    async def connect(cls, url: str, token: str = "", flags: int = 0) -> RealtimeClient:
        return await cls.hello(await open_socket(url), token, flags)

    @classmethod
    async def hello(cls, ws: Any, token: str = "", flags: int = 0) -> RealtimeClient:
        """Say HELLO on an open WebSocket and wait for the WELCOME."""
        client = cls(ws)
        await ws.send(
            HelloMessage(version=m.PROTOCOL_VERSION, flags=flags, token=token.encode()).encode()
        )
        _, fields, text = await client.expect_message(m.WELCOME)
        client.client_id, _, client.resume_key = text.partition(" ")
        for _ in range(int(fields["arms"])):  # an ARM for each arm follows at once
            _, arm, name = await client.expect_message(m.ARM)
            client.arms[name] = int(arm["index"])
        return client

    @classmethod
    async def resume(cls, ws: Any, key: str, flags: int = 0) -> RealtimeClient:
        """The session of ``key`` continued on ``ws``, a new connection (the server
        closes the old one): what a client does when its link stalled (the page:
        realtime.ts). The key is spent: the returned client's ``resume_key`` is the next.
        One resume at a time: a later one would supersede this, so open connections in
        parallel (a SYN lost in the cut waits 1 s to be resent) but resume on the first
        that opens."""
        flags |= m.HelloFlags.RESUME | m.HelloFlags.RESUMABLE
        return await cls.hello(ws, key, flags)

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq

    async def expect(self, wanted: m.Message, timeout: float = 5.0) -> dict[str, Any]:
        """Read until a message of type ``wanted``; an ERROR on the way raises."""
        return (await self.expect_message(wanted, timeout))[1]

    async def expect_message(
        self, wanted: m.Message, timeout: float = 5.0
    ) -> tuple[m.Message, dict[str, Any], Any]:
        """As ``expect``, with the message's tail (text) too."""
        async with asyncio.timeout(timeout):
            while True:
                data = await self.ws.recv()
                if data[0] == wanted.type_id:
                    return m.decode(data)
                if data[0] == m.ERROR.type_id:
                    _, fields, text = m.decode(data)
                    raise RuntimeError(
                        f"server error {fields['code']} for seq {fields['seq']}: {text}"
                    )

    async def take_lease(self) -> None:
        await self.ws.send(LeaseMessage(seq=self.next_seq(), action=m.LeaseAction.TAKE).encode())
        await self.expect(m.ACK)

    async def sync_clock(self, rounds: int = 50) -> float:
        """NTP-style offset from the ping with the shortest round trip; returns that RTT."""
        clock = ClockSync()
        for _ in range(rounds):
            t0 = time.monotonic()
            await self.ws.send(PingMessage(seq=self.next_seq(), t0=t0).encode())
            pong = await self.expect(m.PONG)
            clock.pong(t0, pong["t1"], pong["t2"], time.monotonic())
        self.offset = clock.offset
        return clock.best_rtt

    async def close(self) -> None:
        await self.ws.close()


class StallResumer:
    """Keeps a client's session through a stalled link, as the page does (realtime.ts):
    nothing heard for ``stall_s`` → open connections every ``every_s`` (in parallel: a
    SYN lost in the cut is resent only after 1 s) and resume on the first to open, alone
    (a second resume would take the session over again). The caller calls ``heard()``
    for every message it reads and reads ``client.ws`` afresh after a resume."""

    def __init__(
        self, client: RealtimeClient, url: str, stall_s: float = 0.4, every_s: float = 0.25
    ) -> None:
        self.client, self.url = client, url
        self.stall_s, self.every_s = stall_s, every_s
        self.last_heard = time.monotonic()
        self.resumed = 0
        self.last_resumed = -math.inf
        # What each attempt came to: (time.monotonic(), "resumed" / why not), the
        # last 64 (for a closer look at a lease lost through a cut).
        self.attempts: deque[tuple[float, str]] = deque(maxlen=64)
        self._resuming = False
        self._tasks: set[asyncio.Task[None]] = set()

    def heard(self) -> None:
        self.last_heard = time.monotonic()

    async def recv(self) -> Any:
        """The next message on the client's connection, whichever it is by then (an
        old one closed by a resume is left behind), counted as news."""
        while True:
            try:
                data = await self.client.ws.recv()
            except websockets.WebSocketException:
                await asyncio.sleep(0.01)
                continue
            self.heard()
            return data

    def stalled(self) -> bool:
        return time.monotonic() - self.last_heard > self.stall_s

    async def run(self) -> None:
        """Watch until cancelled."""
        last = 0.0
        try:
            while True:
                await asyncio.sleep(0.1)
                now = time.monotonic()
                if self.stalled() and not self._resuming and now - last >= self.every_s:
                    last = now
                    task = asyncio.create_task(self._attempt())
                    self._tasks.add(task)
                    task.add_done_callback(self._tasks.discard)
        finally:
            for task in list(self._tasks):
                task.cancel()

    async def _attempt(self) -> None:
        started = time.monotonic()
        try:
            ws = await asyncio.wait_for(open_socket(self.url), 3.0)
        except (OSError, TimeoutError, websockets.WebSocketException) as exc:
            self.attempts.append((time.monotonic(), f"open: {type(exc).__name__} {exc}"))
            return
        # Resumed by another attempt since this one started: not needed. (The old
        # connection's news getting through is no reason to stop: our side of it may
        # still wait on TCP's retransmission timer, as in the page, realtime.ts.)
        if self._resuming or self.last_resumed > started:
            self.attempts.append((time.monotonic(), "not needed"))
            await ws.close()
            return
        self._resuming = True
        try:
            new = await RealtimeClient.resume(ws, self.client.resume_key)
        except (OSError, TimeoutError, RuntimeError, websockets.WebSocketException) as exc:
            self.attempts.append((time.monotonic(), f"resume: {type(exc).__name__} {exc}"))
            return
        finally:
            self._resuming = False
        self.attempts.append((time.monotonic(), "resumed"))
        self.last_resumed = time.monotonic()
        old, self.client.ws = self.client.ws, new.ws
        self.client.resume_key = new.resume_key  # a key resumes once: the next one
        self.heard()
        self.resumed += 1
        closing = asyncio.create_task(asyncio.wait_for(old.close(), 1.0))
        self._tasks.add(closing)  # type: ignore[arg-type]
        closing.add_done_callback(self._tasks.discard)  # type: ignore[arg-type]
