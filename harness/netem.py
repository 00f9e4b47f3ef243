"""The one link emulator the benchmarks and the tests share: a server and a
client network namespace joined by a veth pair, shaped by a named link profile.

    python -m bench.netem [--json] [--profile wifi --profile mobile] [--probes 300]

measures what each profile really does (``measure_link`` and ``measure_rate`` here: UDP
probes between the namespaces, real sockets): round-trip and one-way delays, loss each
way, throughput where the profile limits the rate.

Use it from code as a context manager::

    with NetemPair("wan") as pair:
        server = subprocess.Popen([*pair.server_prefix, "telerobot", "serve",
                                   "--host", pair.server_addr, ...])
        client = subprocess.run([*pair.client_prefix, sys.executable, ...])
        with pair.outage():          # nothing gets through either way…
            time.sleep(2.0)
        pair.link_down(2.0)          # …the same, blocking
        pair.apply("mobile")         # another profile, same namespaces
        print(measure_link(pair))    # what the link does now, measured

Profiles. Every figure applies to EACH direction separately: ``delay_ms`` is the
ONE-WAY delay, so a round trip takes 2 × ``delay_ms`` (plus 2 × jitter's spread),
``loss_pct`` is lost on the way out and again on the way back (a request and its
answer both arrive with probability (1 − p)²), ``rate_mbit`` caps each direction (the
Ethernet frame is counted, as netem counts it).

============  ===========  ==========  ======  ===========
profile       delay        jitter (σ)  loss    rate
============  ===========  ==========  ======  ===========
``lan``       —            —           —       — (the bare veth)
``wifi``      5 ms         3 ms        0.5 %   —
``wan``       40 ms        10 ms       1 %     20 Mbit/s
``mobile``    80 ms        30 ms       2 %     4 Mbit/s
``bad``       150 ms       50 ms       5 %     2 Mbit/s
============  ===========  ==========  ======  ===========

Jitter without reordering. netem draws each packet's delay independently (here from
its ``normal`` table, σ = jitter) and, without a rate, sends packets in the order of
their drawn times, so a stream denser than the jitter comes out heavily reordered.
With ``rate`` set, netem takes the last packet still held as the reference: a packet
leaves no earlier than the one before it (``time_to_send = max(now + delay,
last.time_to_send) + length / rate``). Every shaped profile therefore sets a rate (an
unlimited profile gets 10 Gbit/s, which costs 1.2 µs a frame): packets keep their order,
and a lone packet's delay is the profile's, but a stream denser than the jitter is
held behind its slower predecessors, so its delays are those of a FIFO link: e.g. at
1 kHz on ``mobile`` the median one-way delay is ~129 ms, not 80 ms (a simulation of the
rule; measured here: 132–143 ms), 10 ms apart ~98 ms, 50 ms apart ~82 ms. Measure with
probes spaced wider than the jitter (``probe_interval_s``) to see a profile's own delay.
``limit_packets`` (netem's ``limit``, default 1000 as netem's) bounds what a direction
holds, delayed or queued behind the rate; past it packets are dropped.

Two backends, one behaviour:

- ``netem`` (preferred): ``tc qdisc replace dev <veth> root netem limit L delay D J
  distribution normal loss random P% rate R`` on each veth end's egress. TSO/GSO is
  turned down to one segment a packet while shaped (``gso_max_segs 1``) so loss and
  rate act on wire-sized packets as on a real link, not on 64 KB TCP super-packets.
- ``forwarder`` (when the kernel has no ``sch_netem``, e.g. ``CONFIG_NET_SCH_NETEM``
  unset): each veth end's egress is redirected (``clsact`` + ``u32`` + ``mirred``) to a
  TAP device whose other end is a small Python process (``python -m harness.netem
  _forward``) that applies the same enqueue rule as netem (the formula above, the
  same loss draw, the same limit) and writes each frame, when due, into the peer
  namespace's TAP, whose ingress is redirected into the peer veth as if received on
  it. Its timing is the process's wake-up (select(2)): a fixed 5 ms or 40 ms delay
  came out 0.15 ms late a direction (median; 2-core VM at load ~2), more under heavy
  load; it runs at nice −10, as do the measuring helpers below.

``lan`` installs nothing: the bare veth, which is what bench.force_under_video shapes
with its own HTB classes (the pair leaves the root qdisc to its user until a shaped
profile is applied). ``down()`` (and ``outage()``/``link_down()``) drops every packet
both ways from that moment (netem's ``loss 100%``; packets already delayed still
arrive, as on a cut cable past the cut) until ``up()`` restores the profile.

Namespaces are named ``trnetem-<pid>-<n>-srv``/``-cli`` (two runs on one machine never
collide), removed on ``close()``/leaving the ``with`` block, also on an exception; a
later pair removes those a killed process left behind (their pid gone).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import itertools
import json
import math
import os
import random
import select
import shutil
import struct
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

REPO = Path(__file__).resolve().parents[1]
NS_PREFIX = "trnetem"
SERVER_DEV, CLIENT_DEV = "trb0", "trb1"  # the veth ends (each in its own namespace)
SERVER_TAP, CLIENT_TAP = "trt0", "trt1"  # the forwarder's TAPs (likewise)
UNLIMITED_RATE_MBIT = 10_000.0  # what an unlimited shaped profile's netem ``rate`` is
Backend = Literal["netem", "forwarder"]


# ---------------------------------------------------------------- profiles
@dataclass(frozen=True)
class Profile:
    """A link, each direction: ``delay_ms`` ONE-WAY (a round trip is twice it),
    ``jitter_ms`` the σ of a normal spread around it, ``loss_pct`` random loss,
    ``rate_mbit`` the cap (None: unlimited), ``limit_packets`` what it holds."""

    name: str
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    loss_pct: float = 0.0
    rate_mbit: float | None = None
    limit_packets: int = 1000

    @property
    def shaped(self) -> bool:
        """Whether anything is installed for it (``lan`` is the bare veth)."""
        return bool(self.delay_ms or self.jitter_ms or self.loss_pct or self.rate_mbit)

    def cut(self) -> Profile:
        """The same link, cut: every packet lost."""
        return dataclasses.replace(self, name=f"{self.name} (down)", loss_pct=100.0)


PROFILES: dict[str, Profile] = {
    p.name: p
    for p in (
        Profile("lan"),
        Profile("wifi", delay_ms=5, jitter_ms=3, loss_pct=0.5),
        Profile("wan", delay_ms=40, jitter_ms=10, loss_pct=1, rate_mbit=20),
        Profile("mobile", delay_ms=80, jitter_ms=30, loss_pct=2, rate_mbit=4),
        Profile("bad", delay_ms=150, jitter_ms=50, loss_pct=5, rate_mbit=2),
    )
}


def profile_named(profile: Profile | str) -> Profile:
    if isinstance(profile, Profile):
        return profile
    try:
        return PROFILES[profile]
    except KeyError:
        raise ValueError(f"no link profile {profile!r}; there are {sorted(PROFILES)}") from None


# ---------------------------------------------------------------- what this machine allows
class LinkEmulatorError(RuntimeError):
    """A command the emulator needs failed (the message has its output)."""


def _run(argv: Sequence[str], check: bool = True) -> subprocess.CompletedProcess[str]:
    out = subprocess.run(list(argv), capture_output=True, text=True, timeout=30)
    if check and out.returncode != 0:
        raise LinkEmulatorError(f"`{' '.join(argv)}` failed: {out.stderr.strip()}")
    return out


_counter = itertools.count(1)


def _unique_name() -> str:
    return f"{NS_PREFIX}-{os.getpid()}-{next(_counter)}"


@contextlib.contextmanager
def _scratch_ns() -> Iterator[str]:
    name = f"{_unique_name()}-probe"
    _run(["ip", "netns", "add", name])
    try:
        yield name
    finally:
        _run(["ip", "netns", "del", name], check=False)


@functools.cache
def netns_available() -> str | None:
    """Why network namespaces cannot be made here, or None if they can."""
    if os.geteuid() != 0:
        return "not root (network namespaces and tc need CAP_NET_ADMIN)"
    for tool in ("ip", "tc"):
        if shutil.which(tool) is None:
            return f"no `{tool}` command (iproute2)"
    try:
        with _scratch_ns() as ns:
            _run(["ip", "-n", ns, "link", "add", "trp0", "type", "veth", "peer", "trp1"])
    except (LinkEmulatorError, OSError, subprocess.TimeoutExpired) as e:
        return f"the kernel refused a namespace with a veth pair: {e}"
    return None


@functools.cache
def netem_available() -> str | None:
    """Why the kernel's netem qdisc cannot be used here, or None if it can."""
    if (why := netns_available()) is not None:
        return why
    try:
        with _scratch_ns() as ns:
            _run(["tc", "-n", ns, "qdisc", "add", "dev", "lo", "root", "netem", "delay", "1ms"])
    except LinkEmulatorError as e:
        return f"no netem qdisc in this kernel (CONFIG_NET_SCH_NETEM): {e}"
    return None


