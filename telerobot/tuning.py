"""Process settings for the 1 kHz paths, shared by the server and the master-arm
bridge (a leaf module: importing it pulls in neither)."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import os
import shutil
import sys
import threading
from collections.abc import Iterator

log = logging.getLogger(__name__)

STARTED_NICENESS = "TELEROBOT_STARTED_NICENESS"  # the server's, before it raised it


def tune_for_realtime() -> None:
    """Settings that keep the 1 kHz paths on time (measured in bench/command_latency):
    uvloop's faster event loop, a shorter GIL switch interval so the sensor thread
    and the event loop hand over quickly, and no collection pauses of objects made
    at start-up."""
    try:
        import uvloop

        asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())
    except ImportError:  # optional: plain asyncio works, a little slower
        pass
    sys.setswitchinterval(0.0005)
    gc.collect()
    gc.freeze()


def raise_cpu_priority(steps: int) -> str:
    """Lower this process's niceness by ``steps`` (before its threads start: they
    inherit it), if the system lets it. Says what it did, for the log.

    Why: on a machine shared with other programs (a 2-core box, an attacker's local
    processes, a test suite), the scheduler gave the server's event loop slices after
    theirs, and the REST e-stop waited up to 30–40 ms behind them (bench.abuse);
    the same stalls cost forces and dead-man heartbeats."""
    before = os.getpriority(os.PRIO_PROCESS, 0)
    # Its helper processes inherit this, and take their niceness from how the server
    # was started, not from its raised priority (``yield_cpu``).
    os.environ[STARTED_NICENESS] = str(before)
    if steps <= 0:
        return "CPU priority as started (cpu_priority 0)"
    try:
        os.setpriority(os.PRIO_PROCESS, 0, max(-20, before - steps))
    except OSError:
        return (
            f"CPU priority as started (niceness {before}): raising it needs root or"
            " CAP_SYS_NICE (e.g. systemd's Nice=-5, or setcap cap_sys_nice+ep on the"
            " Python binary); set cpu_priority 0 to silence this"
        )
    return f"CPU priority raised: niceness {before} → {os.getpriority(os.PRIO_PROCESS, 0)}"


def raise_thread_priority(steps: int) -> int:
    """Lower the calling thread's niceness by ``steps`` if the system lets it (on Linux
    niceness is per thread: the threads it starts from now inherit it, the ones already
    running and the processes already started keep theirs). Returns the niceness now."""
    now = os.getpriority(os.PRIO_PROCESS, 0)
    if steps > 0:
        with contextlib.suppress(OSError):  # not root nor CAP_SYS_NICE: as started
            os.setpriority(os.PRIO_PROCESS, 0, max(-20, now - steps))
    return os.getpriority(os.PRIO_PROCESS, 0)


@contextlib.contextmanager
def thread_priority_raised(steps: int) -> Iterator[int]:
    """``raise_thread_priority`` for a block, the calling thread's niceness restored
    after it (the threads started inside keep the raised one)."""
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        yield raise_thread_priority(steps)
    finally:
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, before)


SLICE_US = 100  # the scheduler's shortest slice a thread may ask for (Linux ≥ 6.12: 0.1 ms)
_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}


def short_slice(us: int | None = None) -> bool:
    """Ask the kernel to run the calling thread in short slices (EEVDF's custom slice,
    Linux ≥ 6.12; ``sched_setattr`` with ``sched_runtime``, its niceness kept): a thread
    that wakes for a force sample then preempts a longer-sliced one at once, where
    otherwise the running thread (the video encoder's) may finish its slice first. No
    rights are needed; elsewhere it does nothing. Threads and processes started from
    this thread inherit it (``yield_cpu`` gives helpers the default back).
    ``TELEROBOT_SLICE_US`` overrides the length (0: leave the default). Returns whether
    the kernel took it."""
    us = int(os.environ.get("TELEROBOT_SLICE_US", SLICE_US)) if us is None else us
    return us > 0 and _set_slice(us * 1000)


RT_PRIORITY = 10  # SCHED_FIFO priority of the 1 kHz threads (1–99: above every ordinary
# thread, below the kernel's own interrupt threads at 50)
_SCHED_FIFO = 1
_SCHED_FLAG_RESET_ON_FORK = 0x01


# What each 1 kHz thread got, by thread name (the newest of a name): the server says it at
# start and in GET /api/v1/health (docs/running.md, "Realtime"). Bounded: one entry a
# thread name, and the names are the code's.
_GOT: dict[str, str] = {}
_GOT_LOCK = threading.Lock()
ORDINARY = "ordinary"
# EEVDF's default slice is 0.75 ms × (1 + log2 CPUs) (1.4 ms on 2 cores): a slice below
# the least default is one a thread asked for and got.
SHORTEST_DEFAULT_SLICE_NS = 750_000


def prompt_thread() -> str:
    """Run the calling thread (a 1 kHz loop, woken per sample) ahead of ordinary threads:
    SCHED_FIFO at ``RT_PRIORITY`` where the system lets it (root, CAP_SYS_NICE or an
    ``RLIMIT_RTPRIO``), with reset-on-fork so the processes it starts are ordinary
    again; otherwise in short slices (``short_slice``). ``TELEROBOT_RT_PRIORITY``
    overrides the priority (0: never realtime). Returns what it got, for the log.

    Why: with short slices a woken force thread still waited for the video encoder's
    thread to be preempted, and a p99 of 0.45 ms against 0.14 ms without video was the
    result on 2 cores (bench.force_under_video); a realtime thread preempts at once.
    Each wakes for microseconds a millisecond, so the others lose nothing they notice."""
    priority = int(os.environ.get("TELEROBOT_RT_PRIORITY", RT_PRIORITY))
    if priority > 0:
        _set_attr(_SCHED_FIFO, _SCHED_FLAG_RESET_ON_FORK, 0, min(99, priority), 0)
    got = applied_scheduling()
    if not got.startswith("realtime"):
        short_slice()
        got = applied_scheduling()
    with _GOT_LOCK:
        _GOT[threading.current_thread().name] = got
    return got


def applied_scheduling(tid: int | None = None) -> str:
    """What the kernel applied to a thread of this process (the calling one by
    default), read back from ``/proc/self/task/<tid>/sched``, not what was asked:
    ``realtime (SCHED_FIFO n)``, ``short slices (0.1 ms)`` or ``ordinary`` (where the
    file says neither, or there is none: not Linux)."""
    tid = threading.get_native_id() if tid is None else tid
    try:
        with open(f"/proc/self/task/{tid}/sched") as f:
            text = f.read()
    except OSError:
        return ORDINARY
    fields = {}
    for line in text.splitlines():
        name, sep, value = line.partition(":")
        if sep:
            fields[name.strip()] = value.strip()
    policy, prio = fields.get("policy"), fields.get("prio")
    if policy == str(_SCHED_FIFO) and prio is not None and prio.lstrip("-").isdigit():
        return f"realtime (SCHED_FIFO {99 - int(prio)})"  # the kernel's prio: 99 − priority
    slice_ns = fields.get("se.slice")
    if slice_ns is not None and slice_ns.isdigit() and int(slice_ns) < SHORTEST_DEFAULT_SLICE_NS:
        return f"short slices ({int(slice_ns) / 1e6:.1f} ms)"
    return ORDINARY


def scheduling() -> dict[str, str]:
    """What each 1 kHz thread got (by thread name), as it was read back."""
    with _GOT_LOCK:
        return dict(_GOT)


def realtime_summary() -> str:
    """One line for the start: what the force threads got, and where to read more."""
    got = scheduling()
    if got and all(v.startswith("realtime") for v in got.values()):
        return f"force threads: {next(iter(got.values()))}"
    kinds = sorted(set(got.values()) - {ORDINARY})
    detail = f" ({', '.join(kinds)})" if kinds else ""
    return (
        f"force threads: {ORDINARY}{detail}, not realtime — forces may jitter under video;"
        " see docs/running.md#realtime"
    )


def _set_slice(ns: int) -> bool:
    """``sched_setattr`` of the calling thread: SCHED_OTHER at its niceness, with a
    custom slice of ``ns`` (0: the kernel's default)."""
    try:
        nice = os.getpriority(os.PRIO_PROCESS, 0)
    except OSError:
        return False
    return _set_attr(0, 0, nice, 0, ns)


def _set_attr(policy: int, flags: int, nice: int, priority: int, runtime_ns: int) -> bool:
    """``sched_setattr`` of the calling thread (Linux; elsewhere False)."""
    import ctypes
    import platform
    import struct

    number = _SCHED_SETATTR.get(platform.machine())
    if number is None or sys.platform != "linux":
        return False
    try:
        # struct sched_attr (VER0, 48 bytes): size, policy, flags, nice, priority,
        # runtime, deadline, period.
        attr = ctypes.create_string_buffer(
            struct.pack("=IIQiIQQQ", 48, policy, flags, nice, priority, runtime_ns, 0, 0), 48
        )
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.syscall(number, 0, attr, 0) == 0)
    except (OSError, AttributeError):
        return False


def started_yielding(argv: list[str], steps: int) -> list[str]:
    """``argv`` run ``steps`` nice steps behind the server as it was started from its
    first instruction (through coreutils' ``nice``), where ``yield_cpu`` in the child
    comes only after its interpreter has started and imported: a read job's ~0.25 s of
    start-up CPU ran at the server's raised priority, level with its event loop
    (bench.abuse: single e-stops of 30–50 ms during tokenless timeline reads)."""
    nice = shutil.which("nice")
    try:
        now, target = _behind_start(steps)
    except (OSError, ValueError):
        return argv
    return [nice, "-n", str(target - now), *argv] if nice and target > now else argv


def _behind_start(steps: int) -> tuple[int, int]:
    """This process's niceness now, and the one ``steps`` behind the server as it was
    started (never above where it is: lowering one's priority needs no rights)."""
    now = os.getpriority(os.PRIO_PROCESS, 0)
    started = int(os.environ.get(STARTED_NICENESS, now))
    return now, min(19, max(now, started + steps))


def yield_cpu(steps: int) -> None:
    """Run this process (a helper of the server's: the media worker, a read job, an
    export) ``steps`` nice steps behind the server *as it was started*: behind its
    raised priority alone, video would sit only 5 steps below a client on the same
    machine, not 10. Lowering one's priority needs no rights; failing is harmless."""
    with contextlib.suppress(OSError, ValueError):
        os.setpriority(os.PRIO_PROCESS, 0, _behind_start(steps)[1])
    _set_slice(0)  # a helper works in the kernel's default slices, whoever started it
