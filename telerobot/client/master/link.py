"""A client of the priority channel (``telerobot.server.realtime.priority``): one TCP socket,
length-prefixed messages, a reader thread that hands every force sample over the
moment it arrives. Thread-safe sends; used by the master-arm bridge and the
force-under-video benchmark.

With ``datagrams=True`` the forces come as UDP datagrams instead (DATAGRAMS in
docs/protocol.md), for an operator (the server sends an observer's on TCP only): on a
lossy link a lost sample is then just lost, where on TCP it holds every later one back
by a retransmission (a round trip or more). The server answers with a key of its own,
new at every registration; a second reader thread takes the datagrams and keeps the
server's mapping alive with that key. Until a datagram comes the forces stay on TCP;
if none arrives within ``DATAGRAM_FALLBACK_S`` of the key, the link registers again
(a new key), and again, each time waiting twice as long, up to ``DATAGRAM_RETRY_MAX_S``:
on a lossy link one lost keep-alive, answer or outage must not cost the datagrams for
the whole session. Only a server that refuses (an ERROR to the DATAGRAMS) keeps the
forces on TCP for good. ``datagrams`` says which and why ("asking", "asking (try 2)",
"udp", "tcp: <why>"), ``datagram_registrations`` how many times it asked; if the
server goes back to TCP later (the keep-alives lost, or refused because a NAT gave
the socket a new port), the link registers again, for a new key.

**Arms** (docs/protocol.md, "Arms (version 3)"). A server drives one arm or more: the
link learns them from WELCOME and the ARM messages after it (``arms``: index, name,
joint count) before its constructor returns. Every command takes the arm it is for,
by index or name; left out it is 0, "the only arm", so a one-arm caller works
unchanged (and is refused, with the arms' names, by a server with more). STATE comes
per arm (``states``: the newest of each); each arm's sensor numbers its own samples,
so the stale filter is per arm, and ``on_arm_force`` says whose each sample is
(``on_force`` gets them all, or only ``force_arm``'s when that names one)."""

from __future__ import annotations

import contextlib
import json
import logging
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

import httpx

from telerobot.drivers.base import DeviceError, ForceSample, InvalidCommand, TelerobotError
from telerobot.protocol import messages as m
from telerobot.protocol.clock import ClockSync
from telerobot.protocol.netprio import mark_high_priority
from telerobot.protocol.typed import (
    ArmMessage,
    CartIncMessage,
    DatagramsMessage,
    EnergyMessage,
    ErrorMessage,
    EstopMessage,
    EventMessage,
    HeartbeatMessage,
    HelloMessage,
    JointIncMessage,
    LeaseMessage,
    NameMessage,
    PingMessage,
    PongMessage,
    StateMessage,
    WelcomeMessage,
    parse,
)
from telerobot.tuning import prompt_thread

log = logging.getLogger(__name__)

ForceCallback = Callable[[ForceSample, float], None]  # sample, receive time (monotonic)
ArmForceCallback = Callable[[int, ForceSample, float], None]  # arm index, sample, receive time
DATAGRAM_KEEPALIVE_S = 0.5  # DATAGRAMS to the server this often (it waits 2 s)
FIRST_SEQ_END = m.FORCE_HEAD.size + 4  # a FORCE's first sample's seq ends here
# No force datagram this long after the server's key: register again (forces on TCP
# meanwhile), each try waiting twice the last, up to DATAGRAM_RETRY_MAX_S.
DATAGRAM_FALLBACK_S = 2.0
DATAGRAM_RETRY_MAX_S = 12.0


def newer(seq: int, last: int) -> bool:
    """Whether sample number ``seq`` comes after ``last`` (u32, wrapping)."""
    return 0 < (seq - last) & 0xFFFFFFFF < 0x80000000