@functools.cache
def forwarder_available() -> str | None:
    """Why the user-space forwarder (TAP + clsact/u32/mirred) cannot run, or None."""
    if (why := netns_available()) is not None:
        return why
    if not os.path.exists("/dev/net/tun"):
        return "no /dev/net/tun"
    try:
        with _scratch_ns() as ns:
            _run(["ip", "-n", ns, "tuntap", "add", "dev", "trp0", "mode", "tap"])
            _run(["tc", "-n", ns, "qdisc", "add", "dev", "trp0", "clsact"])
            _run(["tc", "-n", ns, "filter", "add", "dev", "trp0", "ingress", *_REDIRECT_ALL,
                  "ingress", "redirect", "dev", "lo"])  # fmt: skip
    except LinkEmulatorError as e:
        return f"no TAP redirect (clsact, u32, mirred) in this kernel: {e}"
    return None


def emulator_available() -> str | None:
    """Why no shaped profile can be applied here (neither backend), or None."""
    if (why := netns_available()) is not None:
        return why
    if netem_available() is None or forwarder_available() is None:
        return None
    return f"{netem_available()}; and {forwarder_available()}"


def _remove_orphans() -> None:
    """Namespaces an earlier, killed run left behind (its pid is gone)."""
    try:
        names = os.listdir("/run/netns")
    except OSError:
        return
    for name in names:
        parts = name.split("-")
        mine = len(parts) >= 3 and parts[0] == NS_PREFIX and parts[1].isdigit()
        if mine and not os.path.exists(f"/proc/{parts[1]}"):
            _run(["ip", "netns", "del", name], check=False)


