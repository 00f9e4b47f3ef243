"""Janus as the media server that fans the one encoded stream out to many viewers:
the process started and supervised with a generated configuration, the streaming
plugin's RTP mountpoint fed with the same H.264 packets the encoder already makes (no
second encode). Its HTTP API's client is the media worker's (backend/media/relay.py).

Janus 1.1.2 (Debian's) facts this relies on (docs of the streaming plugin and the REST
API; checked here): it is configured by a folder of ``.jcfg`` files (``-F``); plugins
and transports are turned off by a ``disable`` list; the HTTP API binds to 127.0.0.1
with the admin API off; a mountpoint of type "rtp" listens for H.264 RTP on a UDP port
and counts a packet as a key frame only if it carries an SPS (our encoder repeats
SPS/PPS before each IDR); a viewer ``watch``es, gets Janus's SDP offer by long poll and
``start``s with its answer. A session ends 60 s after its last request (seen here;
keepalives hold it) and holds a viewer until destroyed: whoever creates one destroys it.

The media worker feeds it and signals for observers (backend/media/relay.py); the
server starts and supervises it (backend/media/media_server.py).
"""

from __future__ import annotations

import contextlib
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from telerobot.drivers.base import DeviceError, DriverUnavailable

JANUS = "janus"
# Debian's multiarch folder for this machine's architecture (x86_64-linux-gnu,
# aarch64-linux-gnu, …), wherever Janus's plugins were installed.
LIBS = next(
    iter(sorted(Path("/usr/lib").glob("*/janus/plugins"))), Path("/usr/lib/janus/plugins")
).parent
OTHER_PLUGINS = (
    "audiobridge duktape echotest lua nosip recordplay sip textroom videocall videoroom voicemail"
)
OTHER_TRANSPORTS = "mqtt nanomsg pfunix rabbitmq websockets"
MOUNTPOINT = 1
H264_FMTP = "profile-level-id=42e01f;packetization-mode=1"
READY_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class JanusSettings:
    http_port: int  # its HTTP API, on 127.0.0.1
    rtp_port: int  # where the robot's H.264 RTP goes, on 127.0.0.1
    secret: str  # the mountpoint's secret (its full info, its viewer count)
    rtp_ports: tuple[int, int] = (20000, 20999)  # its WebRTC side
    # Where it sends its viewers' key frame requests from (to the address that sent it
    # RTCP last); None: they go nowhere, and the feed must make key frames by itself.
    rtcp_port: int | None = None
    # Datagrams to this port (on 127.0.0.1) go to every viewer's data channel, as bytes
    # (observers' state and forces); None: no data channel.
    data_port: int | None = None
    # Where its HTTP API listens, and where it takes the RTP and data: 127.0.0.1 when the
    # robot's server runs beside it (the server starts it), the host's address for a
    # Janus the server reaches over the network (`telerobot media-server`).
    api_host: str = "127.0.0.1"
    feed_host: str = "127.0.0.1"
    # ICE connectivity checks as keep-alives: how Janus notices a viewer that vanished
    # without closing (a laptop shut, a crash) and hangs its peer up.
    conncheck: bool = True
    # Every request to its API carries this (its api_secret); None: none needed.
    api_secret: str | None = None

    @property
    def api(self) -> str:
        host = "127.0.0.1" if self.api_host in ("0.0.0.0", "") else self.api_host
        return f"http://{host}:{self.http_port}/janus"


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _disable(names: str) -> str:
    return ",".join(f"libjanus_{n}.so" for n in names.split())


