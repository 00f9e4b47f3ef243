"""The server's side of the media server (docs/media-server.md): where it is, and
keeping it up.

``telerobot serve --media-server janus`` starts Janus itself (``JanusProcess``: a
generated configuration, its HTTP API on 127.0.0.1, the admin API off, one mountpoint
with a secret derived from the operator token) and restarts it when it dies, with a
doubling backoff; viewers through it see their video stall and renegotiate (the page
does so by itself) once it is back. With ``--media-server-url`` it uses a Janus on
another machine and only watches that it answers. The media worker does the feeding
and the observers' signalling (backend/media/relay.py); this runs in the server.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import logging
import shutil
import socket
import time
from typing import Any
from urllib.parse import urlsplit

import httpx

from telerobot.drivers.base import DriverUnavailable
from telerobot.server.media.janus import JANUS, JanusProcess, JanusSettings, free_port
from telerobot.server.settings import Settings

log = logging.getLogger(__name__)

WATCH_S = 0.5  # how often the process is checked
PROBE_S = 2.0  # how often a Janus elsewhere is asked whether it answers
FIRST_BACKOFF_S, MAX_BACKOFF_S = 0.5, 8.0


def derived_secret(token: str, what: bytes = b"telerobot media server") -> str:
    """A secret for the media server when none is set: from the operator token, one way."""
    return hmac.new(token.encode(), what, hashlib.sha256).hexdigest()[:32]


def resolve(settings: Settings, token: str) -> Settings:
    """``settings`` with the media server's address, ports and secret filled in (free
    ports chosen now for the ones left 0), as the media worker needs them."""
    if settings.media_server == "none":
        return settings
    update: dict[str, Any] = {}
    if settings.media_server_secret is None:
        update["media_server_secret"] = derived_secret(token)
    if settings.media_server_api_secret is None:
        update["media_server_api_secret"] = derived_secret(token, b"telerobot media server api")
    if settings.media_server_url is None:  # ours: on this machine
        http = settings.media_server_http_port or free_port()
        update["media_server_http_port"] = http
        update["media_server_url"] = f"http://127.0.0.1:{http}/janus"
        update["media_server_host"] = "127.0.0.1"
        for name in ("media_server_rtp_port", "media_server_rtcp_port", "media_server_data_port"):
            update[name] = getattr(settings, name) or free_port(socket.SOCK_DGRAM)
    elif settings.media_server_host is None:  # the settings checked the ports
        update["media_server_host"] = urlsplit(settings.media_server_url).hostname
    return settings.model_copy(update=update)


class MediaServerSupervisor:
    def __init__(self, settings: Settings, managed: bool) -> None:
        """``settings`` as ``resolve`` gives them; ``managed``: Janus is ours to start
        (no ``media_server_url`` was given)."""
        self.settings = settings
        self.managed = settings.media_server != "none" and managed
        self.process: JanusProcess | None = None
        if self.managed:
            assert settings.media_server_secret is not None  # resolve() sets it
            self.process = JanusProcess(
                JanusSettings(
                    http_port=settings.media_server_http_port,
                    rtp_port=settings.media_server_rtp_port,
                    secret=settings.media_server_secret,
                    rtp_ports=settings.media_server_webrtc_ports,
                    rtcp_port=settings.media_server_rtcp_port or None,
                    data_port=settings.media_server_data_port or None,
                    api_secret=settings.media_server_api_secret,
                )
            )
        self.state = "stopped"
        self.restarts = 0
        self.last_error: str | None = None
        self.started_at: float | None = None
        self._task: asyncio.Task[None] | None = None
        self._stopping = False
        # Starting and stopping the process (each in a thread) never overlap: a stop
        # during a restart waits for the start, then stops what it started.
        self._lock = asyncio.Lock()

    @property
    def url(self) -> str | None:
        return self.settings.media_server_url

    async def start(self) -> None:
        if self.settings.media_server == "none":
            return
        if self.process is not None:
            if shutil.which(JANUS) is None:
                raise DriverUnavailable(
                    "--media-server janus needs Janus on this machine: apt-get install janus"
                    " (make test installs it), or give one elsewhere with --media-server-url"
                )
            await self._start_process()
        else:
            await self._probe()
        self._task = asyncio.create_task(self._watch(), name="media-server-watchdog")

    async def _start_process(self) -> bool:
        assert self.process is not None
        self.state = "starting"
        async with self._lock:
            if self._stopping:
                return False
            try:
                await asyncio.to_thread(self.process.start)
            except Exception as exc:  # any failure: said, and tried again later
                self.state, self.last_error = "down", str(exc)
                log.error("the media server did not start: %s", exc)
                return False
        self.state, self.started_at = "running", time.monotonic()
        # Not its URL: the line `telerobot serve` prints with ours is found by its "http://"
        log.info("media server (Janus) running, its HTTP API on 127.0.0.1 port %d",
                 self.settings.media_server_http_port)  # fmt: skip
        return True

    async def _probe(self) -> None:
        try:
            async with httpx.AsyncClient(timeout=2.0) as http:
                answered = (await http.get(f"{self.url}/info")).status_code == 200
        except httpx.HTTPError as exc:
            answered, self.last_error = False, f"{type(exc).__name__}: {exc}"
        self.state = "running" if answered else "unreachable"

    async def _watch(self) -> None:
        backoff = FIRST_BACKOFF_S
        while not self._stopping:
            if self.process is None:
                await asyncio.sleep(PROBE_S)
                await self._probe()
                continue
            await asyncio.sleep(WATCH_S)
            if self.process.alive or self._stopping:
                if self.state == "running" and time.monotonic() - (self.started_at or 0) > 30:
                    backoff = FIRST_BACKOFF_S  # up a while: the next death starts afresh
                continue
            proc = self.process.proc
            code = proc.returncode if proc is not None else None
            said = self.process.log_tail()
            self.last_error = f"Janus exited (code {code})" + (f": {said}" if said else "")
            log.error("the media server died (exit code %s); restarting it in %g s", code, backoff)
            self.state = "restarting"
            async with self._lock:
                await asyncio.to_thread(self.process.stop)  # its old folder and log
            await asyncio.sleep(backoff)
            backoff = min(MAX_BACKOFF_S, backoff * 2)
            self.restarts += 1
            await self._start_process()

    async def stop(self) -> None:
        self._stopping = True
        # The lock first: a start in flight (in its thread) ends before anything else,
        # and then the watchdog is cancelled where it cannot be starting one.
        async with self._lock:
            if self._task is not None:
                self._task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await self._task
            if self.process is not None:
                await asyncio.to_thread(self.process.stop)
        self.state = "stopped"

    def status(self, operator: bool = False) -> dict[str, Any]:
        """Its state for anyone; where it is (its API's URL, its process, what it
        said when it died) for the operator only."""
        shown: dict[str, Any] = {
            "kind": self.settings.media_server,
            "state": self.state,
            "restarts": self.restarts,
        }
        if operator:
            shown.update(
                managed=self.managed,
                url=self.url,
                last_error=self.last_error,
                pid=self.process.proc.pid
                if self.process is not None and self.process.proc is not None
                else None,
            )
        return shown