# ---------------------------------------------------------------- the pair
_REDIRECT_ALL = ("protocol", "all", "prio", "1", "u32", "match", "u32", "0", "0",
                 "action", "mirred")  # fmt: skip


class NetemPair:
    """Two network namespaces (server, client) joined by a veth pair, shaped by a
    profile on both ends' egress. A context manager; ``open()``/``close()`` otherwise."""

    def __init__(
        self,
        profile: Profile | str = "lan",
        *,
        backend: Backend | Literal["auto"] = "auto",
        server_addr: str = "10.231.0.1",
        client_addr: str = "10.231.0.2",
        prefix_len: int = 24,
    ) -> None:
        base = _unique_name()
        self.server_ns, self.client_ns = f"{base}-srv", f"{base}-cli"
        self.server_dev, self.client_dev = SERVER_DEV, CLIENT_DEV
        self.server_addr, self.client_addr = server_addr, client_addr
        self.prefix_len = prefix_len
        self._wanted_backend = backend
        self._backend: Backend | None = None
        self._profile = profile_named(profile)
        self._installed: Profile | None = None  # what the link does now (None: bare veth)
        self._down = False
        self._forwarder: subprocess.Popen[str] | None = None
        self._redirecting = False
        self._open = False

    # -- the namespaces and where to run things
    @property
    def server_prefix(self) -> tuple[str, ...]:
        """argv prefix running a command in the server's namespace."""
        return ("ip", "netns", "exec", self.server_ns)

    @property
    def client_prefix(self) -> tuple[str, ...]:
        """argv prefix running a command in the client's namespace."""
        return ("ip", "netns", "exec", self.client_ns)

    def client_executable(self, program: str, directory: str) -> str:
        """An executable script in ``directory`` that runs ``program`` (with its
        arguments) in the client's namespace: for a caller that takes the path of a
        program, not a command line (Playwright's ``executable_path``: a browser behind
        the emulated link; Playwright drives it over pipes, which the namespace keeps)."""
        path = os.path.join(directory, f"in-{self.client_ns}-{os.path.basename(program)}")
        with open(path, "w") as f:
            f.write(f'#!/bin/sh\nexec {" ".join(self.client_prefix)} {program} "$@"\n')
        os.chmod(path, 0o755)
        return path

    @property
    def profile(self) -> Profile:
        """The profile applied (also while the link is down)."""
        return self._profile

    @property
    def is_down(self) -> bool:
        return self._down

    @property
    def backend(self) -> Backend | None:
        """``netem`` or ``forwarder``, once a shaped profile (or ``down()``) needed one."""
        return self._backend

    def __enter__(self) -> NetemPair:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        if self._open:
            return
        if (why := netns_available()) is not None:
            raise LinkEmulatorError(why)
        _remove_orphans()
        self._open = True
        try:
            _run(["ip", "netns", "add", self.server_ns])
            _run(["ip", "netns", "add", self.client_ns])
            _run(["ip", "link", "add", self.server_dev, "netns", self.server_ns, "type", "veth",
                  "peer", self.client_dev, "netns", self.client_ns])  # fmt: skip
            for ns, dev, addr in (
                (self.server_ns, self.server_dev, self.server_addr),
                (self.client_ns, self.client_dev, self.client_addr),
            ):
                _run(["ip", "-n", ns, "addr", "add", f"{addr}/{self.prefix_len}", "dev", dev])
                _run(["ip", "-n", ns, "link", "set", dev, "up"])
                _run(["ip", "-n", ns, "link", "set", "lo", "up"])
            self._install()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop the forwarder, remove both namespaces (and with them the veth pair)."""
        if self._forwarder is not None:
            proc, self._forwarder = self._forwarder, None
            with contextlib.suppress(OSError):
                assert proc.stdin is not None
                proc.stdin.close()  # its signal to exit
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
        if self._open:
            for ns in (self.server_ns, self.client_ns):
                _run(["ip", "netns", "del", ns], check=False)
        self._open = False
        self._installed = None
        self._redirecting = False

    # -- profiles and outages
    def apply(self, profile: Profile | str) -> None:
        """Shape both directions by ``profile`` (a name in PROFILES or a Profile). While
        the link is down it stays down; the profile takes over at ``up()``."""
        self._profile = profile_named(profile)
        if self._open:
            self._install()

    def down(self) -> None:
        """Cut the link: every packet either way is lost until ``up()``."""
        self._down = True
        if self._open:
            self._install()

    def up(self) -> None:
        """Restore the profile after ``down()``."""
        self._down = False
        if self._open:
            self._install()

    @contextlib.contextmanager
    def outage(self) -> Iterator[None]:
        """The link is down inside the ``with`` block, restored after (also on errors)."""
        self.down()
        try:
            yield
        finally:
            self.up()

    def link_down(self, seconds: float) -> None:
        """Drop the link completely for ``seconds``, then restore the profile (blocks)."""
        with self.outage():
            time.sleep(seconds)

    # -- the backends
    def _choose_backend(self) -> Backend:
        if self._backend is not None:
            return self._backend
        wanted = self._wanted_backend
        why_netem = netem_available() if wanted in ("auto", "netem") else "not asked for"
        if why_netem is None:
            self._backend = "netem"
        elif wanted == "netem":
            raise LinkEmulatorError(why_netem)
        elif (why_forwarder := forwarder_available()) is None:
            self._backend = "forwarder"
        else:
            raise LinkEmulatorError(f"no link emulator here: {why_netem}; {why_forwarder}")
        return self._backend

    def _install(self) -> None:
        wanted = self._profile.cut() if self._down else self._profile
        target = wanted if wanted.shaped else None
        if target == self._installed:
            return
        if target is None and self._backend is None:
            self._installed = None  # nothing was ever installed
            return
        if self._choose_backend() == "netem":
            self._install_netem(target)
        else:
            self._install_forwarder(target)
        self._installed = target

    def _ends(self) -> tuple[tuple[str, str], tuple[str, str]]:
        return ((self.server_ns, self.server_dev), (self.client_ns, self.client_dev))

    def _install_netem(self, p: Profile | None) -> None:
        for ns, dev in self._ends():
            if p is None:
                _run(["tc", "-n", ns, "qdisc", "del", "dev", dev, "root"], check=False)
                _run(["ip", "-n", ns, "link", "set", dev, "gso_max_segs", "65535"])
                continue
            _run(["ip", "-n", ns, "link", "set", dev, "gso_max_segs", "1"])
            _run(["tc", "-n", ns, "qdisc", "replace", "dev", dev, "root", *netem_args(p)])

    def _install_forwarder(self, p: Profile | None) -> None:
        if p is None:
            if self._redirecting:
                for ns, dev in self._ends():
                    _run(["tc", "-n", ns, "qdisc", "del", "dev", dev, "clsact"], check=False)
                self._redirecting = False
            return
        self._forwarder_command(json.dumps(dataclasses.asdict(p)))
        if not self._redirecting:
            for (ns, dev), tap in zip(self._ends(), (SERVER_TAP, CLIENT_TAP), strict=True):
                _run(["tc", "-n", ns, "qdisc", "add", "dev", dev, "clsact"])
                _run(["tc", "-n", ns, "filter", "add", "dev", dev, "egress", *_REDIRECT_ALL,
                      "egress", "redirect", "dev", tap])  # fmt: skip
            self._redirecting = True

    @property
    def forwarder_pid(self) -> int | None:
        """The user-space forwarder's process id while it runs (forwarder backend)."""
        return self._forwarder.pid if self._forwarder is not None else None

    def forwarder_counters(self) -> dict[str, dict[str, int]] | None:
        """The forwarder's own counts per direction (frames in, lost, over the limit,
        out), or None with the netem backend or before the forwarder started."""
        if self._forwarder is None:
            return None
        result: dict[str, dict[str, int]] = json.loads(self._forwarder_command("stats"))
        return result

    def _forwarder_command(self, line: str) -> str:
        if self._forwarder is None:
            self._start_forwarder()
        proc = self._forwarder
        assert proc is not None and proc.stdin is not None and proc.stdout is not None
        proc.stdin.write(line + "\n")
        proc.stdin.flush()
        answer = proc.stdout.readline()
        if not answer:
            raise LinkEmulatorError(f"the forwarder exited: {proc.stderr and proc.stderr.read()}")
        return answer

    def _start_forwarder(self) -> None:
        proc = subprocess.Popen(
            [*self.server_prefix, sys.executable, "-m", "harness.netem", "_forward",
             SERVER_TAP, CLIENT_TAP],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        self._forwarder = proc
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != "ready":
            proc.wait(timeout=5)
            why = proc.stderr.read() if proc.stderr else ""
            raise LinkEmulatorError(f"the forwarder did not start: {why}")
        # Both TAPs were made in the server's namespace; the client's moves to its own.
        # Each takes its veth's MAC address, so a frame written into it is for this host.
        _run(["ip", "-n", self.server_ns, "link", "set", CLIENT_TAP, "netns", self.client_ns])
        for (ns, dev), tap in zip(self._ends(), (SERVER_TAP, CLIENT_TAP), strict=True):
            mac = json.loads(_run(["ip", "-j", "-n", ns, "link", "show", dev]).stdout)[0]["address"]
            _run(["ip", "-n", ns, "link", "set", tap, "address", mac, "addrgenmode", "none"])
            _run(["ip", "-n", ns, "link", "set", tap, "up"])
            _run(["tc", "-n", ns, "qdisc", "add", "dev", tap, "clsact"])
            _run(["tc", "-n", ns, "filter", "add", "dev", tap, "ingress", *_REDIRECT_ALL,
                  "ingress", "redirect", "dev", dev])  # fmt: skip


def _tc_ms(value: float) -> str:
    return f"{value:g}ms"


def netem_args(p: Profile) -> list[str]:
    """The ``netem …`` arguments for a profile (the netem backend's qdisc)."""
    args = ["netem", "limit", str(p.limit_packets), "delay", _tc_ms(p.delay_ms)]
    if p.jitter_ms:
        args += [_tc_ms(p.jitter_ms), "distribution", "normal"]
    if p.loss_pct:
        args += ["loss", "random", f"{p.loss_pct:g}%"]
    # A rate always: it is what keeps jittered packets in order (see the module's notes).
    args += ["rate", f"{p.rate_mbit or UNLIMITED_RATE_MBIT:g}mbit"]
    return args


# ---------------------------------------------------------------- the user-space forwarder
class _Direction:
    """One direction of the forwarder: netem's enqueue rule (delay drawn from a normal
    distribution, random loss, the limit, the rate measured from the last packet held)
    on a FIFO of (time to send, frame)."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.held: deque[tuple[float, bytes]] = deque()
        self.set(Profile("lan"))
        self.counts = {"in": 0, "lost": 0, "over_limit": 0, "out": 0,
                       "late_over_5ms": 0, "late_max_us": 0, "assigned_over_250ms": 0}  # fmt: skip

    def set(self, p: Profile) -> None:
        self.delay, self.jitter = p.delay_ms / 1000, p.jitter_ms / 1000
        self.loss = p.loss_pct / 100
        self.rate_bps = (p.rate_mbit or UNLIMITED_RATE_MBIT) * 1e6
        self.limit = p.limit_packets

    def enqueue(self, frame: bytes, now: float) -> None:
        self.counts["in"] += 1
        if self.loss and (self.loss >= 1 or self.rng.random() < self.loss):
            self.counts["lost"] += 1
            return
        if len(self.held) >= self.limit:
            self.counts["over_limit"] += 1
            return
        delay = self.delay
        if self.jitter:  # netem's normal table spans about ±4σ
            delay += self.jitter * max(-4.0, min(4.0, self.rng.gauss(0.0, 1.0)))
        send_at = now + max(0.0, delay)
        if self.held:  # the last packet held is the reference: never before it
            send_at = max(send_at, self.held[-1][0])
        send_at += len(frame) * 8 / self.rate_bps
        if send_at - now > 0.25:  # the rule's own queueing, not the machine's
            self.counts["assigned_over_250ms"] += 1
        self.held.append((send_at, frame))

    def released(self, due: float, now: float) -> None:
        """Count a frame sent later than due: the forwarder starved of CPU, which a real
        link is not (so a figure measured while this grows is the machine's)."""
        self.counts["out"] += 1
        late = now - due
        if late > 0.005:
            self.counts["late_over_5ms"] += 1
        self.counts["late_max_us"] = max(self.counts["late_max_us"], int(late * 1e6))


def _open_tap(name: str) -> int:
    import fcntl

    tunsetiff, iff_tap, iff_no_pi = 0x400454CA, 0x0002, 0x1000
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, tunsetiff, struct.pack("16sH", name.encode(), iff_tap | iff_no_pi))
    return fd


def forward(server_tap: str, client_tap: str) -> None:
    """The forwarder process: frames the server's TAP receives (its veth's egress) go,
    when due, into the client's TAP, and the other way round. Commands on stdin, one a
    line (a Profile as JSON: both directions take it; ``stats``: the counters), each
    answered by a line; EOF on stdin ends it."""
    with contextlib.suppress(OSError):
        os.nice(-10)
    rng = random.Random()
    taps = (_open_tap(server_tap), _open_tap(client_tap))
    up, down = _Direction(rng), _Direction(rng)  # server → client, client → server
    routes = ((taps[0], up, taps[1]), (taps[1], down, taps[0]))
    control = sys.stdin.fileno()
    print("ready", flush=True)
    buffered = b""
    while True:
        heads = [d.held[0][0] for _, d, _ in routes if d.held]
        timeout = max(0.0, min(heads) - time.monotonic()) if heads else None
        ready, _, _ = select.select([taps[0], taps[1], control], [], [], timeout)
        now = time.monotonic()
        for src, direction, _ in routes:
            if src in ready:
                while True:
                    try:
                        frame = os.read(src, 65536)
                    except BlockingIOError:
                        break
                    direction.enqueue(frame, now)
        for _, direction, dst in routes:
            held = direction.held
            while held and held[0][0] <= now:
                due, frame = held.popleft()
                with contextlib.suppress(OSError):
                    os.write(dst, frame)
                    direction.released(due, now)
        if control in ready:
            chunk = os.read(control, 65536)
            if not chunk:
                return
            buffered += chunk
            while b"\n" in buffered:
                line, buffered = buffered.split(b"\n", 1)
                if line.strip() == b"stats":
                    print(json.dumps({"server_to_client": up.counts,
                                      "client_to_server": down.counts}), flush=True)  # fmt: skip
                else:
                    profile = Profile(**json.loads(line))
                    up.set(profile)
                    down.set(profile)
                    print("ok", flush=True)


# ---------------------------------------------------------------- measuring the link
PROBE = struct.Struct("!Id")  # seq, the client's send time (CLOCK_MONOTONIC, shared)
ECHO = struct.Struct("!Idd")  # + the server's receive time


def echo(addr: str) -> None:
    """Run in the server's namespace: answer every probe with its receive time; print
    the port, then, when stdin closes, what arrived (JSON: [[seq, receive time], …])."""
    sock = _udp_socket()
    sock.bind((addr, 0))
    print(sock.getsockname()[1], flush=True)
    seen: list[tuple[int, float]] = []
    control = sys.stdin.fileno()
    while True:
        ready, _, _ = select.select([sock, control], [], [])
        if sock in ready:
            data, peer = sock.recvfrom(2048)
            now = time.monotonic()
            seq, sent = PROBE.unpack_from(data)
            seen.append((seq, now))
            sock.sendto(ECHO.pack(seq, sent, now) + data[ECHO.size :], peer)
        if control in ready and not os.read(control, 4096):
            print(json.dumps(seen), flush=True)
            return


def probe(addr: str, port: int, count: int, interval_s: float, size: int, wait_s: float) -> None:
    """Run in the client's namespace: ``count`` probes every ``interval_s``, then wait
    ``wait_s`` for the last answers; print JSON [[seq, sent, echoed, received], …] of the
    answers and the send times of all."""
    sock = _udp_socket()
    sock.connect((addr, port))
    sent: list[float] = []
    answers: list[tuple[int, float, float, float]] = []
    pad = bytes(max(0, size - PROBE.size))
    print("sending", flush=True)
    start = time.monotonic() + 0.01
    end = start + count * interval_s + wait_s
    while True:
        now = time.monotonic()
        due = start + len(sent) * interval_s if len(sent) < count else end
        if now >= due:
            if len(sent) >= count:
                break
            with contextlib.suppress(ConnectionRefusedError):  # an ICMP error, answered late
                sock.send(PROBE.pack(len(sent), now) + pad)
            sent.append(now)
            continue
        ready, _, _ = select.select([sock], [], [], due - now)
        if ready:
            with contextlib.suppress(ConnectionRefusedError):
                data = sock.recv(2048)
                answers.append((*ECHO.unpack_from(data), time.monotonic()))
    print(json.dumps({"sent": sent, "answers": answers}), flush=True)


def _udp_socket() -> Any:
    """A UDP socket for a measuring process, which also runs at nice −10 (as root) like
    the forwarder: on a loaded machine its wake-ups would otherwise be the measurement."""
    import socket

    with contextlib.suppress(OSError):
        os.nice(-10)

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    return sock


@dataclass(frozen=True)
class LinkMeasurement:
    """What ``measure_link`` saw. Delays in ms; one-way delays are real (both ends read
    the same CLOCK_MONOTONIC); losses as shares (0.02 = 2 %)."""

    probes: int
    interval_ms: float
    rtt_p50_ms: float
    rtt_p90_ms: float
    up_p50_ms: float  # client → server
    down_p50_ms: float  # server → client
    loss_up: float
    loss_down: float
    loss_round_trip: float
    reordered: float  # share of probes the server got after a later one
    sent: list[float] = dataclasses.field(repr=False, default_factory=list)
    answered: dict[int, tuple[float, float, float]] = dataclasses.field(
        repr=False, default_factory=dict
    )  # seq -> (sent, echoed, received)
    echoed_at: dict[int, float] = dataclasses.field(repr=False, default_factory=dict)

    def figures(self) -> dict[str, float]:
        """The summary (no per-probe records), for JSON."""
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name not in ("sent", "answered", "echoed_at")
        }


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    v = sorted(values)
    return v[min(len(v) - 1, max(0, math.ceil(q / 100 * len(v)) - 1))]