class Thinning:
    """How many samples the server should send one of (DATAGRAMS.every), judged from
    the sample numbers that arrive. Datagrams have no congestion control: 1000 a second
    are ~0.7 Mbit/s with their headers, which a 2 Mbit/s link shared with video cannot
    carry without queueing and dropping everything, commands included. So: every half
    second, more than ``LOSS_UP`` of the samples sent missing doubles ``every`` (up to
    ``MAX``); ``CLEAN_S`` with less than ``LOSS_CLEAN`` missing halves it. (A link's
    random loss looks like congestion here; a bad link then gets ~60 samples a second,
    which is what it can carry anyway.)"""

    MAX = 16
    LOSS_UP = 0.05
    LOSS_CLEAN = 0.01
    CLEAN_S = 2.0

    def __init__(self, now: float) -> None:
        self.every = 1
        self.loss = 0.0  # of the last window judged
        self._first: int | None = None
        self._last = 0
        self._got = 0
        self._clean_since = now

    def arrived(self, seq: int) -> None:
        if seq % self.every:
            return  # sent before the server heard of the last change
        if self._first is None:
            self._first = self._last = seq
        elif newer(seq, self._last):
            self._last = seq
        self._got += 1

    def judge(self, now: float) -> int:
        """End a window (every ``DATAGRAM_KEEPALIVE_S``); returns ``every`` for the next."""
        if self._first is not None and self._got > 1:
            expected = ((self._last - self._first) & 0xFFFFFFFF) // self.every + 1
            self.loss = max(0.0, 1.0 - self._got / expected)
            if self.loss > self.LOSS_UP:
                self.every = min(2 * self.every, self.MAX)
                self._clean_since = now
            elif self.loss >= self.LOSS_CLEAN:
                self._clean_since = now
            elif now - self._clean_since >= self.CLEAN_S and self.every > 1:
                self.every //= 2
                self._clean_since = now
        self._first, self._got = None, 0
        return self.every


@dataclass
class Reply:
    name: str
    fields: dict[str, Any]
    text: str


@dataclass(frozen=True)
class LinkArm:
    """One arm the server drives, as its ARM message said."""

    index: int  # on the wire: 1 for the first
    name: str  # what REST's ``?arm=`` takes ("arm" on a one-arm server)
    joints: int


