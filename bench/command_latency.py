"""WebSocket client → command applied at the driver, while force streams at 1 kHz.

Starts ``telerobot serve`` on the simulation as its own process; one client takes
control and sends small Cartesian increments, each timed from just before it is
sent to the server time at which the driver took it (the ACK's time, mapped to the
client's clock by the ping clock sync); a second client receives every force
sample meanwhile.

    python -m bench.command_latency [--json] [--commands 10000]

Thesis reference (§4.7): a 48-byte command took ~0.7 ms client to server (1.1 ms with video).
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import time

import httpx
import numpy as np

from backend.realtime import messages as m
from bench.common import emit, machine, parser, percentiles_ms, serve_for_bench
from bench.wsclient import RealtimeClient


async def drain_forces(client: RealtimeClient, counter: list[int]) -> None:
    while True:
        data = await client.ws.recv()
        if data[0] == m.FORCE.type_id:
            counter[0] += len(m.decode_force(data))


async def measure(
    port: int, token: str, commands: int, period_s: float, force_client: bool = True
) -> dict[str, float | int]:
    url = f"ws://127.0.0.1:{port}/ws"
    forces = await RealtimeClient.connect(
        url, flags=m.HelloFlags.EVERY_FORCE_SAMPLE if force_client else 0
    )
    received = [0]
    drain = asyncio.create_task(drain_forces(forces, received))
    op = await RealtimeClient.connect(url, token=token)
    await op.take_lease()
    rtt = await op.sync_clock()
    latencies: list[float] = []
    limited = 0
    next_send = time.monotonic()
    for i in range(commands):
        dz = 0.0002 if (i // 50) % 2 == 0 else -0.0002  # a small back-and-forth
        seq = op.next_seq()
        sent = time.monotonic()
        await op.ws.send(m.encode(m.CART_INC, seq, sent, m.Frame.BASE, 0.0, 0.0, dz, 0.0, 0.0, 0.0))
        ack = await op.expect(m.ACK)
        latencies.append(ack["server_time"] - op.offset - sent)
        limited += ack["result"] == m.Ack.LIMITED
        next_send += period_s
        await asyncio.sleep(max(0.0, next_send - time.monotonic()))
    drain.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await drain
    await op.close()
    await forces.close()
    figures = percentiles_ms(latencies)
    return {
        **figures,
        "n": len(latencies),
        "limited": limited,
        "ping_rtt_ms": rtt * 1000.0,
        "forces_received": received[0],
        "force_rate_hz": received[0] / (len(latencies) * period_s),
        "p50_ms_raw_clock": float(np.percentile(np.array(latencies) + op.offset, 50) * 1000.0),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--commands", type=int, default=10_000)
    p.add_argument("--period-ms", type=float, default=2.0, help="time between commands")
    p.add_argument(
        "--batched-forces", action="store_true", help="the second client takes ~10 ms force batches"
    )
    args = p.parse_args()
    token = secrets.token_hex(16)
    with (
        serve_for_bench(env={"TELEROBOT_OPERATOR_TOKEN": token, "TELEROBOT_HOME_POSE": "qn"}) as (
            _,
            base,
        ),
    ):
        time.sleep(5.0)  # the simulated arm initialises (qz → qn takes ~3.6 s)
        port = int(base.rstrip("/").rsplit(":", 1)[1])
        figures = asyncio.run(
            measure(port, token, args.commands, args.period_ms / 1000, not args.batched_forces)
        )
        streams = httpx.get(f"http://127.0.0.1:{port}/api/v1/telemetry").json()["streams"]
        server = next(s for s in streams if s["name"] == "command_processing")
        figures["server_processing_p50_ms"] = server["p50"]
        figures["server_processing_p99_ms"] = server["p99"]
    emit({**figures, "thesis_ms": 0.7}, False)
    if args.json:
        import json

        keep = {k: figures[k] for k in ("p50_ms", "p99_ms", "max_ms", "n")}
        print(json.dumps({"command_latency": keep, "details": figures, "machine": machine()}))


if __name__ == "__main__":
    main()