def write_config(folder: Path, settings: JanusSettings) -> None:
    """The three ``.jcfg`` files: the core, the HTTP transport, the streaming plugin."""
    folder.mkdir(parents=True, exist_ok=True)
    lo, hi = settings.rtp_ports
    api_secret = "" if settings.api_secret is None else f'\n  api_secret = "{settings.api_secret}"'
    (folder / "janus.jcfg").write_text(
        f"""general: {{
  configs_folder = "{folder}"
  plugins_folder = "{LIBS / "plugins"}"
  transports_folder = "{LIBS / "transports"}"
  events_folder = "{LIBS / "events"}"
  loggers_folder = "{LIBS / "loggers"}"
  debug_level = 3
  debug_colors = false
  server_name = "telerobot-janus"{api_secret}
}}
certificates: {{ }}
media: {{ rtp_port_range = "{lo}-{hi}" }}
nat: {{ ignore_mdns = true{"; ice_keepalive_conncheck = true" if settings.conncheck else ""} }}
plugins: {{ disable = "{_disable(OTHER_PLUGINS)}" }}
transports: {{ disable = "{_disable(OTHER_TRANSPORTS)}" }}
loggers: {{ disable = "libjanus_jsonlog.so" }}
events: {{ broadcast = false }}
"""
    )
    (folder / "janus.transport.http.jcfg").write_text(
        f"""general: {{ json = "compact"; base_path = "/janus"; http = true;
  port = {settings.http_port}; ip = "{settings.api_host}"; https = false }}
admin: {{ admin_http = false; admin_https = false }}
"""
    )
    rtcp = "" if settings.rtcp_port is None else f"\n  videortcpport = {settings.rtcp_port}"
    if settings.data_port is not None:  # not databuffermsg: 1.1.2 leaks each datagram
        rtcp += (
            f"\n  data = true\n  dataport = {settings.data_port}"
            f'\n  dataiface = "{settings.feed_host}"\n  datatype = "binary"'
        )
    (folder / "janus.plugin.streaming.jcfg").write_text(
        f"""general: {{ events = false }}
robot-stereo: {{
  type = "rtp"
  id = {MOUNTPOINT}
  description = "Telerobot stereo H.264"
  audio = false
  video = true
  videoport = {settings.rtp_port}
  videoiface = "{settings.feed_host}"
  videopt = 96
  videocodec = "h264"
  videofmtp = "{H264_FMTP}"
  secret = "{settings.secret}"{rtcp}
}}
"""
    )


def launch(settings: JanusSettings, folder: Path, **io: Any) -> subprocess.Popen[bytes]:
    """Janus started with a configuration written into ``folder``/conf (``io``: where
    its log goes; by default this process's stdout)."""
    exe = shutil.which(JANUS)
    if exe is None:
        raise DriverUnavailable(
            "the media server mode needs Janus: apt-get install janus (make test installs it)"
        )
    write_config(folder / "conf", settings)
    return subprocess.Popen([exe, "-F", str(folder / "conf"), "-o"], **io)


def wait_ready(proc: subprocess.Popen[bytes], api: str) -> bool | None:
    """True once its HTTP API answers; False if it exited first; None if neither within
    ``READY_TIMEOUT_S``."""
    deadline = time.monotonic() + READY_TIMEOUT_S
    while proc.poll() is None:
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(api + "/info", timeout=1).status_code == 200:
                return True
        if time.monotonic() > deadline:
            return None
        time.sleep(0.05)
    return False


class JanusProcess:
    """Janus started with a generated configuration in a folder of its own, ready when
    its HTTP API answers; ``stop`` ends it (SIGINT: it says "Bye!")."""

    def __init__(self, settings: JanusSettings) -> None:
        self.settings = settings
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self.proc: subprocess.Popen[bytes] | None = None
        self.log: Path | None = None

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def start(self) -> JanusProcess:
        self._dir = tempfile.TemporaryDirectory(prefix="telerobot-janus-")
        folder = Path(self._dir.name)
        self.log = folder / "janus.log"
        with self.log.open("wb") as out:
            self.proc = launch(self.settings, folder, stdout=out, stderr=subprocess.STDOUT)
        ready = wait_ready(self.proc, self.settings.api)
        if ready is False:
            raise DeviceError(f"janus exited at start:\n{self.log.read_text()[-2000:]}")
        if ready is None:
            self.stop()
            raise DeviceError(f"janus did not answer within {READY_TIMEOUT_S:g} s")
        return self

    def log_tail(self, chars: int = 400) -> str:
        """The end of its log (why it died), before ``stop`` removes it."""
        if self.log is None or not self.log.exists():
            return ""
        with self.log.open("rb") as f:
            f.seek(max(0, self.log.stat().st_size - chars))
            return f.read().decode("utf-8", "replace").strip()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(2)  # SIGINT: a clean exit
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None

    def __enter__(self) -> JanusProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def run_foreground(settings: JanusSettings, folder: Path) -> int:
    """Janus with a configuration written into ``folder``, in the foreground (its log on
    stdout) until it exits or is interrupted; its exit code."""
    proc = launch(settings, folder)

    def forward(signum: int, _frame: object) -> None:  # stopped: Janus stops too
        proc.send_signal(signal.SIGINT)

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    if wait_ready(proc, settings.api):
        print(
            f"media server ready: its HTTP API on {settings.api_host}:{settings.http_port},"
            f" RTP to {settings.feed_host}:{settings.rtp_port}",
            flush=True,
        )
    return proc.wait()


