"""Shared helpers for the benchmarks: repeated timing with medians, machine info,
and the one JSON line every ``--json`` run ends with."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any


def parser(description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    return p


def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        # Who ran it, and what the last server's 1 kHz threads got (realtime or not):
        # figures taken with rights say so (docs/running.md, "Realtime").
        "euid": os.geteuid(),
        **({"server_scheduling": dict(SERVER_SCHEDULING)} if SERVER_SCHEDULING else {}),
    }


# What the newest server a bench started said of its 1 kHz threads (GET /api/v1/health).
SERVER_SCHEDULING: dict[str, str] = {}
UNPRIVILEGED_UID = 65534  # nobody: no rights, no RLIMIT_RTPRIO


def as_user(uid: int | None) -> tuple[str, ...]:
    """The prefix that runs a command as ``uid`` with no rights (util-linux's setpriv;
    the caller must be root), or nothing for None."""
    if uid is None:
        return ()
    return ("setpriv", f"--reuid={uid}", f"--regid={uid}", "--clear-groups", "--inh-caps=-all")


def _note_scheduling(base: str) -> None:
    import httpx

    with contextlib.suppress(httpx.HTTPError, ValueError, KeyError):
        got = httpx.get(base + "api/v1/health", timeout=10).json()["scheduling"]
        SERVER_SCHEDULING.clear()
        SERVER_SCHEDULING.update(got)


def time_per_call_us(fn: Callable[[], object], *, calls: int, repeats: int = 7) -> float:
    """Median over ``repeats`` runs of the mean time per call, in microseconds
    (the machine is shared and noisy: medians, never one timing)."""
    fn()  # warm up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        samples.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(samples)


def emit(figures: dict[str, Any], as_json: bool) -> None:
    width = max(len(k) for k in figures)
    for k, v in figures.items():
        if not isinstance(v, dict):
            print(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    if as_json:
        print(json.dumps(figures))


@contextlib.contextmanager
def telerobot_process(
    *args: str,
    wait_for: str,
    env: dict[str, str] | None = None,
    timeout: float = 60.0,
    drain: bool = True,
    prefix: tuple[str, ...] = (),
    exe: Path | None = None,
    cwd: Path | None = None,
) -> Iterator[tuple[subprocess.Popen[str], re.Match[str]]]:
    """Run ``telerobot ARGS`` as its own process; yield once a line of its output
    matches ``wait_for`` (the benchmarks and the end-to-end tests use it). ``prefix``
    runs it through another command (``ip netns exec NAME``); ``exe``: another
    installation's ``telerobot`` (default: this environment's), run in ``cwd``."""
    exe = exe or Path(sys.executable).parent / "telerobot"
    proc = subprocess.Popen(
        [*prefix, str(exe), *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
    )
    assert proc.stdout is not None
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    match = None
    try:
        while match is None:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                raise RuntimeError(f"telerobot {' '.join(args)} exited:\n{''.join(seen)}")
            seen.append(line)
            match = re.search(wait_for, line)
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"no line matching {wait_for!r} within {timeout} s:\n{''.join(seen)}"
                )
        if drain:  # keep reading its output so a chatty server never blocks on a full pipe
            threading.Thread(target=lambda: [None for _ in proc.stdout or []], daemon=True).start()
        yield proc, match
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


SERVED = r"https?://(\S+?):(\d+)/"  # the URL `telerobot serve` prints: host, port


@contextlib.contextmanager
def serve_for_bench(
    *args: str,
    env: dict[str, str] | None = None,
    prefix: tuple[str, ...] = (),
    port: int = 0,
    ready: bool = False,
    exe: Path | None = None,
    cwd: Path | None = None,
    user: int | None = None,
) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """`telerobot serve ARGS` for a benchmark or a test (the one way both start a
    server): this HTTP port (0: any free one, so a running `make run` is never in the
    way), any priority port, a throw-away state folder, no 3D view. With ``ready``, once
    its robot is READY; with ``user``, as that user with no rights (``as_user``). Yields
    the process and its base URL (http://host:port/)."""
    import tempfile

    with tempfile.TemporaryDirectory() as state:
        if user is not None:
            os.chown(state, user, user)
        with telerobot_process(
            "serve", "--http-port", str(port), "--priority-port", "0", "--state-dir", state,
            *args, wait_for=SERVED, env={"TELEROBOT_VIEWER": "false", **(env or {})},
            prefix=(*prefix, *as_user(user)), exe=exe, cwd=cwd,
        ) as (proc, m):  # fmt: skip
            host = "127.0.0.1" if m.group(1) == "localhost" else m.group(1)
            base = f"http://{host}:{m.group(2)}/"
            if ready:
                wait_until_ready(base)
            _note_scheduling(base)
            yield proc, base


def arm_names(arms: int) -> list[str]:
    """The benches' names for ``arms`` arms: left and right for two, arm1… else."""
    return ["left", "right"] if arms == 2 else [f"arm{i + 1}" for i in range(arms)]


def arms_env(arms: int, model: str, robot: str = "sim") -> dict[str, str]:
    """The environment of a server driving ``arms`` arms of ``model`` (issue 33):
    ``TELEROBOT_ARMS`` (``left=so101:sim,right=so101:sim``) for two or more, the robot's
    own settings for one; a PUMA at its ``qn`` pose, as the benches' one arm."""
    env = {"TELEROBOT_HOME_POSE": "qn"} if model == "puma560" else {}
    if arms == 1:
        return {**env, "TELEROBOT_ROBOT_MODEL": model, "TELEROBOT_ROBOT": robot}
    spec = ",".join(f"{name}={model}:{robot}" for name in arm_names(arms))
    return {**env, "TELEROBOT_ARMS": spec}


@contextlib.contextmanager
def busy_core(on: bool) -> Iterator[None]:
    """With ``on``, one core kept busy meanwhile (Debian's stress-ng), as a machine that
    is also doing something else: the benches' ``--busy-core``."""
    proc = subprocess.Popen(["stress-ng", "--cpu", "1", "--quiet"]) if on else None
    try:
        yield
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(10)


def wait_until_ready(base: str, timeout: float = 30.0) -> None:
    """Wait until the server at ``base`` says every arm is READY (the simulated arm
    initialises to its home pose first)."""
    import httpx

    deadline = time.monotonic() + timeout
    while any(
        (status := arm["status"]) != "READY" for arm in httpx.get(base + "api/v1/robot/arms").json()
    ):
        if time.monotonic() > deadline:
            raise RuntimeError(f"the robot never became READY (still {status})")
        time.sleep(0.05)


def percentiles_ms(values_s: list[float]) -> dict[str, float]:
    import numpy as np

    v = np.array(values_s) * 1000.0
    return {
        "p50_ms": float(np.percentile(v, 50)),
        "p99_ms": float(np.percentile(v, 99)),
        "max_ms": float(v.max()),
        "mean_ms": float(v.mean()),
    }


def p50_p99(values_ms: list[float]) -> dict[str, float] | None:
    """``{"p50", "p99"}`` of figures already in ms, rounded to 0.01; None with none."""
    import numpy as np

    if not values_ms:
        return None
    p50, p99 = np.percentile(np.array(values_ms), [50, 99])
    return {"p50": round(float(p50), 2), "p99": round(float(p99), 2)}


async def open_viewer(base: str, timeout: float = 30.0) -> tuple[Any, Any]:
    """An aiortc peer that asks ``base`` for the stereo video (one POST, as a browser
    does): returns the peer connection and its video track once the track is up."""
    import asyncio

    import httpx
    from aiortc import RTCPeerConnection, RTCSessionDescription

    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    tracks: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", tracks.put_nowait)
    await pc.setLocalDescription(await pc.createOffer())
    async with httpx.AsyncClient(base_url=base, timeout=timeout) as http:
        r = await http.post(
            "api/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp, "type": "offer"}
        )
        if r.status_code != 200:
            await pc.close()
            raise RuntimeError(f"the server refused the offer: HTTP {r.status_code} {r.text}")
        await pc.setRemoteDescription(RTCSessionDescription(r.json()["sdp"], r.json()["type"]))
    return pc, await asyncio.wait_for(tracks.get(), timeout)


async def answer_server_offer(
    http: Any, pc: Any, layer: str | None = None, before_answer: Any = None
) -> dict[str, str]:
    """The server offers (``/webrtc/server-offer``, the media server's offer for an
    observer on a server with one), ``pc`` answers (``/webrtc/answer``); the peer's id
    and secret. ``before_answer(offer)`` runs once the offer is set and before the
    answer is made (the moment to open Janus's data channel). ``http``: an
    httpx.AsyncClient on the server (with the token for the operator's direct path)."""
    from aiortc import RTCSessionDescription

    params = {"layer": layer} if layer else None
    r = await http.post("api/v1/webrtc/server-offer", params=params, json={})
    if r.status_code != 200:
        raise RuntimeError(f"the server refused to offer: HTTP {r.status_code} {r.text[:300]}")
    offer = r.json()
    await pc.setRemoteDescription(RTCSessionDescription(offer["sdp"], offer["type"]))
    if before_answer is not None:
        before_answer(offer)
    await pc.setLocalDescription(await pc.createAnswer())
    peer = {"peer_id": offer["peer_id"], "peer_secret": offer["peer_secret"]}
    r = await http.post(
        "api/v1/webrtc/answer", json={"sdp": pc.localDescription.sdp, "type": "answer", **peer}
    )
    if r.status_code != 200:
        raise RuntimeError(f"the server refused the answer: HTTP {r.status_code} {r.text[:300]}")
    return peer


async def open_server_offer_viewer(
    base: str, token: str | None = None, timeout: float = 30.0
) -> tuple[Any, Any, dict[str, str]]:
    """An aiortc peer that takes the server's offer (``/webrtc/server-offer``, then
    ``/webrtc/answer``), as an observer does on a server with a media server (its offer
    is the media server's) or with ``token`` the operator's direct path. Returns the
    peer connection, its video track once up, and the peer's id and secret."""
    import asyncio

    import httpx
    from aiortc import RTCPeerConnection

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    pc = RTCPeerConnection()
    tracks: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", tracks.put_nowait)
    async with httpx.AsyncClient(base_url=base, timeout=timeout, headers=headers) as http:
        try:
            peer = await answer_server_offer(http, pc)
        except RuntimeError:
            await pc.close()
            raise
    return pc, await asyncio.wait_for(tracks.get(), timeout), peer
