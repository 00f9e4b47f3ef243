"""Every use of aiortc's internals, in one place (docs/architecture.md, rule 24: other
projects' internals behind one adapter).

aiortc has no public way to hear a viewer's RTCP (NACKs, REMB, receiver reports), to
act on a key-frame request for pre-encoded video, to put a pacer, FEC or a header stamp
in a sender's RTP path, to read its RTP history or round trip, or to size its payloads.
The media modules do all of that through the functions here, never by name. ``check()``
runs when the video pipeline is made: if an internal has moved (another aiortc than
the tested ones, ``TESTED``), the server refuses to start the video and says which,
instead of a feature quietly stopping (a renamed history once would have stopped the
key-frame fallback unsaid). tests/test_aiortc_compat.py fails on the same.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from importlib.metadata import version
from typing import Any

from telerobot.drivers.base import TelerobotError

# The aiortc releases this adapter is tested with (pyproject.toml pins the same range).
TESTED = ">=1.9,<1.17"

# An aiortc RTCRtpSender's (name-mangled) attributes, its methods replaced per sender,
# and the DTLS transport's RTP path, which FEC, the pacer and the playout stamp wrap.
_HISTORY = "_RTCRtpSender__rtp_history"
_RTT = "_RTCRtpSender__rtt"
_PACKETS = "_RTCRtpSender__packet_count"
_EXTENSIONS = "_RTCRtpSender__rtp_header_extensions_map"
_ENCODER = "_RTCRtpSender__encoder"
_SENDER_NEEDS = (_HISTORY, _RTT, _PACKETS, _EXTENSIONS, _ENCODER, "_ssrc",
                 "_handle_rtcp_packet", "_send_keyframe")  # fmt: skip
_TRANSPORT_NEEDS = ("_send_rtp",)
_TRANSCEIVER_NEEDS = ("_codecs", "_headerExtensions")
# Where a peer's UDP sockets are: the ICE transport's aioice connection, its protocols
_ICE_NEEDS = ("_connection",)
_CONNECTION_NEEDS = ("_protocols",)


class AiortcIncompatible(TelerobotError):
    """This aiortc keeps its internals elsewhere than the tested releases."""

    code = "aiortc_incompatible"


def _missing(obj: Any, names: tuple[str, ...], what: str) -> list[str]:
    return [f"{what}.{n}" for n in names if not hasattr(obj, n)]


def check() -> None:
    """Build a peer connection's video sender (no network) and look for every internal
    used here; raise ``AiortcIncompatible`` naming what is missing."""
    import asyncio

    from aiortc import RTCPeerConnection
    from aiortc.codecs import CODECS, HEADER_EXTENSIONS, h264, vpx
    from aiortc.rtcdtlstransport import RTCDtlsTransport
    from aiortc.rtp import HeaderExtensionsMap

    missing = [
        f"aiortc.codecs.{name}.PACKET_MAX"
        for name, module in (("h264", h264), ("vpx", vpx))
        if not isinstance(getattr(module, "PACKET_MAX", None), int)
    ]
    if not isinstance(CODECS.get("video"), list) or not isinstance(
        HEADER_EXTENSIONS.get("video"), list
    ):
        missing.append("aiortc.codecs.CODECS / HEADER_EXTENSIONS['video']")
    if not hasattr(HeaderExtensionsMap(), "_HeaderExtensionsMap__ids"):
        missing.append("HeaderExtensionsMap.__ids")
    missing += _missing(RTCDtlsTransport, _TRANSPORT_NEEDS, "RTCDtlsTransport")

    async def build() -> list[str]:
        pc = RTCPeerConnection()
        try:
            transceiver = pc.addTransceiver("video", direction="sendonly")
            ice = transceiver.sender.transport.transport
            return (
                _missing(transceiver.sender, _SENDER_NEEDS, "RTCRtpSender")
                + _missing(transceiver, _TRANSCEIVER_NEEDS, "RTCRtpTransceiver")
                + _missing(ice, _ICE_NEEDS, "RTCIceTransport")
                + _missing(getattr(ice, "_connection", None), _CONNECTION_NEEDS, "aioice")
            )
        finally:
            await pc.close()

    try:
        asyncio.get_running_loop()
        running = True
    except RuntimeError:
        running = False
    if running:  # (inside a loop: the sender's internals are read off a thread's loop)
        import concurrent.futures

        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            missing += pool.submit(asyncio.run, build()).result()
    else:
        missing += asyncio.run(build())
    if missing:
        raise AiortcIncompatible(
            f"aiortc {version('aiortc')} keeps its internals elsewhere than the releases"
            f" Telerobot's video is tested with (aiortc{TESTED}): {', '.join(missing)}"
            f" missing. Install a tested one: pip install 'aiortc{TESTED}'"
        )


# ---------------------------------------------------------------- the process's offers
def offer_video_codec(mime: str, payload_type: int, clock_rate: int = 90000) -> None:
    """Let aiortc negotiate ``mime`` for video from now on (this process)."""
    from aiortc.codecs import CODECS
    from aiortc.rtcrtpparameters import RTCRtpCodecParameters

    video = CODECS["video"]
    if all(c.mimeType.lower() != mime for c in video):
        codec = RTCRtpCodecParameters(mimeType=mime, clockRate=clock_rate, payloadType=payload_type)
        video.append(codec)


def offer_video_extension(uri: str, ext_id: int) -> None:
    """Let aiortc negotiate the RTP header extension ``uri`` for video (this process)."""
    from aiortc.codecs import HEADER_EXTENSIONS
    from aiortc.rtcrtpparameters import RTCRtpHeaderExtensionParameters

    video = HEADER_EXTENSIONS["video"]
    if all(x.uri != uri for x in video):
        video.append(RTCRtpHeaderExtensionParameters(id=ext_id, uri=uri))


# ---------------------------------------------------------------- a transceiver
def agreed_codecs(transceiver: Any) -> list[Any]:
    """The codecs both peers agreed on, in aiortc's order (the first is sent)."""
    return list(getattr(transceiver, "_codecs", []))


