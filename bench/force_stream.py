"""1 kHz force samples at a WebSocket client: inter-arrival p50/p99/max and loss.

Starts ``telerobot serve`` on the simulation as its own process (as it runs by
default: media worker on, no video viewer), connects as a client that asks for every
sample, and times each FORCE message's arrival.

A late arrival is told apart by where it was held up, both on this machine's
CLOCK_MONOTONIC (the sensor stamps its samples with it): ``sensor_interval_p99_ms``
is the spread of the sensor's own timestamps (its thread woke late), ``latency_*``
the time from a sample's timestamp to its arrival here (the server's event loop, the
WebSocket, this process).

    python -m bench.force_stream [--json] [--samples 10000] [--no-video]

``--no-video`` runs the server without its media worker, as when the first figures
were taken (before the video existed).

Thesis reference (§4.7, 100 Mbps LAN, 2003): 0.679 ms mean inter-arrival alone.
"""

from __future__ import annotations

import asyncio
import time

import numpy as np

from bench.common import emit, machine, parser
from harness.servers import serve_for_bench
from harness.wsclient import RealtimeClient
from telerobot.protocol import messages as m


async def measure(port: int, samples: int) -> dict[str, float | int]:
    client = await RealtimeClient.connect(
        f"ws://127.0.0.1:{port}/ws", flags=m.HelloFlags.EVERY_FORCE_SAMPLE
    )
    arrivals: list[float] = []
    stamps: list[float] = []  # the sensor's time of each sample (server, same clock)
    seqs: list[int] = []
    warmup = 500  # let the server settle (initialisation, first states)
    while len(seqs) < samples + warmup:
        data = await client.ws.recv()
        if data[0] != m.FORCE.type_id:
            continue
        now = time.monotonic()
        for seq, t, _ in m.decode_force(data):
            arrivals.append(now)
            stamps.append(t)
            seqs.append(seq)
    await client.close()
    arr, st, sq = np.array(arrivals[warmup:]), np.array(stamps[warmup:]), np.array(seqs[warmup:])
    gaps = np.diff(arr) * 1000.0
    latency = (arr - st) * 1000.0
    lost = int(np.sum(np.diff(sq) - 1))
    return {
        "interarrival_p50_ms": float(np.percentile(gaps, 50)),
        "interarrival_p99_ms": float(np.percentile(gaps, 99)),
        "interarrival_max_ms": float(gaps.max()),
        "interarrival_mean_ms": float(gaps.mean()),
        "sensor_interval_p99_ms": float(np.percentile(np.diff(st) * 1000.0, 99)),
        "latency_p50_ms": float(np.percentile(latency, 50)),
        "latency_p99_ms": float(np.percentile(latency, 99)),
        "lost": lost,
        "n": len(sq),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--samples", type=int, default=10_000)
    p.add_argument("--no-video", action="store_true", help="the server without its media worker")
    args = p.parse_args()
    env = {"TELEROBOT_VIDEO": "false"} if args.no_video else None
    with serve_for_bench(env=env) as (_, base):
        figures = asyncio.run(measure(int(base.rstrip("/").rsplit(":", 1)[1]), args.samples))
    emit({**figures, "thesis_mean_ms_alone": 0.679}, False)
    if args.json:
        import json

        print(
            json.dumps({"force_stream": figures, "video": not args.no_video, "machine": machine()})
        )


if __name__ == "__main__":
    main()
