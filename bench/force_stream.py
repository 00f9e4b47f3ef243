"""1 kHz force samples at a WebSocket client: inter-arrival p50/p99/max and loss.

Starts ``telerobot serve`` on the simulation as its own process, connects as a
client that asks for every sample, and times each FORCE message's arrival.

    python -m bench.force_stream [--json] [--samples 10000]

Thesis reference (§4.7, 100 Mbps LAN, 2003): 0.679 ms mean inter-arrival alone.
"""

from __future__ import annotations

import asyncio
import time

import numpy as np

from backend.realtime import messages as m
from bench.common import emit, machine, parser, serve_for_bench
from bench.wsclient import RealtimeClient


async def measure(port: int, samples: int) -> dict[str, float | int]:
    client = await RealtimeClient.connect(
        f"ws://127.0.0.1:{port}/ws", flags=m.HelloFlags.EVERY_FORCE_SAMPLE
    )
    arrivals: list[float] = []
    seqs: list[int] = []
    warmup = 500  # let the server settle (initialisation, first states)
    while len(seqs) < samples + warmup:
        data = await client.ws.recv()
        if data[0] != m.FORCE.type_id:
            continue
        now = time.perf_counter()
        for seq, _, _ in m.decode_force(data):
            arrivals.append(now)
            seqs.append(seq)
    await client.close()
    arr, sq = np.array(arrivals[warmup:]), np.array(seqs[warmup:])
    gaps = np.diff(arr) * 1000.0
    lost = int(np.sum(np.diff(sq) - 1))
    return {
        "interarrival_p50_ms": float(np.percentile(gaps, 50)),
        "interarrival_p99_ms": float(np.percentile(gaps, 99)),
        "interarrival_max_ms": float(gaps.max()),
        "interarrival_mean_ms": float(gaps.mean()),
        "lost": lost,
        "n": len(sq),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--samples", type=int, default=10_000)
    args = p.parse_args()
    with serve_for_bench() as (_, base):
        figures = asyncio.run(measure(int(base.rstrip("/").rsplit(":", 1)[1]), args.samples))
    emit({**figures, "thesis_mean_ms_alone": 0.679}, False)
    if args.json:
        import json

        print(json.dumps({"force_stream": figures, "machine": machine()}))


if __name__ == "__main__":
    main()