class RtpFeed:
    """The encoder's H.264 packets as RTP to the mountpoint's port: packetised as aiortc
    packetises them for a peer (single NAL, STAP-A, FU-A), never encoded again. With
    ``rtcp_port`` (the mountpoint's ``videortcpport``) it also sends RTCP sender reports
    there, from the same socket: Janus sends its viewers' key frame requests (PLI) back
    to the address they came from (``read_feedback``)."""

    def __init__(
        self,
        port: int,
        ssrc: int = 0x7E1E,
        host: str = "127.0.0.1",
        rtcp_port: int | None = None,
    ) -> None:
        from aiortc.codecs.h264 import H264Encoder  # its packetiser only

        self._packetiser = H264Encoder()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._to = (host, port)
        self._rtcp_to = None if rtcp_port is None else (host, rtcp_port)
        self._seq = 0
        self._last_timestamp = 0
        self.ssrc = ssrc
        self.packets = 0
        self.octets = 0

    def fileno(self) -> int:
        return self._sock.fileno()

    def send_report(self) -> None:
        """An RTCP sender report to the RTCP port (nothing without one)."""
        if self._rtcp_to is None:
            return
        from aiortc.clock import current_ntp_time
        from aiortc.rtp import RtcpSenderInfo, RtcpSrPacket

        report = RtcpSrPacket(
            ssrc=self.ssrc,
            sender_info=RtcpSenderInfo(
                ntp_timestamp=current_ntp_time(),
                rtp_timestamp=self._last_timestamp,
                packet_count=self.packets & 0xFFFFFFFF,
                octet_count=self.octets & 0xFFFFFFFF,
            ),
        )
        with contextlib.suppress(OSError):
            self._sock.sendto(bytes(report), self._rtcp_to)

    def read_feedback(self) -> bool:
        """Read what came back; True if it asked for a key frame (PLI or FIR)."""
        from aiortc.rtp import RtcpPacket, RtcpPsfbPacket

        asked = False
        while True:
            try:
                data = self._sock.recv(2048)
            except (BlockingIOError, InterruptedError):
                return asked
            except OSError:  # e.g. ICMP port unreachable while Janus restarts
                continue
            with contextlib.suppress(ValueError):
                for packet in RtcpPacket.parse(data):
                    if isinstance(packet, RtcpPsfbPacket) and packet.fmt in (1, 4):
                        asked = True  # PLI (1) or FIR (4)

    def send(self, packet: Any) -> None:
        """One encoded access unit (an ``av.Packet`` with its pts and time base)."""
        from aiortc.rtp import RtpPacket

        payloads, timestamp = self._packetiser.pack(packet)
        # The pts is the capture time on the monotonic clock at 90 kHz: past 2³² (13.25 h
        # of uptime) it no longer fits RTP's 32 bits, and every send failed (the relay's
        # viewers got no frame on a machine up that long). RTP timestamps wrap.
        timestamp &= 0xFFFFFFFF
        for i, payload in enumerate(payloads):
            rtp = RtpPacket(
                payload_type=96,
                sequence_number=self._seq & 0xFFFF,
                timestamp=timestamp,
                ssrc=self.ssrc,
                payload=payload,
            )
            rtp.marker = int(i == len(payloads) - 1)
            with contextlib.suppress(BlockingIOError, OSError):  # UDP: a full buffer drops
                self._sock.sendto(rtp.serialize(), self._to)
            self._seq += 1
            self.packets += 1
            self.octets += len(payload)
        self._last_timestamp = timestamp

    def close(self) -> None:
        self._sock.close()
