"""WebSocket client → command applied at the driver, while force streams at 1 kHz.

Starts ``telerobot serve`` on the simulation as its own process; one client takes
control and sends small Cartesian increments, each timed from just before it is
sent to the server time at which the driver took it (the ACK's time, mapped to the
client's clock by the ping clock sync); a second client receives every force
sample meanwhile.

    python -m bench.command_latency [--json] [--commands 10000] [--robot so101-emulator]

``--robot so101-emulator``: the same against the SO-101 driver on its Feetech bus
emulator (``telerobot so101-emulator`` over TCP, its own process), the PUMA
simulation measured first in the same run as the baseline; the JSON adds
``so101_emulator`` and ``so101_p99_ratio`` (its p99 over the simulation's). The ACK
comes when the driver has taken the goal; it goes on the bus between two of the
driver's sync reads (half duplex), and ``goal_to_bus_p50_ms``/``…_p99_ms`` say how long
that took (the driver's own clock). It adds ``so101_sync_read_hz``: the driver's sync
reads of all six servos per second on the emulator in this process, over a
pseudo-terminal and over TCP, paced (the default 5 ms period: 200 Hz) and flat out
(no period), each over ``READ_WINDOW_S`` after the first 0.5 s
(tests/test_so101_driver.py asserts the pacing, not these rates).

Thesis reference (§4.7): a 48-byte command took ~0.7 ms client to server (1.1 ms with video).
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import tempfile
import time

import httpx
import numpy as np

from bench.common import (
    emit,
    machine,
    parser,
    percentiles_ms,
    serve_for_bench,
    telerobot_process,
)
from bench.wsclient import RealtimeClient
from telerobot.protocol import messages as m


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


def run_server(
    env: dict[str, str], commands: int, period_s: float, force_client: bool
) -> dict[str, float | int]:
    token = secrets.token_hex(16)
    with serve_for_bench(env={"TELEROBOT_OPERATOR_TOKEN": token, **env}) as (_, base):
        port = int(base.rstrip("/").rsplit(":", 1)[1])
        wait_ready(base)
        figures = asyncio.run(measure(port, token, commands, period_s, force_client))
        streams = httpx.get(f"http://127.0.0.1:{port}/api/v1/telemetry").json()["streams"]
        server = next(s for s in streams if s["name"] == "command_processing")
        figures["server_processing_p50_ms"] = server["p50"]
        figures["server_processing_p99_ms"] = server["p99"]
        # A bus arm: how long the goals then waited for the half-duplex bus.
        bus = httpx.get(f"http://127.0.0.1:{port}/api/v1/robot/diagnostics").json()
        for k, v in bus.get("goal_to_bus_ms", {}).items():
            figures[f"goal_to_bus_{k}_ms" if k != "n" else "goals_on_bus"] = v
        if "read_rate_hz" in bus:
            figures["bus_read_rate_hz"] = bus["read_rate_hz"]
    return figures


READ_WINDOW_S = 2.0


async def sync_read_rate_hz(make_link: str, poll_period_s: float) -> float:
    """Sync reads per second of the SO-101 driver on the bus emulator (in this process)."""
    from telerobot.drivers.robot.models import load_model
    from telerobot.drivers.robot.so101.arm import So101Arm
    from telerobot.drivers.robot.so101.calibration import JointCalibration, So101Calibration
    from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator

    names = load_model("so101").joint_names
    cal = So101Calibration(
        names, tuple(JointCalibration(i + 1, 2048.0, 1) for i in range(len(names)))
    )
    bus = FeetechBusEmulator(start=dict.fromkeys(cal.ids, 2048.0))
    with getattr(BusLink, make_link)(bus) as link:
        arm = So101Arm(link.url, calibration=cal, poll_period_s=poll_period_s)
        await arm.connect()
        try:
            await asyncio.sleep(0.5)  # past the first reads
            r0, t0 = arm.reads, time.monotonic()
            await asyncio.sleep(READ_WINDOW_S)
            return (arm.reads - r0) / (time.monotonic() - t0)
        finally:
            await arm.disconnect()


def sync_read_rates() -> dict[str, float]:
    return {
        f"{where}_{how}": asyncio.run(sync_read_rate_hz(f"on_{where}", period))
        for where in ("pty", "tcp")
        for how, period in (("paced", 0.005), ("flat_out", 0.0))
    }


def wait_ready(base: str, timeout: float = 30.0) -> None:
    """The arm initialised (the PUMA's qz → qn takes ~3.6 s, the SO-101's rest → ready ~1 s)."""
    deadline = time.monotonic() + timeout
    while httpx.get(base + "api/v1/robot/state").json()["status"] != "READY":
        if time.monotonic() > deadline:
            raise RuntimeError(f"the arm at {base} is not READY after {timeout:g} s")
        time.sleep(0.1)
    time.sleep(0.5)


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--commands", type=int, default=10_000)
    p.add_argument("--period-ms", type=float, default=2.0, help="time between commands")
    p.add_argument(
        "--batched-forces", action="store_true", help="the second client takes ~10 ms force batches"
    )
    p.add_argument("--robot", choices=("sim", "so101-emulator"), default="sim")
    args = p.parse_args()
    period, every = args.period_ms / 1000, not args.batched_forces
    figures = run_server({"TELEROBOT_HOME_POSE": "qn"}, args.commands, period, every)
    emit({**figures, "thesis_ms": 0.7}, False)
    result: dict[str, object] = {
        "command_latency": {k: figures[k] for k in ("p50_ms", "p99_ms", "max_ms", "n")},
        "details": figures,
    }
    if args.robot == "so101-emulator":
        with (
            tempfile.TemporaryDirectory() as tmp,
            telerobot_process(
                "so101-emulator", "--tcp", "127.0.0.1:0", "--calibration", f"{tmp}/cal.json",
                wait_for=r"listening on (socket://\S+)",
            ) as (_, emulator),
        ):  # fmt: skip
            env = {
                "TELEROBOT_ROBOT": "so101",
                "TELEROBOT_ROBOT_MODEL": "so101",
                "TELEROBOT_SO101_PORT": emulator.group(1),
                "TELEROBOT_SO101_CALIBRATION": f"{tmp}/cal.json",
            }
            so101 = run_server(env, args.commands, period, every)
        print("SO-101 driver on the bus emulator:")
        emit(so101, False)
        result["so101_emulator"] = {
            k: so101[k]
            for k in ("p50_ms", "p99_ms", "max_ms", "n", "goal_to_bus_p50_ms", "goal_to_bus_p99_ms")
            if k in so101
        }
        result["so101_details"] = so101
        result["so101_sync_read_hz"] = reads = sync_read_rates()
        print("SO-101 sync reads of six servos on the emulator (Hz):")
        emit(reads, False)
        result["so101_p99_ratio"] = float(so101["p99_ms"]) / float(figures["p99_ms"])
        print(f"so101 p99 / simulation p99: {result['so101_p99_ratio']:.2f}")
    if args.json:
        import json

        print(json.dumps({**result, "machine": machine()}))


if __name__ == "__main__":
    main()
