"""Recording's cost and losses, in one run:

    python -m bench.recording [--json] [--seconds 10] [--record-seconds 60]

- ``force_p99_ratio``: force one-way p99 with 2×1280×720 video (bench.force_under_video's
  measurement), recording on ÷ off;
- ``command_p99_ratio``: command latency p99 (bench.command_latency's measurement),
  recording on ÷ off;
- ``dropped``: messages the recorder dropped in a ``--record-seconds`` recording of
  1 kHz force + video + 100 Hz commands (its own counters, and force seq gaps in the
  file), ``mb_per_min`` the file's size per minute; ``state_gap_max_ms`` and
  ``state_gaps_over_40_ms``: the recorded 50 Hz states' longest spacing, and how many
  came more than two periods apart;
- ``replay_force_n`` / ``export_s_per_min``: from bench.task_replay / bench.export
  when those modules are there (merged here, measured by their owners).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import itertools
import secrets
import statistics
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

from bench import command_latency, force_under_video
from bench.common import emit, machine, parser
from harness.servers import serve_for_bench

VIDEO_ENV = {
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_VIDEO_WIDTH": "1280",
    "TELEROBOT_VIDEO_HEIGHT": "720",
    "TELEROBOT_VIDEO_FPS": "30",
    "TELEROBOT_HOME_POSE": "qn",
}


def _recording_on(name: str):  # type: ignore[no-untyped-def]
    """``serve_for_bench`` that also records from the start (``--record NAME``)."""
    original = serve_for_bench

    @contextlib.contextmanager
    def serve(*args: str, **kwargs: Any) -> Iterator[tuple[Any, str]]:
        with original(*args, "--record", name, **kwargs) as served:
            yield served

    return serve


def force_p99(seconds: float, record: bool) -> float:
    if record:
        vars(force_under_video)["serve_for_bench"] = _recording_on("bench-force")
    try:
        figures = force_under_video.measure(seconds, False)
    finally:
        vars(force_under_video)["serve_for_bench"] = serve_for_bench
    return float(figures["p99_ms_video"])


def command_p99(commands: int, record: bool) -> float:
    """Command latency p99 with one viewer of the 2×1280×720 video in both phases: a
    recording makes the pipeline encode (to record the video) even with nobody
    watching, so without a viewer "off" would also go without the encoder's load, and
    the ratio would measure the encoder, not the recorder."""
    token = secrets.token_hex(16)
    args = ("--record", "bench-commands") if record else ()
    env = {**VIDEO_ENV, "TELEROBOT_OPERATOR_TOKEN": token}
    with serve_for_bench(*args, env=env) as (_, base):
        time.sleep(5.0)  # the simulated arm initialises
        port = int(base.rstrip("/").rsplit(":", 1)[1])

        async def watched() -> dict[str, Any]:
            viewer = asyncio.create_task(_viewer_for(base, 600))
            await asyncio.sleep(3.0)  # the video flows
            try:
                return await command_latency.measure(port, token, commands, 0.002)
            finally:
                viewer.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await viewer

        figures = asyncio.run(watched())
    return float(figures["p99_ms"])


def alternated(measure: Any, rounds: int) -> tuple[float, float, list[float], list[float]]:
    """``measure(record)`` alternated off/on ``rounds`` times: the medians, and every run
    (this machine is shared and noisy: one run each says little)."""
    off: list[float] = []
    on: list[float] = []
    for _ in range(rounds):
        off.append(measure(False))
        on.append(measure(True))
    return statistics.median(off), statistics.median(on), off, on


async def _viewer_for(base: str, seconds: float) -> None:
    from harness.aiortc_viewers import open_viewer

    with contextlib.suppress(Exception):
        pc, _track = await open_viewer(base)
        await asyncio.sleep(seconds)
        await pc.close()


async def commands_at_100_hz(port: int, token: str, seconds: float) -> dict[str, Any]:
    """100 Hz small jogs from one operator, every answer read (a refusal under load,
    e.g. a stale command, is counted, not fatal: this phase counts the recorder's
    losses, bench.command_latency measures latency above)."""
    from harness.wsclient import RealtimeClient
    from telerobot.protocol import messages as m

    op = await RealtimeClient.connect(f"ws://127.0.0.1:{port}/ws", token=token)
    await op.take_lease()
    sent = refused = 0

    async def answers() -> None:
        nonlocal refused
        async for data in op.ws:
            if m.decode(data)[0] is m.ERROR:
                refused += 1

    reader = asyncio.create_task(answers())
    next_send = time.monotonic()
    for i in range(int(seconds * 100)):
        dz = 0.0002 if (i // 50) % 2 == 0 else -0.0002
        await op.ws.send(
            m.encode(m.CART_INC, op.next_seq(), time.monotonic(), m.Frame.BASE, 0, 0, dz, 0, 0, 0)
        )
        sent += 1
        next_send += 0.01
        await asyncio.sleep(max(0.0, next_send - time.monotonic()))
    await asyncio.sleep(0.5)
    reader.cancel()
    with contextlib.suppress(asyncio.CancelledError, Exception):
        await reader
    await op.close()
    return {"n": sent, "refused": refused}


def recording(seconds: float) -> dict[str, Any]:
    """A ``seconds`` recording of 1 kHz force + video (one viewer) + 100 Hz commands."""
    from telerobot.server.recording.reader import read, summary

    token = secrets.token_hex(16)
    with (
        tempfile.TemporaryDirectory() as state,
        serve_for_bench(
            "--state-dir", state, env={**VIDEO_ENV, "TELEROBOT_OPERATOR_TOKEN": token}
        ) as (_, base),
    ):
        time.sleep(5.0)
        op = {"Authorization": f"Bearer {token}"}
        r = httpx.post(base + "api/v1/recordings", json={"name": "bench"}, headers=op, timeout=10)
        r.raise_for_status()
        port = int(base.rstrip("/").rsplit(":", 1)[1])

        async def both() -> dict[str, Any]:
            viewer = asyncio.create_task(_viewer_for(base, seconds + 2))
            figures = await commands_at_100_hz(port, token, seconds)
            await viewer
            return figures

        commands = asyncio.run(both())
        stopped = httpx.post(base + "api/v1/recordings/active/stop", headers=op, timeout=60)
        stopped.raise_for_status()
        path = Path(state) / "recordings" / stopped.json()["file"]
        counts, meta = summary(path)
        seqs = [m["seq"] for _t, _ns, m in read(path, ["/force"])]
        gaps = sum(b - a - 1 for a, b in itertools.pairwise(seqs) if b > a + 1)
        # The state's own times: how far apart the recorded states came (50 Hz asked)
        state_t = [float(m["t"]) for _t, _ns, m in read(path, ["/robot/state"])]
        state_gaps = [(b - a) * 1000 for a, b in itertools.pairwise(state_t)]
        dropped = {k.removeprefix("dropped."): int(v) for k, v in meta.items() if "dropped." in k}
        minutes = float(meta["duration_s"]) / 60
        return {
            "dropped": sum(dropped.values()),
            "dropped_by_topic": dropped,
            "force_seq_gaps": gaps,
            "state_gap_max_ms": max(state_gaps, default=None),
            "state_gaps_over_40_ms": sum(g > 40 for g in state_gaps),
            "counts": counts,
            "commands_sent": commands["n"],
            "commands_refused": commands["refused"],
            "video_packets": counts.get("/video/stereo", 0),
            "mb_per_min": path.stat().st_size / 1e6 / minutes,
            "duration_s": float(meta["duration_s"]),
        }


def others() -> dict[str, Any]:
    """MERGE POINT: the other recording benches' figures (task replay, export), if present."""
    out: dict[str, Any] = {}
    for module, key in (
        ("bench.task_replay", "replay_force_n"),
        ("bench.export", "export_s_per_min"),
    ):
        try:
            mod = importlib.import_module(module)
        except ImportError:
            out[key] = None
            continue
        try:
            result = mod.measure()
            out[key] = result.get(key) if isinstance(result, dict) else result
        except Exception as exc:  # another part's bench failing must not hide ours
            out[key] = None
            out[f"{key}_error"] = f"{type(exc).__name__}: {exc}"
    return out


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=10.0, help="per force phase")
    p.add_argument("--commands", type=int, default=3000)
    p.add_argument("--record-seconds", type=float, default=60.0)
    p.add_argument("--no-others", action="store_true", help="skip task_replay / export")
    p.add_argument("--rounds", type=int, default=3, help="off/on alternations per figure")
    p.add_argument(
        "--recording-only", action="store_true", help="only the recording's losses and gaps"
    )
    args = p.parse_args()
    if args.recording_only:
        emit(recording(args.record_seconds), args.json)
        return
    f_off, f_on, f_offs, f_ons = alternated(lambda r: force_p99(args.seconds, r), args.rounds)
    c_off, c_on, c_offs, c_ons = alternated(lambda r: command_p99(args.commands, r), args.rounds)
    rec = recording(args.record_seconds)
    figures: dict[str, Any] = {
        "force_p99_ratio": f_on / f_off,
        "command_p99_ratio": c_on / c_off,
        "dropped": rec["dropped"] + rec["force_seq_gaps"],
        "mb_per_min": rec["mb_per_min"],
        "state_gap_max_ms": rec["state_gap_max_ms"],
        "state_gaps_over_40_ms": rec["state_gaps_over_40_ms"],
        "force_p99_ms_off": f_off,
        "force_p99_ms_on": f_on,
        "command_p99_ms_off": c_off,
        "command_p99_ms_on": c_on,
        "runs": {
            **{"force_off": f_offs, "force_on": f_ons},
            **{"command_off": c_offs, "command_on": c_ons},
        },
        "recording": rec,
        **({} if args.no_others else others()),
    }
    emit({k: v for k, v in figures.items() if not isinstance(v, dict)}, False)
    if args.json:
        import json

        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
