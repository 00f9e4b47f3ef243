"""The process settings (``telerobot.tuning``): the server and the master bridge raise their
own CPU priority where the system lets them, and say how to let them where not."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

PROBE = (
    "import os; from telerobot.tuning import raise_cpu_priority as r; "
    "print(r({steps})); print(os.getpriority(os.PRIO_PROCESS, 0))"
)


def probe(steps: int, *prefix: str) -> tuple[str, int]:
    out = subprocess.run(
        [*prefix, sys.executable, "-c", PROBE.format(steps=steps)],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout.splitlines()  # fmt: skip
    return out[0], int(out[1])


@pytest.mark.skipif(os.geteuid() != 0, reason="raising the priority needs root here")
def test_the_server_raises_its_cpu_priority_where_allowed() -> None:
    before = os.getpriority(os.PRIO_PROCESS, 0)
    said, after = probe(5)
    assert after == max(-20, before - 5) and "raised" in said, said
    said, after = probe(0)
    assert after == before and "as started" in said


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to drop the capability")
def test_without_the_right_it_runs_as_started_and_says_how() -> None:
    before = os.getpriority(os.PRIO_PROCESS, 0)
    said, after = probe(5, "setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice")
    assert after == before, said
    assert "CAP_SYS_NICE" in said and "cpu_priority 0" in said


@pytest.mark.skipif(os.geteuid() != 0, reason="raising the priority needs root here")
def test_helpers_yield_from_where_the_server_started_not_from_its_raised_priority() -> None:
    # The media worker at video_nice 10 sits 10 steps below a client started beside the
    # server, not 5 (10 below the server's raised priority).
    before = os.getpriority(os.PRIO_PROCESS, 0)
    child = (
        "import os; from telerobot.tuning import yield_cpu; yield_cpu(10);"
        " print(os.getpriority(os.PRIO_PROCESS, 0))"
    )
    parent = (
        "import os, subprocess, sys; from telerobot.tuning import raise_cpu_priority as r;"
        f" r(5); subprocess.run([sys.executable, '-c', {child!r}], check=True)"
    )
    out = subprocess.run(
        [sys.executable, "-c", parent], capture_output=True, text=True, check=True, timeout=60
    ).stdout
    assert int(out) == min(19, before + 10), out


@pytest.mark.skipif(os.geteuid() != 0, reason="raising the priority needs root here")
def test_a_helper_started_yielding_runs_behind_the_server_from_its_first_instruction() -> None:
    # A read job's interpreter start-up and imports ran at the server's raised priority
    # until its main() lowered it; started through ``started_yielding`` it never does.
    # The child's own first instruction reads its niceness.
    before = os.getpriority(os.PRIO_PROCESS, 0)
    child = "import os; print(os.getpriority(os.PRIO_PROCESS, 0))"
    parent = (
        "import os, subprocess, sys; from telerobot import tuning;"
        " tuning.raise_cpu_priority(5);"
        f" argv = tuning.started_yielding([sys.executable, '-S', '-c', {child!r}], 10);"
        " print(argv[0].endswith('nice'));"
        " subprocess.run(argv, check=True)"
    )
    out = subprocess.run(
        [sys.executable, "-c", parent], capture_output=True, text=True, check=True, timeout=60
    ).stdout.split()
    assert out == ["True", str(min(19, before + 10))], out


@pytest.mark.skipif(os.geteuid() != 0, reason="raising the priority needs root here")
def test_a_block_at_a_raised_thread_priority_hands_it_to_its_threads_and_restores_it() -> None:
    # bench.abuse's legitimate clients and bench.master_contact's bridge threads run so.
    code = (
        "import os, threading; from telerobot.tuning import thread_priority_raised\n"
        "get = lambda: os.getpriority(os.PRIO_PROCESS, 0)\n"
        "seen = []\n"
        "with thread_priority_raised(5) as inside:\n"
        "    t = threading.Thread(target=lambda: seen.append(get())); t.start(); t.join()\n"
        "    print(inside, get(), seen[0])\n"
        "print(get())"
    )
    before = os.getpriority(os.PRIO_PROCESS, 0)
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    ).stdout.split()
    raised = max(-20, before - 5)
    assert [int(x) for x in out] == [raised, raised, raised, before], out


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to drop the capability")
def test_the_master_bridge_runs_as_started_without_the_right_and_says_so() -> None:
    # `telerobot master` raises its 1 kHz loop (--cpu-priority) before anything starts;
    # refused, it says how to allow it and goes on (here it then fails to find a server).
    out = subprocess.run(
        ["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice",
         sys.executable, "-m", "telerobot.server.cli", "master", "--server", "http://127.0.0.1:9/"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert "CAP_SYS_NICE" in out.stderr and "--cpu-priority 0" in out.stderr, out.stderr


def _slice_ns() -> int | None:
    try:
        with open("/proc/thread-self/sched") as f:
            lines = [line for line in f if line.startswith("se.slice")]
    except OSError:
        return None
    return int(lines[0].split(":")[1]) if lines else None


@pytest.mark.skipif(_slice_ns() is None, reason="no per-thread scheduler figures here")
def test_a_prompt_thread_runs_in_short_slices_and_its_helpers_in_the_default() -> None:
    # Where they may not run realtime, the force sensor's, the priority channel's and
    # the master link's threads ask for 0.1 ms slices (so they preempt the video encoder
    # when they wake); a helper process started from such a thread goes back to the
    # kernel's default.
    code = (
        "import threading; from telerobot.drivers.threads import WorkerThread\n"
        "from telerobot.tuning import yield_cpu\n"
        "from tests.test_tuning import _slice_ns\n"
        "seen = []\n"
        "w = WorkerThread(lambda: seen.append(_slice_ns()), 'probe', prompt=True)\n"
        "w.start(); w.stop()\n"
        "default = _slice_ns()\n"
        "w = WorkerThread(lambda: (yield_cpu(0), seen.append(_slice_ns())), 'h', prompt=True)\n"
        "w.start(); w.stop()\n"
        "print(seen[0], seen[1], default)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60,
        env={**os.environ, "TELEROBOT_RT_PRIORITY": "0"},  # realtime has no slice to ask
    ).stdout.split()  # fmt: skip
    prompt, helper, default = (int(v) for v in out)
    if not _kernel_has_custom_slices():
        # Nothing to ask for: the thread must not claim short slices it did not get.
        assert prompt == default
        return
    assert prompt == 100_000 and helper == default


def _kernel_has_custom_slices() -> bool:
    """Linux ≥ 6.12 (EEVDF's custom slice): a skip on a slice equal to the default is
    what a broken fallback gives, so the kernel decides, not the result."""
    major, minor = (int(v) for v in os.uname().release.split(".")[:2])
    return sys.platform == "linux" and (major, minor) >= (6, 12)


def test_what_a_prompt_thread_reports_is_what_the_kernel_applied() -> None:
    """prompt_thread reads its scheduling back (/proc/self/task/<tid>/sched): with no
    realtime and no slice asked for, it says ordinary, never short slices."""
    code = (
        "import threading; from telerobot import tuning\n"
        "r = []\n"
        "t = threading.Thread(target=lambda: r.append(tuning.prompt_thread()), name='p')\n"
        "t.start(); t.join()\n"
        "print(r[0]); print(tuning.realtime_summary())"
    )
    env = {**os.environ, "TELEROBOT_RT_PRIORITY": "0", "TELEROBOT_SLICE_US": "0"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60,
        env=env,
    ).stdout.splitlines()  # fmt: skip
    assert out[0] == "ordinary", out
    assert out[1].startswith("force threads: ordinary, not realtime") and "running.md" in out[1]


REALTIME_PROBE = (
    "import os, subprocess, sys\n"
    "from telerobot.drivers.threads import WorkerThread\n"
    "from telerobot.tuning import prompt_thread, yield_cpu\n"
    "seen = []\n"
    "RESET_ON_FORK = 0x40000000  # sched_getscheduler's flag beside the policy\n"
    "CHILD = [sys.executable, '-c', 'import os; print(os.sched_getscheduler(0))']\n"
    "def probe():\n"
    "    seen.append(os.sched_getscheduler(0) & ~RESET_ON_FORK)\n"
    "    seen.append(int(subprocess.run(CHILD, capture_output=True, text=True).stdout))\n"
    "    yield_cpu(0)\n"
    "    seen.append(os.sched_getscheduler(0))\n"
    "w = WorkerThread(probe, 'probe', prompt=True)\n"
    "w.start(); w.stop(10)\n"
    "print(*seen, os.sched_getscheduler(0))"
)


def realtime_probe(**env: str) -> list[int]:
    out = subprocess.run(
        [sys.executable, "-c", REALTIME_PROBE], capture_output=True, text=True, check=True,
        timeout=60, env={**os.environ, **env},
    ).stdout.split()  # fmt: skip
    return [int(v) for v in out]


@pytest.mark.skipif(os.geteuid() != 0, reason="a realtime thread needs root or CAP_SYS_NICE")
def test_a_prompt_thread_runs_realtime_where_allowed_and_what_it_starts_does_not() -> None:
    # The 1 kHz threads preempt the video encoder at once when they wake (SCHED_FIFO);
    # a process started from one (reset-on-fork) and a helper (yield_cpu) are ordinary,
    # and so is the rest of the process.
    fifo, other = os.SCHED_FIFO, os.SCHED_OTHER
    assert realtime_probe() == [fifo, other, other, other]
    # TELEROBOT_RT_PRIORITY=0: never realtime (short slices where the kernel has them)
    assert realtime_probe(TELEROBOT_RT_PRIORITY="0") == [other, other, other, other]


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs util-linux's setpriv")
def test_without_the_right_a_prompt_thread_runs_as_it_can() -> None:
    # Where the system refuses realtime (no CAP_SYS_NICE, RLIMIT_RTPRIO 0: a login
    # user's), the thread runs ordinary, in short slices where the kernel has them.
    code = (
        "import resource, os\n"
        "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n"
        "from telerobot.tuning import prompt_thread\n"
        "print(prompt_thread()); print(os.sched_getscheduler(0))"
    )
    out = subprocess.run(
        ["setpriv", "--bounding-set", "-sys_nice", sys.executable, "-c", code],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout.splitlines()  # fmt: skip
    slices = "short slices (0.1 ms)" if _kernel_has_custom_slices() else "ordinary"
    assert out[0] == slices and int(out[1]) == os.SCHED_OTHER, out


@pytest.mark.skipif(
    shutil.which("setpriv") is None or os.geteuid() != 0,
    reason="needs util-linux's setpriv, run as root to become another user",
)
def test_an_unprivileged_user_gets_short_slices_and_is_told_so() -> None:
    """The non-root path on every run: as nobody (no rights, no RLIMIT_RTPRIO), a prompt
    thread is ordinary (short slices where the kernel has them) and the start's line
    says so and where to read how to grant realtime."""
    code = (
        "import os, threading; from telerobot import tuning\n"
        "r = []\n"
        "t = threading.Thread(target=lambda: r.append(tuning.prompt_thread()), name='p')\n"
        "t.start(); t.join()\n"
        "print(os.geteuid()); print(r[0]); print(tuning.realtime_summary())"
    )
    out = subprocess.run(
        ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups",
         sys.executable, "-c", code],
        capture_output=True, text=True, check=True, timeout=60, cwd="/",
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    ).stdout.splitlines()  # fmt: skip
    slices = "short slices (0.1 ms)" if _kernel_has_custom_slices() else "ordinary"
    assert out[0] == "65534" and out[1] == slices, out
    assert "not realtime" in out[2] and "docs/running.md#realtime" in out[2], out


def test_health_says_what_the_1khz_threads_got(client: TestClient) -> None:
    """GET /api/v1/health reports each 1 kHz thread's scheduling as the kernel applied
    it, and whether all are realtime (a user without the right is told, not guessing)."""
    body = client.get("/api/v1/health").json()
    assert body["scheduling"], body  # the simulated force sensor's thread at least
    kinds = set(body["scheduling"].values())
    assert all(k.startswith(("realtime (SCHED_FIFO", "short slices (", "ordinary")) for k in kinds)
    assert body["realtime"] == all(k.startswith("realtime") for k in kinds)
    assert isinstance(body["niceness"], int)