def agreed_extensions(transceiver: Any) -> list[Any]:
    """The RTP header extensions both peers agreed on."""
    return list(getattr(transceiver, "_headerExtensions", []))


# ---------------------------------------------------------------- a sender
def rtp_history(sender: Any) -> dict[int, Any]:
    """The packets the sender keeps to resend (aiortc: the last 128, by number % 128)."""
    return getattr(sender, _HISTORY)  # type: ignore[no-any-return]


def rtt_s(sender: Any) -> float | None:
    """The round trip the sender's RTCP measured (None before a report says)."""
    value = getattr(sender, _RTT, None)
    return None if value is None else float(value)


def packets_sent(sender: Any) -> int:
    return int(getattr(sender, _PACKETS, 0))


def extension_id(sender: Any, name: str) -> int | None:
    """The id the peers agreed on for a header extension aiortc knows by ``name``
    (``abs_send_time`` …); None if none."""
    ids = getattr(getattr(sender, _EXTENSIONS, None), "_HeaderExtensionsMap__ids", None)
    value = getattr(ids, name, None)
    return int(value) if value else None


def ssrc(sender: Any) -> int:
    return int(sender._ssrc)


RtcpHandler = Callable[[Any], Awaitable[None]]


def handle_rtcp(sender: Any, handler: RtcpHandler) -> RtcpHandler:
    """Every RTCP packet for ``sender`` goes to ``handler`` instead; returns aiortc's
    own handler (call it for what aiortc should still do: resends, REMB)."""
    own: RtcpHandler = sender._handle_rtcp_packet
    sender._handle_rtcp_packet = handler
    return own


def on_keyframe_request(sender: Any, then: Callable[[], None]) -> None:
    """Call ``then`` after aiortc's own handling of a viewer's PLI or FIR (pre-encoded
    video needs the encoder told), and when ``request_keyframe`` is called."""
    own = sender._send_keyframe

    def both() -> None:
        own()
        then()

    sender._send_keyframe = both


def request_keyframe(sender: Any) -> None:
    """As a viewer's PLI would."""
    sender._send_keyframe()


def limit_payload(transceiver: Any, size: int) -> bool:
    """The transceiver's sender packs H.264 and VP8 payloads of at most ``size`` bytes
    (aiortc's packetizers read one module constant, 1300, for every sender in the
    process: it is swapped for this sender's ``pack`` only, which runs on the event
    loop's thread, one call at a time). For pre-encoded video (the shared encoders'
    frames); False if the peers agreed on neither codec."""
    from aiortc.codecs import get_encoder, h264, vpx

    codecs = [c for c in agreed_codecs(transceiver) if c.mimeType.lower() in _PACKED]
    if not codecs:
        return False
    module: Any = h264 if codecs[0].mimeType.lower() == "video/h264" else vpx

    class Sized:
        def __init__(self) -> None:
            self._real = get_encoder(codecs[0])

        def __getattr__(self, name: str) -> Any:
            return getattr(self._real, name)

        def pack(self, *args: Any, **kwargs: Any) -> Any:
            before = module.PACKET_MAX
            module.PACKET_MAX = min(before, size)
            try:
                return self._real.pack(*args, **kwargs)
            finally:
                module.PACKET_MAX = before

    setattr(transceiver.sender, _ENCODER, Sized())
    return True


_PACKED = ("video/h264", "video/vp8")


def send_rtp_path(transport: Any) -> Callable[[bytes], Awaitable[None]] | None:
    """The transport's RTP send path (what a sender calls per packet), or None."""
    return getattr(transport, "_send_rtp", None)


def put_in_rtp_path(transport: Any, send: Callable[[bytes], Awaitable[None]]) -> None:
    """``send`` becomes the transport's RTP path (it calls the one it wraps)."""
    transport._send_rtp = send


def peer_sockets(pc: Any) -> list[Any]:
    """The UDP sockets of a peer connection (aiortc exposes none: they sit in aioice's
    connection behind the ICE transport). Each as its event loop gives it: a
    ``socket.socket``, or uvloop's ``PseudoSocket`` (the server's loop), which takes
    ``setsockopt`` as well."""
    found = []
    for transceiver in pc.getTransceivers():
        ice = transceiver.sender.transport.transport
        for protocol in ice._connection._protocols:
            transport = getattr(protocol, "transport", None)
            sock = transport.get_extra_info("socket") if transport is not None else None
            if sock is not None:
                found.append(sock)
    return found
