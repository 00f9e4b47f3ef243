"""Debian's headless Chromium as the tests and the benchmarks launch it: its flags
(``ARGS``), and on this shared machine its software GPU and its session put below the
server (``yield_software_gpu``, ``yield_browser_session``), as if the browser ran on
the operator's own machine."""

from __future__ import annotations

import os

import psutil

# Frame pacing stays on: without vsync and with the frame-rate limit off, headless
# Chromium composites as fast as it can and its software GPU takes both cores.
ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--autoplay-policy=no-user-gesture-required",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

GPU_NICE = 10


def yield_software_gpu(nice: int = GPU_NICE) -> int:
    """Lower the priority of every thread of the Chromium GPU processes started by this
    process; returns how many threads. With no GPU, Chromium draws with SwiftShader, and
    its GPU process takes 1.2 cores of this 2-core machine for a page with video: at the
    same priority it starves the page's realtime worker (dead-man heartbeats 185 ms
    apart) and the server. Real graphics hardware takes no CPU for it; here it gets
    what is left. (Niceness is per thread on Linux, hence every thread.)"""
    done = 0
    for process in psutil.Process().children(recursive=True):
        try:
            if "--type=gpu-process" not in process.cmdline():
                continue
            for thread in process.threads():
                if os.getpriority(os.PRIO_PROCESS, thread.id) < nice:
                    os.setpriority(os.PRIO_PROCESS, thread.id, nice)
                    done += 1
        except (psutil.Error, OSError):
            continue  # gone meanwhile
    return done


def yield_browser_session(nice: int = GPU_NICE) -> bool:
    """Set the scheduling autogroup of the browser started by this process to ``nice``.

    Why: Linux's autogroups (``/proc/sys/kernel/sched_autogroup_enabled``, on in
    Debian) share the CPU between sessions first, and a thread's niceness counts only
    inside its own. Playwright starts Chromium in a session of its own, so the software
    GPU's niceness (``yield_software_gpu``) did not hold it back from the server: the
    two sessions split the 2 cores evenly, the encoder's threads waited in the run
    queue, and capture → decoded had a p99 of ~100 ms (docs/PERFORMANCE.md, issue 29).
    The operator's browser runs on another machine than the robot's server; here the
    browser's session gets what the server's leaves, as the GPU alone was meant to."""
    for process in psutil.Process().children(recursive=True):
        try:
            if "--type=gpu-process" in process.cmdline():
                with open(f"/proc/{process.pid}/autogroup", "w") as f:
                    f.write(str(nice))
                return True
        except (psutil.Error, OSError):
            continue
    return False