def _helper(prefix: Sequence[str], *args: str) -> list[str]:
    return [*prefix, sys.executable, "-m", "harness.netem", *args]


def measure_link(
    pair: NetemPair,
    *,
    probes: int = 500,
    interval_s: float = 0.01,
    size: int = 64,
    wait_s: float | None = None,
    started: Callable[[], object] | None = None,
) -> LinkMeasurement:
    """Measure the link instead of assuming it: ``probes`` UDP datagrams of ``size``
    bytes every ``interval_s`` from a process in the client's namespace to an echo
    process in the server's. Mind the spacing: probes closer than the jitter are
    held behind each other (the link is a FIFO) and see more than the profile's delay.
    Blocks for about probes × interval + ``wait_s`` (default: 4 × the profile's
    worst one-way delay, at least 0.5 s). ``started`` is called (in this thread) once
    the first probe is about to go, for callers that act on the link meanwhile."""
    p = pair.profile
    if wait_s is None:
        wait_s = max(0.5, 4 * (p.delay_ms + 4 * p.jitter_ms) / 1000)
    server = subprocess.Popen(
        _helper(pair.server_prefix, "_echo", pair.server_addr),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO,
    )  # fmt: skip
    try:
        assert server.stdout is not None and server.stdin is not None
        port = server.stdout.readline().strip()
        if not port:
            raise LinkEmulatorError("the echo process did not start")
        client = subprocess.Popen(
            _helper(pair.client_prefix, "_probe", pair.server_addr, port, str(probes),
                    str(interval_s), str(size), str(wait_s)),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
        )  # fmt: skip
        assert client.stdout is not None
        if client.stdout.readline().strip() == "sending" and started is not None:
            started()
        out, err = client.communicate(timeout=probes * interval_s + wait_s + 30)
        if client.returncode != 0:
            raise LinkEmulatorError(f"the probe failed: {err[-2000:]}")
        server.stdin.close()
        echoed: list[list[float]] = json.loads(server.stdout.readline())
        server.wait(timeout=10)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
    result = json.loads(out)
    sent: list[float] = result["sent"]
    answered = {int(a[0]): (a[1], a[2], a[3]) for a in result["answers"]}
    echoed_at = {int(seq): t for seq, t in echoed}
    later = 0
    highest = -1
    for seq, _ in echoed:
        if seq < highest:
            later += 1
        highest = max(highest, int(seq))
    n_up = len(echoed_at)
    return LinkMeasurement(
        probes=len(sent),
        interval_ms=interval_s * 1000,
        rtt_p50_ms=_percentile([(r - s) * 1000 for s, _, r in answered.values()], 50),
        rtt_p90_ms=_percentile([(r - s) * 1000 for s, _, r in answered.values()], 90),
        up_p50_ms=_percentile([(echoed_at[q] - sent[q]) * 1000 for q in echoed_at], 50),
        down_p50_ms=_percentile([(r - e) * 1000 for _, e, r in answered.values()], 50),
        loss_up=1 - n_up / len(sent) if sent else math.nan,
        loss_down=1 - len(answered) / n_up if n_up else math.nan,
        loss_round_trip=1 - len(answered) / len(sent) if sent else math.nan,
        reordered=later / n_up if n_up else math.nan,
        sent=sent,
        answered=answered,
        echoed_at=echoed_at,
    )