class PriorityLink:
    @property
    def offset(self) -> float:
        """Server clock − this machine's monotonic clock (s)."""
        return self.clock.offset

    @property
    def best_rtt(self) -> float:
        return self.clock.best_rtt

    def __init__(
        self,
        host: str,
        port: int,
        token: str = "",
        *,
        on_force: ForceCallback | None = None,
        on_arm_force: ArmForceCallback | None = None,
        on_state: Callable[[dict[str, Any]], None] | None = None,
        on_reply: Callable[[Reply], None] | None = None,
        timeout_s: float = 5.0,
        datagrams: bool = False,
        name: str = "",
        policy: bool = False,
    ) -> None:
        """``policy``: this client is a learned policy (HELLO's POLICY flag): it drives
        under an operator's supervision (docs/protocol.md, Supervised autonomy)."""
        self.on_force = on_force
        self.on_state = on_state
        self.on_reply = on_reply
        self._send_lock = threading.Lock()
        self._seq = 0
        self.operator = False
        self.client_id = ""
        self.joint_count = 0  # the first arm's, from WELCOME
        self.arms: tuple[LinkArm, ...] = ()  # from the ARM messages after WELCOME
        self._arms_said = 0  # WELCOME.arms: how many ARM messages follow it
        # The newest STATE of each arm (by index), as decoded.
        self.states: dict[int, dict[str, Any]] = {}
        self.on_arm_force = on_arm_force
        self.force_arm = 0  # on_force gets this arm's samples only (0: every arm's)
        # A policy's supervision as the server last said it (EVENT autonomy, sent on
        # joining and at each change): off, autonomous, paused or correcting.
        self.autonomy = "off"
        self.clock = ClockSync()  # the server's clock, from PING
        self.closed_reason: str | None = None
        self.received = 0
        self.received_by_arm: dict[int, int] = {}
        self.stale_samples = 0  # older than one already handed over (datagrams reorder)
        self._last_seq: dict[int, int] = {}  # per arm: each sensor numbers its own samples
        self._force_lock = threading.Lock()  # two readers with datagrams
        # Forces as datagrams: "tcp" (not asked), "asking" ("asking (try 2)", … when the
        # last registration brought no datagram), "udp", or "tcp: <why>" (for good).
        self.datagrams = "tcp"
        self.datagrams_received = 0
        self.datagram_registrations = 0  # DATAGRAMS sent on TCP (each for a new key)
        self._udp: socket.socket | None = None
        self._udp_reader: threading.Thread | None = None
        # The registration's state, between the two readers (and the constructor).
        self._datagram_lock = threading.Lock()
        self._datagram_seq = -1
        self._datagram_key = b""  # the server's (none until it answers)
        self._datagram_asked_at = -DATAGRAM_FALLBACK_S  # time.monotonic()
        self._datagram_answered_at: float | None = None  # when this try's key came
        self._datagram_try = 0  # of this round of asking (1: the first DATAGRAMS)
        self._datagram_wait_s = DATAGRAM_FALLBACK_S  # for this try's first datagram
        # The newest sample that came by UDP, per arm (each sensor numbers its own).
        self._last_datagram_seq: dict[int, int] = {}
        self.thinning = Thinning(0.0)
        self._stopping = threading.Event()
        try:
            self.sock = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as exc:
            raise DeviceError(
                f"cannot reach the priority channel at tcp://{host}:{port}: {exc}"
            ) from None
        mark_high_priority(self.sock)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # Blocking from here on, before the reader starts (the WELCOME's time limit is the
        # wait below). Switched while the reader was in recv(), Python set the socket's
        # mode before the descriptor's, and a recv() in between found a non-blocking
        # descriptor in blocking mode: "[Errno 11] Resource temporarily unavailable",
        # taken for a lost channel (a busy machine's test run reconnected a live link).
        self.sock.settimeout(None)
        self._welcome = threading.Event()
        self._pings: dict[int, float] = {}
        flags = m.HelloFlags.POLICY if policy else 0
        hello = HelloMessage(version=m.PROTOCOL_VERSION, flags=flags, token=token.encode("ascii"))
        self._send(hello.encode())
        self._reader = threading.Thread(target=self._read, name="priority-link", daemon=True)
        self._reader.start()
        if not self._welcome.wait(timeout_s):
            self.close()
            raise DeviceError(
                f"no WELCOME from tcp://{host}:{port} within {timeout_s:g} s"
                + (f": {self.closed_reason}" if self.closed_reason else "")
            )
        if name:  # who has control, as everyone sees it (else "priority HOST:PORT")
            self.rename(name)
        if datagrams:
            self._ask_for_datagrams()

    # ------------------------------------------------------------ sending
    def _next(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        return self._seq

    def _send(self, message: bytes) -> None:
        with self._send_lock:
            self.sock.sendall(m.LENGTH.pack(len(message)) + message)

    def rename(self, name: str) -> int:
        """Go by ``name`` (NAME: answered by ACK, or by ERROR saying why)."""
        seq = self._next()
        self._send(NameMessage(seq=seq, text=name).encode())
        return seq

    def lease(self, action: m.LeaseAction) -> int:
        seq = self._next()
        self._send(LeaseMessage(seq=seq, action=int(action)).encode())
        return seq

    def cartesian(self, dX: tuple[float, float, float], rotvec: tuple[float, float, float],
                  frame: m.Frame = m.Frame.BASE, arm: int | str = 0) -> int:  # fmt: skip
        """A Cartesian increment for ``arm`` (index or name; 0: the only arm)."""
        index = self.arm_index(arm)
        seq = self._next()
        (dx, dy, dz), (rx, ry, rz) = dX, rotvec
        command = CartIncMessage(
            seq=seq, client_time=time.monotonic(), frame=int(frame),
            dx=dx, dy=dy, dz=dz, rx=rx, ry=ry, rz=rz, arm=index,
        )  # fmt: skip
        self._send(command.encode())
        return seq

    def energy(self, e_in: float, e_out: float, arm: int | str = 0) -> int:
        """This master's side of the two-port with ``arm`` (ENERGY: J, the arm's units,
        so far); answered by PORT_ENERGY."""
        index = self.arm_index(arm)
        seq = self._next()
        self._send(EnergyMessage(seq=seq, e_in=e_in, e_out=e_out, arm=index).encode())
        return seq

    def next_seq(self) -> int:
        """A seq for a command about to be sent (so its reply can be expected first)."""
        with self._send_lock:
            return self._next()

    def joints(self, dq: Sequence[float], seq: int | None = None, arm: int | str = 0) -> int:
        """A joint increment (rad) for ``arm`` (index or name; 0: the only arm), one per
        joint of that arm; returns its seq."""
        index = self.arm_index(arm)
        seq = self.next_seq() if seq is None else seq
        command = JointIncMessage(
            seq=seq, client_time=time.monotonic(), arm=index, joints=tuple(dq)
        )
        self._send(command.encode())
        return seq

    # ------------------------------------------------------------ arms
    @property
    def arm_names(self) -> list[str]:
        return [a.name for a in self.arms]

    def arm_index(self, arm: int | str = 0) -> int:
        """``arm`` as the wire names it: an index as it is (0: the only arm; the server
        refuses 0 when it drives more), a name as its ARM message's index."""
        if isinstance(arm, str):
            for a in self.arms:
                if a.name == arm:
                    return a.index
            raise InvalidCommand(f"no arm named {arm!r} here: {self._listed()}")
        if not 0 <= arm <= len(self.arms):
            raise InvalidCommand(f"no arm {arm} here: {self._listed()}")
        return arm

    def arm(self, arm: int | str = 0) -> LinkArm:
        """The arm ``arm`` names (index or name); 0 is the only arm, refused (with the
        arms' names) on a server that drives more."""
        index = self.arm_index(arm)
        if index == 0:
            if len(self.arms) != 1:
                raise InvalidCommand(
                    f"this server drives {len(self.arms)} arms ({', '.join(self.arm_names)}):"
                    " name the arm"
                )
            return self.arms[0]
        return self.arms[index - 1]

    def _listed(self) -> str:
        return (
            f"this server drives {len(self.arms)} arm{'s' if len(self.arms) != 1 else ''}"
            f" ({', '.join(f'{a.index} {a.name}' for a in self.arms)})"
        )

    def heartbeat(self) -> None:
        self._send(HeartbeatMessage(seq=self._next(), client_time=time.monotonic()).encode())

    def estop(self) -> None:
        self._send(EstopMessage(seq=self._next(), client_time=time.monotonic()).encode())

    def ping(self) -> None:
        seq = self._next()
        t0 = time.monotonic()
        self._pings[seq] = t0
        self._send(PingMessage(seq=seq, t0=t0).encode())

    def send_raw(self, message: bytes) -> None:
        """One framed message as it is (for tests of the server's checks)."""
        self._send(message)

    def close(self) -> None:
        self._stopping.set()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        for reader in (self._reader, self._udp_reader):
            if (
                reader is not None
                and reader.is_alive()
                and reader is not threading.current_thread()
            ):
                reader.join(timeout=2)
        if self._udp is not None:
            self._udp.close()

    # ------------------------------------------------------------ forces as datagrams
    def _ask_for_datagrams(self) -> None:
        if not self.operator:
            self.datagrams = "tcp: the server sends an observer's forces on TCP only"
            return
        try:
            udp = socket.socket(self.sock.family, socket.SOCK_DGRAM)
            udp.connect(self.sock.getpeername()[:2])  # the channel's address, UDP
        except OSError as exc:
            self.datagrams = f"tcp: no UDP socket ({exc})"
            return
        mark_high_priority(udp)
        udp.settimeout(DATAGRAM_KEEPALIVE_S / 2)
        self._udp = udp
        self.thinning = Thinning(time.monotonic())
        self._register_datagrams()
        self._udp_reader = threading.Thread(
            target=self._read_datagrams, args=(udp,), name="priority-link-udp", daemon=True
        )
        self._udp_reader.start()

    def _register_datagrams(self, again: bool = False) -> None:
        """DATAGRAMS on TCP: the server answers with a new key (the old one is void).
        ``again``: the last try brought no datagram, so the next try of this round,
        waiting twice as long (up to ``DATAGRAM_RETRY_MAX_S``); else a new round."""
        with self._datagram_lock:
            if again:
                if not self.datagrams.startswith("asking"):
                    return  # (refused, or a datagram came, meanwhile)
                self._datagram_try += 1
                self._datagram_wait_s = min(2 * self._datagram_wait_s, DATAGRAM_RETRY_MAX_S)
            else:
                self._datagram_try = 1
                self._datagram_wait_s = DATAGRAM_FALLBACK_S
            self._datagram_key = b""
            self._datagram_answered_at = None
            self._datagram_asked_at = time.monotonic()
            tries = self._datagram_try
            self.datagrams = "asking" if tries == 1 else f"asking (try {tries})"
            self._datagram_seq = self.next_seq()
            self.datagram_registrations += 1
            asking = DatagramsMessage(
                seq=self._datagram_seq, key=bytes(16), every=self.thinning.every
            )
            message = asking.encode()
        self._send(message)  # (not under the lock: the TCP reader takes it for the answer)

    def _retry_due(self, now: float) -> bool:
        """Whether this try has had its time: ``_datagram_wait_s`` since the key came
        (the server learns our address only after it), or since asking while no answer
        has come (an answer held up on TCP is then void, but the next, waiting longer,
        gets through)."""
        if not self.datagrams.startswith("asking"):
            return False
        answered = self._datagram_answered_at
        since = self._datagram_asked_at if answered is None else answered
        return now - since > self._datagram_wait_s

    def _read_datagrams(self, udp: socket.socket) -> None:
        prompt_thread()  # woken per sample: ahead of whatever runs on its core
        said_at = -DATAGRAM_KEEPALIVE_S
        while not self._stopping.is_set() and not self.datagrams.startswith("tcp"):
            now = time.monotonic()
            if self._retry_due(now):
                if not self._reader.is_alive():
                    self.datagrams = f"tcp: {self.closed_reason or 'the channel closed'}"
                    return
                log.warning(
                    "no force datagram within %g s (try %d): forces on TCP, asking again",
                    self._datagram_wait_s,
                    self._datagram_try,
                )
                try:
                    self._register_datagrams(again=True)
                except OSError as exc:  # (the channel is gone)
                    self.datagrams = f"tcp: {exc}"
                    return
            if now - said_at >= DATAGRAM_KEEPALIVE_S and self._datagram_key:
                said_at = now
                every = self.thinning.judge(now) if self.datagrams == "udp" else self.thinning.every
                with contextlib.suppress(OSError):
                    udp.send(DatagramsMessage(seq=0, key=self._datagram_key, every=every).encode())
            try:
                data = udp.recv(2048)
            except TimeoutError:
                continue
            except OSError:
                continue  # (an ICMP error; or closed, and the loop ends)
            if data[:1] == bytes((m.FORCE.type_id,)) and len(data) >= FIRST_SEQ_END:
                seq = int.from_bytes(data[m.FORCE_HEAD.size : FIRST_SEQ_END], "little")
                arm = data[1]
                if self.datagrams != "udp" and self._datagram_key:
                    # (Not while the key is still to come: a datagram of the last
                    # registration, on its way before it, says nothing of this one.)
                    with self._datagram_lock:
                        if self.datagrams.startswith("asking") and self._datagram_key:
                            self.datagrams = "udp"
                self.datagrams_received += 1
                last = self._last_datagram_seq.get(arm)
                if last is None or newer(seq, last):
                    self._last_datagram_seq[arm] = seq
                # Judged on the first arm's samples (each sensor numbers its own; they
                # share the link, so one tells the link's loss).
                if arm == min(self._last_datagram_seq):
                    self.thinning.arrived(seq)
                with contextlib.suppress(m.MalformedMessage):
                    self._forces(data, time.monotonic())

    def _tcp_force(self, message: bytes) -> None:
        """A sample on TCP while the datagrams flow: newer than any datagram, it means
        the server has gone back to TCP (our keep-alives stopped reaching it, or come
        from a port it does not know: a NAT's new mapping). Register again (a new round
        of tries), at most once per ``DATAGRAM_FALLBACK_S``."""
        last = self._last_datagram_seq.get(message[1]) if len(message) > 1 else None
        if len(message) < FIRST_SEQ_END or last is None:
            return
        seq = int.from_bytes(message[m.FORCE_HEAD.size : FIRST_SEQ_END], "little")
        now = time.monotonic()
        if newer(seq, last) and now - self._datagram_asked_at > DATAGRAM_FALLBACK_S:
            log.info("forces came on TCP again: asking for datagrams anew")
            with contextlib.suppress(OSError):
                self._register_datagrams()

    # ------------------------------------------------------------ receiving
    def _read(self) -> None:
        prompt_thread()
        buf = bytearray()
        try:
            while True:
                data = self.sock.recv(65536)
                if not data:
                    self.closed_reason = self.closed_reason or "the server closed the channel"
                    return
                now = time.monotonic()
                buf += data
                while len(buf) >= m.LENGTH.size:
                    (size,) = m.LENGTH.unpack_from(buf)
                    if len(buf) < m.LENGTH.size + size:
                        break
                    message = bytes(buf[m.LENGTH.size : m.LENGTH.size + size])
                    del buf[: m.LENGTH.size + size]
                    self._dispatch(message, now)
        except OSError as exc:
            self.closed_reason = self.closed_reason or str(exc)

    def _forces(self, message: bytes, now: float) -> None:
        arm = m.force_arm(message)
        with self._force_lock:
            for seq, t, values in m.decode_force(message):
                last = self._last_seq.get(arm)
                if last is not None and not newer(seq, last):
                    self.stale_samples += 1
                    continue
                self._last_seq[arm] = seq
                self.received += 1
                self.received_by_arm[arm] = self.received_by_arm.get(arm, 0) + 1
                sample = ForceSample(seq, t, values)  # type: ignore[arg-type]
                if self.on_arm_force is not None:
                    self.on_arm_force(arm, sample, now)
                if self.on_force is not None and self.force_arm in (0, arm):
                    self.on_force(sample, now)

    def _dispatch(self, message: bytes, now: float) -> None:
        if message[0] == m.FORCE.type_id:
            if self.datagrams == "udp":
                self._tcp_force(message)
            self._forces(message, now)
            return
        msg = parse(message)
        if isinstance(msg, ErrorMessage | DatagramsMessage) and msg.seq == self._datagram_seq:
            self._datagrams_answered(msg, now)
        match msg:
            case WelcomeMessage():
                self.operator = msg.role == 1
                self.joint_count = msg.joints
                self.client_id = msg.text
                self._arms_said = msg.arms
                self.arms = ()
                if self._arms_said == 0:  # (no arm: nothing follows)
                    self._welcome.set()
            case ArmMessage():  # the constructor returns once every arm is in
                self.arms = (*self.arms, LinkArm(msg.index, msg.text, msg.joints))
                if len(self.arms) >= self._arms_said:
                    self._welcome.set()
            case StateMessage():  # (not a reply: on_state only)
                fields = msg.as_dict()
                self.states[msg.arm] = fields
                if self.on_state is not None:
                    self.on_state(fields)
                return
            case EventMessage(kind=m.EventKind.AUTONOMY):
                with contextlib.suppress(ValueError, TypeError, KeyError):
                    self.autonomy = str(json.loads(msg.text)["mode"])
            case PongMessage():
                t0 = self._pings.pop(msg.seq, None)
                if t0 is not None:
                    self.clock.pong(t0, msg.t1, msg.t2, now)
            case ErrorMessage() if not self._welcome.is_set():
                self.closed_reason = msg.text
            case _:
                pass  # (the others are for on_reply alone)
        if self.on_reply is not None:
            self.on_reply(Reply(msg.SPEC.name, msg.as_dict(), getattr(msg, "text", "")))

    def _datagrams_answered(self, msg: ErrorMessage | DatagramsMessage, now: float) -> None:
        """The server's answer to our DATAGRAMS (the current one: its seq)."""
        if isinstance(msg, ErrorMessage):
            with self._datagram_lock:  # refused: for good, the UDP reader ends
                self.datagrams = f"tcp: {msg.text}"
            log.warning("forces stay on TCP: %s", msg.text)
        elif self._udp:
            # Registered, with the server's key: say it by UDP now, from the socket the
            # forces should come to (the server learns its port from this one; the UDP
            # reader repeats it every DATAGRAM_KEEPALIVE_S, so one lost is no matter).
            with self._datagram_lock:
                current = msg.seq == self._datagram_seq  # (else asked again)
                if current:
                    self._datagram_key = msg.key
                    self._datagram_answered_at = now
            if current:
                with contextlib.suppress(OSError):
                    answer = DatagramsMessage(seq=0, key=msg.key, every=msg.every)
                    self._udp.send(answer.encode())


def open_link(
    server: str, token: str, *, datagrams: bool = True, name: str = "", policy: bool = False
) -> PriorityLink:
    """Find the server's priority channel (GET /api/v1/force/channel) and connect,
    going by ``name`` (as a ``policy`` if said); forces as datagrams unless
    ``datagrams`` is False."""
    base = server if server.endswith("/") else server + "/"
    try:
        channel = httpx.get(base + "api/v1/force/channel", timeout=5, verify=False).json()
    except (httpx.HTTPError, ValueError) as exc:
        raise TelerobotError(f"cannot ask {base} for its priority channel: {exc}") from None
    host = urlsplit(base).hostname or "localhost"
    return PriorityLink(
        host, int(channel["port"]), token, datagrams=datagrams, name=name, policy=policy
    )