# ---------------------------------------------------------------- throughput
def sink(addr: str, port: int, idle_s: float) -> None:
    """Run in one namespace: count UDP bytes until ``idle_s`` without any (after the
    first); print JSON {packets, bytes, first, last} (arrival times, CLOCK_MONOTONIC)."""
    sock = _udp_socket()
    sock.bind((addr, port))
    print("ready", flush=True)
    packets = size = 0
    first = last = math.nan
    while True:
        ready, _, _ = select.select([sock], [], [], idle_s if packets else 30.0)
        if not ready:
            break
        n = len(sock.recv(65536))
        last = time.monotonic()
        if not packets:
            first = last
        else:
            size += n  # the bytes after the first packet, over the time after it
        packets += 1
    print(json.dumps({"packets": packets, "bytes": size, "first": first, "last": last}))


def blast(addr: str, port: int, mbit: float, seconds: float, size: int) -> None:
    """Run in the other namespace: UDP datagrams of ``size`` bytes paced at ``mbit``."""
    sock = _udp_socket()
    payload = bytes(size)
    gap = size * 8 / (mbit * 1e6)
    start = time.monotonic()
    n = 0
    while (now := time.monotonic()) < start + seconds:
        due = start + n * gap
        if now < due:
            time.sleep(due - now)
        with contextlib.suppress(OSError):
            sock.sendto(payload, (addr, port))
        n += 1
    print(json.dumps({"packets": n, "seconds": time.monotonic() - start}))


@dataclass(frozen=True)
class RateMeasurement:
    offered_mbit: float
    sent_mbit: float  # UDP payload the sender managed (a loaded machine may fall short)
    received_mbit: float  # UDP payload over the arrival span
    frame_mbit: float  # the same counted as Ethernet frames (what a rate limit counts)
    sent_packets: int
    received_packets: int
    arrival_s: float  # from the first datagram's arrival to the last's


UDP_FRAME_OVERHEAD = 14 + 20 + 8  # Ethernet, IPv4, UDP headers


def measure_rate(
    pair: NetemPair,
    *,
    offered_mbit: float,
    seconds: float = 1.5,
    size: int = 1472,
    upstream: bool = True,
    port: int = 5201,
) -> RateMeasurement:
    """Offer ``offered_mbit`` of UDP for ``seconds`` (client → server when ``upstream``)
    and measure what arrives: bytes after the first datagram over the time after it."""
    rx, tx, addr = (
        (pair.server_prefix, pair.client_prefix, pair.server_addr)
        if upstream
        else (pair.client_prefix, pair.server_prefix, pair.client_addr)
    )
    receiver = subprocess.Popen(
        _helper(rx, "_sink", addr, str(port), "0.3"), stdout=subprocess.PIPE, text=True, cwd=REPO
    )
    try:
        assert receiver.stdout is not None
        if receiver.stdout.readline().strip() != "ready":
            raise LinkEmulatorError("the sink did not start")
        sender = subprocess.run(
            _helper(tx, "_blast", addr, str(port), str(offered_mbit), str(seconds), str(size)),
            capture_output=True, text=True, cwd=REPO, timeout=seconds + 30,
        )  # fmt: skip
        if sender.returncode != 0:
            raise LinkEmulatorError(f"the sender failed: {sender.stderr[-2000:]}")
        got = json.loads(receiver.stdout.readline())
        receiver.wait(timeout=10)
    finally:
        if receiver.poll() is None:
            receiver.kill()
            receiver.wait()
    span = got["last"] - got["first"]
    sent = json.loads(sender.stdout)
    mbit = got["bytes"] * 8 / span / 1e6 if span > 0 else math.nan
    return RateMeasurement(
        offered_mbit=offered_mbit,
        sent_mbit=sent["packets"] * size * 8 / sent["seconds"] / 1e6,
        received_mbit=mbit,
        frame_mbit=mbit * (size + UDP_FRAME_OVERHEAD) / size,
        sent_packets=sent["packets"],
        received_packets=got["packets"],
        arrival_s=span,
    )


def probe_interval_s(p: Profile) -> float:
    """A spacing at which a probe rarely waits behind the one before (≈ 1.5 σ of jitter)."""
    return max(0.005, 1.5 * p.jitter_ms / 1000)


if __name__ == "__main__":
    command, rest = (sys.argv[1], sys.argv[2:]) if len(sys.argv) > 1 else ("", [])
    if command == "_forward":
        forward(*rest)
    elif command == "_echo":
        echo(rest[0])
    elif command == "_probe":
        probe(rest[0], int(rest[1]), int(rest[2]), float(rest[3]), int(rest[4]), float(rest[5]))
    elif command == "_sink":
        sink(rest[0], int(rest[1]), float(rest[2]))
    elif command == "_blast":
        blast(rest[0], int(rest[1]), float(rest[2]), float(rest[3]), int(rest[4]))
    else:  # only the emulator's own helper processes start it
        raise SystemExit("harness.netem runs its helpers only; its figures: python -m bench.netem")
