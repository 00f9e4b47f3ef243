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

``--arms 2`` (issue 33, two arms at once): afterwards, a server driving two arms of
``--arms-model`` (``TELEROBOT_ARMS=left=so101:sim,right=so101:sim``) and one client
holding the one lease, as a bimanual operator: one connection, a CART_INC for every arm
each tick at ``--arm-rate-hz`` (100 Hz) per arm, sent back to back (``--stagger``: spread
over the tick), each naming its arm; ACKs are read as they come and matched by seq.
Phases of ``--block-seconds`` (1 s) alternate, ABBA, a one-arm phase (only the first
arm driven) with the all-arms phase on the same server, ``--arms-seconds`` (30 s) of
each, so the shared machine's changing load falls on both alike. The JSON adds
``p99_ms_per_arm`` (all-arms phase), ``p99_ms_one_arm`` (one-arm phase),
``p99_ratio_two_vs_one`` (the worse arm's p99 over the one-arm phase's, every phase
pooled) and ``arms``: the details (p50/max per arm; the ratio from each half of the run
alone, and the median of the rounds' ratios, which a stall of the machine moves less;
``ack_spread_ms``, the last arm's ACK after the first's in one tick; and a one-arm
server of the same model driven the same way in the same run, ``one_arm_server``, with
``p99_ratio_vs_one_arm_server``). The second client receives every force sample of
every arm throughout (``--batched-forces``: ~10 ms batches).

``--model so101|puma560``: the simulated arm of the first run (default: the PUMA, as
before).

``--random-directions`` (issue 50, jogging as an operator does): instead, a server of
``--arms`` (1 or 2) simulated arms of ``--model`` (default so101) and one client on the
server's clock (SYNCED_CLOCK, as the page) holding the lease sends, at the page's
``--rate-hz`` (100 Hz) and to every arm each tick, 0.2 mm increments in random unit
directions, each in the base or the tool frame at random: most of them, on a five-joint
arm, directions it cannot follow with the orientation kept. ``--seconds`` (20 s) after
a 1 s warm-up; a second client takes every force sample. Then the old exact increments
beside them, the same way on a fresh server, one base axis at a time (±0.2 mm back and
forth along x, y or z, ``--exact-seconds`` each). For each: ``ack_ms`` (send → ACK,
the client's clock; p50, p99), ``server_ms`` (the server's own receipt → applied,
``command_processing``; p50, p99, the warm-up in it) and ``stale_dropped`` (commands the
server dropped as older than ``max_command_age_ms`` when it came to them: a loop that
fell behind), with the refusals (what and how many) and, with two arms, each arm's
``ack_ms``. The JSON: ``{"model", "arms", "<model>": {ack_ms, server_ms, stale_dropped,
…, "exact_increments": {"x": …, "y": …, "z": …}}, "machine"}``.

Thesis reference (§4.7): a 48-byte command took ~0.7 ms client to server (1.1 ms with video).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import secrets
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np

from bench.common import arms_env, emit, machine, p50_p99, parser, percentiles_ms
from harness.servers import serve_for_bench, telerobot_process
from harness.wsclient import RealtimeClient
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
    limited = refused = 0
    next_send = time.monotonic()
    for i in range(commands):
        dz = 0.0002 if (i // 50) % 2 == 0 else -0.0002  # a small back-and-forth
        seq = op.next_seq()
        sent = time.monotonic()
        await op.ws.send(m.encode(m.CART_INC, seq, sent, m.Frame.BASE, 0.0, 0.0, dz, 0.0, 0.0, 0.0))
        try:
            ack = await op.expect(m.ACK)
        except RuntimeError:  # refused: stale after a stall of the shared machine (>150 ms)
            refused += 1
        else:
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
        "refused": refused,
        "ping_rtt_ms": rtt * 1000.0,
        "forces_received": received[0],
        "force_rate_hz": received[0] / (commands * period_s),
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


# ---------------------------------------------------------------- two arms or more
WARMUP_S = 1.0  # every arm driven this long first, not counted


def arms_plan(conditions: tuple[str, ...], rounds: int) -> list[tuple[int, str]]:
    """The phases in order, (round, condition): ``rounds`` rounds of every condition,
    ABBA (the order turned every other round)."""
    plan: list[tuple[int, str]] = []
    for r in range(rounds):
        plan.extend((r, c) for c in (conditions if r % 2 == 0 else reversed(conditions)))
    return plan


@dataclass
class ArmsRun:
    """What ``drive_arms`` measured: latencies (s) by (round, condition, arm name)."""

    names: list[str]
    rounds: int
    latencies: dict[tuple[int, str, str], list[float]] = field(
        default_factory=lambda: defaultdict(list)
    )
    limited: int = 0
    refused: int = 0
    refusals: list[str] = field(default_factory=list)  # the first few ERRORs (distinct)
    # all-arms ticks: each arm's ACK time (the server's clock) by tick, then arm name
    acked: dict[int, dict[str, float]] = field(default_factory=lambda: defaultdict(dict))
    unanswered: int = 0
    ping_rtt_ms: float = 0.0
    force_rate_hz: float = 0.0

    def pooled(self, cond: str, name: str) -> list[float]:
        return [v for r in range(self.rounds) for v in self.latencies.get((r, cond, name), [])]


async def drive_arms(
    port: int,
    token: str,
    conditions: tuple[str, ...],
    seconds: float,
    rounds: int,
    rate_hz: float,
    stagger: bool,
    every_force: bool = True,
) -> ArmsRun:
    """One client holding the lease drives the arms at ``rate_hz`` each: in a ``one``
    phase only the first arm, in an ``all`` phase every arm each tick (back to back, or
    spread over the tick with ``stagger``); ``rounds`` phases of each condition,
    ``seconds`` in all per condition. A second client receives every force sample of
    every arm (``every_force``; else ~10 ms batches)."""
    url = f"ws://127.0.0.1:{port}/ws"
    forces = await RealtimeClient.connect(
        url, flags=m.HelloFlags.EVERY_FORCE_SAMPLE if every_force else 0
    )
    received = [0]
    drain = asyncio.create_task(drain_forces(forces, received))
    op = await RealtimeClient.connect(url, token=token)
    run = ArmsRun(list(op.arms), rounds)  # the names in index order
    await op.take_lease()
    run.ping_rtt_ms = await op.sync_clock() * 1000.0
    # seq → (round, condition, arm name, send time, tick); round -1: the warm-up
    pending: dict[int, tuple[int, str, str, float, int]] = {}

    async def read_acks() -> None:
        while True:
            data = await op.ws.recv()
            if data[0] == m.ACK.type_id:
                _, ack, _ = m.decode(data)
                sent = pending.pop(int(ack["seq"]), None)
                if sent is not None and sent[0] >= 0:
                    r, cond, name, t, at_tick = sent
                    run.latencies[(r, cond, name)].append(ack["server_time"] - op.offset - t)
                    run.limited += ack["result"] == m.Ack.LIMITED
                    if cond == "all":
                        run.acked[at_tick][name] = ack["server_time"]
            elif data[0] == m.ERROR.type_id:
                _, error, text = m.decode(data)
                if pending.pop(int(error["seq"]), None) is not None:
                    run.refused += 1
                    if len(run.refusals) < 5 and str(text) not in run.refusals:
                        run.refusals.append(str(text))

    reader = asyncio.create_task(read_acks())
    period = 1.0 / rate_hz
    phase_ticks = max(1, round(seconds / rounds * rate_hz))
    phases = [(-1, "all", round(WARMUP_S * rate_hz))]
    phases += [(r, c, phase_ticks) for r, c in arms_plan(conditions, rounds)]
    tick = 0
    next_tick = time.monotonic()
    for r, cond, ticks in phases:
        driven = run.names if cond == "all" else run.names[:1]
        for _ in range(ticks):
            dz = 0.0002 if (tick // 50) % 2 == 0 else -0.0002  # a small back-and-forth
            for j, name in enumerate(driven):
                if stagger and j:
                    due = next_tick + j * period / len(driven)
                    await asyncio.sleep(max(0.0, due - time.monotonic()))
                seq = op.next_seq()
                sent = time.monotonic()
                pending[seq] = (r, cond, name, sent, tick)
                move = (m.Frame.BASE, 0.0, 0.0, dz, 0.0, 0.0, 0.0, op.arms[name])
                await op.ws.send(m.encode(m.CART_INC, seq, sent, *move))
            tick += 1
            next_tick += period
            await asyncio.sleep(max(0.0, next_tick - time.monotonic()))
    await asyncio.sleep(0.5)  # the last ACKs
    for task in (reader, drain):
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    await op.close()
    await forces.close()
    run.unanswered = len(pending)
    run.force_rate_hz = received[0] / (tick * period)
    return run


def p99_ms(values_s: list[float]) -> float:
    return float(np.percentile(np.array(values_s), 99) * 1000.0) if values_s else math.nan


def arms_figures(run: ArmsRun) -> dict[str, Any]:
    """Per arm of the all-arms phase and the one-arm phase (pooled over the rounds),
    the worse arm's p99 over the one arm's, and that ratio in each half of the run."""
    first = run.names[0]
    one = percentiles_ms(run.pooled("one", first))
    every = {name: percentiles_ms(run.pooled("all", name)) for name in run.names}
    worst = max(f["p99_ms"] for f in every.values())
    halves = [range(run.rounds // 2), range(run.rounds // 2, run.rounds)]

    def ratio(rounds: range) -> float:
        def pool(cond: str, name: str) -> list[float]:
            return [v for r in rounds for v in run.latencies.get((r, cond, name), [])]

        worst_arm = max(p99_ms(pool("all", name)) for name in run.names)
        return worst_arm / p99_ms(pool("one", first))

    # Round by round (a phase of each, side by side), the median: what a stall of the
    # shared machine does to the few rounds it falls in leaves it be.
    by_round = [ratio(range(r, r + 1)) for r in range(run.rounds)]

    return {
        "p99_ms_per_arm": {name: f["p99_ms"] for name, f in every.items()},
        "p50_ms_per_arm": {name: f["p50_ms"] for name, f in every.items()},
        "max_ms_per_arm": {name: f["max_ms"] for name, f in every.items()},
        "n_per_arm": {name: len(run.pooled("all", name)) for name in run.names},
        "p50_ms_one_arm": one["p50_ms"],
        "p99_ms_one_arm": one["p99_ms"],
        "max_ms_one_arm": one["max_ms"],
        "n_one_arm": len(run.pooled("one", first)),
        "p99_ratio_two_vs_one": worst / one["p99_ms"],
        # in an all-arms tick, the last arm's ACK after the first's (the server's clock):
        # how long the one loop took over the commands before it
        "ack_spread_ms": p50_p99(
            [
                (acks[run.names[-1]] - acks[first]) * 1000.0
                for acks in run.acked.values()
                if len(acks) == len(run.names)
            ]
        ),
        # the same from each half of the run alone: how far the figure holds still
        "p99_ratio_by_half": [ratio(h) for h in halves] if run.rounds >= 2 else [],
        "p99_ratio_median_of_rounds": float(np.nanmedian(by_round)),
    }


def run_arms(
    arms: int,
    model: str,
    seconds: float,
    rounds: int,
    rate_hz: float,
    stagger: bool,
    every_force: bool = True,
) -> dict[str, Any]:
    """The arms on one server (one-arm and all-arms phases alternating), then a one-arm
    server of the same model driven the same way, in this run."""
    token = secrets.token_hex(16)
    env = {"TELEROBOT_OPERATOR_TOKEN": token, **arms_env(arms, model)}
    with serve_for_bench(env=env, ready=True) as (_, base):
        port = int(base.rstrip("/").rsplit(":", 1)[1])
        time.sleep(0.5)
        both = ("one", "all")
        run = asyncio.run(
            drive_arms(port, token, both, seconds, rounds, rate_hz, stagger, every_force)
        )
        server = server_processing(base)
    figures = arms_figures(run)
    single = {"TELEROBOT_OPERATOR_TOKEN": token, **arms_env(1, model)}
    with serve_for_bench(env=single, ready=True) as (_, base):
        port = int(base.rstrip("/").rsplit(":", 1)[1])
        time.sleep(0.5)
        alone = asyncio.run(
            drive_arms(port, token, ("one",), seconds, rounds, rate_hz, stagger, every_force)
        )
    one_server = percentiles_ms(alone.pooled("one", alone.names[0]))
    worst = max(figures["p99_ms_per_arm"].values())
    return {
        **figures,
        "one_arm_server": {**one_server, "n": len(alone.pooled("one", alone.names[0]))},
        "p99_ratio_vs_one_arm_server": worst / one_server["p99_ms"],
        "arms": arms,
        "model": model,
        "rate_hz_per_arm": rate_hz,
        "stagger": stagger,
        "every_force_sample": every_force,
        "rounds": rounds,
        "seconds_per_condition": seconds,
        "limited": run.limited,
        "refused": run.refused,
        "refusals": run.refusals,
        "unanswered": run.unanswered,
        "ping_rtt_ms": run.ping_rtt_ms,
        "force_rate_hz": run.force_rate_hz,
        **server,
    }


def server_processing(base: str) -> dict[str, float]:
    streams = httpx.get(base + "api/v1/telemetry").json()["streams"]
    server = next(s for s in streams if s["name"] == "command_processing")
    return {"server_processing_p50_ms": server["p50"], "server_processing_p99_ms": server["p99"]}


# ---------------------------------------------------------------- jogging (issue 50)
JOG_STEP_M = 0.0002  # the page's keyboard increment
JOG_WARMUP_S = 1.0  # driven first, not in ack_ms (in server_ms: the server's window)
# (frame, dx, dy, dz) of the increment a tick sends to an arm (its index among the arms)
Motion = Callable[[int, int], tuple[int, float, float, float]]


def random_directions(seed: int = 50) -> Motion:
    """0.2 mm in a random unit direction, in the base or the tool frame at random."""
    rng = np.random.default_rng(seed)

    def motion(tick: int, arm: int) -> tuple[int, float, float, float]:
        v = rng.normal(size=3)
        dx, dy, dz = (v / np.linalg.norm(v) * JOG_STEP_M).tolist()
        return int(m.Frame.BASE if rng.random() < 0.5 else m.Frame.TOOL), dx, dy, dz

    return motion


def along_axis(axis: int) -> Motion:
    """±0.2 mm along one base axis, 50 ticks each way (the old bench's back and forth)."""

    def motion(tick: int, arm: int) -> tuple[int, float, float, float]:
        d = [0.0, 0.0, 0.0]
        d[axis] = JOG_STEP_M if (tick // 50) % 2 == 0 else -JOG_STEP_M
        return int(m.Frame.BASE), d[0], d[1], d[2]

    return motion


@dataclass
class JogRun:
    """What ``drive_jog`` measured: send → ACK (s) by arm name, refusals."""

    latencies: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    limited: int = 0
    refused: int = 0
    refusals: dict[str, int] = field(default_factory=dict)  # the ERRORs' texts, counted
    unanswered: int = 0
    ping_rtt_ms: float = 0.0
    force_rate_hz: float = 0.0


async def drive_jog(
    port: int, token: str, motion: Motion, seconds: float, rate_hz: float
) -> JogRun:
    """One client on the server's clock holding the lease sends each arm ``motion``'s
    increment every tick at ``rate_hz`` (back to back, as the page does with two arms)
    without waiting for the ACKs, which a reader matches by seq; ``JOG_WARMUP_S`` first,
    not counted. A second client takes every force sample meanwhile."""
    url = f"ws://127.0.0.1:{port}/ws"
    forces = await RealtimeClient.connect(url, flags=m.HelloFlags.EVERY_FORCE_SAMPLE)
    received = [0]
    drain = asyncio.create_task(drain_forces(forces, received))
    started = time.monotonic()
    op = await RealtimeClient.connect(url, token=token, flags=m.HelloFlags.SYNCED_CLOCK)
    names = list(op.arms) or ["arm"]
    await op.take_lease()
    run = JogRun(ping_rtt_ms=await op.sync_clock() * 1000.0)
    pending: dict[int, tuple[str, float, bool]] = {}  # seq → (arm, send time, counted)

    async def read_acks() -> None:
        while True:
            data = await op.ws.recv()
            if data[0] == m.ACK.type_id:
                _, ack, _ = m.decode(data)
                sent = pending.pop(int(ack["seq"]), None)
                if sent is not None and sent[2]:
                    run.latencies[sent[0]].append(ack["server_time"] - op.offset - sent[1])
                    run.limited += ack["result"] == m.Ack.LIMITED
            elif data[0] == m.ERROR.type_id:
                _, error, text = m.decode(data)
                sent = pending.pop(int(error["seq"]), None)
                if sent is not None and sent[2]:
                    run.refused += 1
                    why = str(text).split(":")[0][:80]
                    run.refusals[why] = run.refusals.get(why, 0) + 1

    reader = asyncio.create_task(read_acks())
    period = 1.0 / rate_hz
    warmup = round(JOG_WARMUP_S * rate_hz)
    ticks = warmup + round(seconds * rate_hz)
    next_tick = time.monotonic()
    for tick in range(ticks):
        for i, name in enumerate(names):
            frame, dx, dy, dz = motion(tick, i)
            seq = op.next_seq()
            sent = time.monotonic()
            pending[seq] = (name, sent, tick >= warmup)
            arm = op.arms.get(name, 0)
            cmd = m.encode(m.CART_INC, seq, sent + op.offset, frame, dx, dy, dz, 0.0, 0.0, 0.0, arm)
            await op.ws.send(cmd)
        next_tick += period
        await asyncio.sleep(max(0.0, next_tick - time.monotonic()))
    await asyncio.sleep(0.5)  # the last ACKs
    for task in (reader, drain):
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    run.force_rate_hz = received[0] / (time.monotonic() - started) / len(names)  # per arm
    await op.close()
    await forces.close()
    run.unanswered = sum(1 for _, _, counted in pending.values() if counted)
    return run


def run_jog(
    model: str, arms: int, motion: Motion, seconds: float, rate_hz: float
) -> dict[str, Any]:
    """A fresh server of ``arms`` simulated arms of ``model`` driven by ``motion``: its
    figures (ack_ms, server_ms, stale_dropped, refusals; per arm with two)."""
    token = secrets.token_hex(16)
    env = {"TELEROBOT_OPERATOR_TOKEN": token, **arms_env(arms, model)}
    with serve_for_bench(env=env, ready=True) as (_, base):
        port = int(base.rstrip("/").rsplit(":", 1)[1])
        time.sleep(0.5)
        run = asyncio.run(drive_jog(port, token, motion, seconds, rate_hz))
        server = next(
            s
            for s in httpx.get(base + "api/v1/telemetry").json()["streams"]
            if s["name"] == "command_processing"
        )
        stale = int(httpx.get(base + "api/v1/safety").json()["stale_commands_dropped"])
    pooled = [v * 1000.0 for values in run.latencies.values() for v in values]
    figures: dict[str, Any] = {
        "ack_ms": p50_p99(pooled),
        "server_ms": {"p50": round(server["p50"], 3), "p99": round(server["p99"], 3)},
        "stale_dropped": stale,
        "n": len(pooled),
        "max_ack_ms": round(max(pooled), 2) if pooled else None,
        "server_max_ms": round(server["max"], 3),
        "limited": run.limited,
        "refused": run.refused,
        "refusals": run.refusals,
        "unanswered": run.unanswered,
        "ping_rtt_ms": round(run.ping_rtt_ms, 3),
        "force_rate_hz": round(run.force_rate_hz, 1),
    }
    if arms > 1:
        figures["ack_ms_per_arm"] = {
            name: p50_p99([v * 1000.0 for v in values]) for name, values in run.latencies.items()
        }
    return figures


def jog_figures(
    model: str, arms: int, seconds: float, exact_seconds: float, rate_hz: float
) -> dict[str, Any]:
    """Random directions, then the exact increments along x, y and z, each on its own
    server."""
    print(f"{arms} × {model}: random directions, {seconds:g} s at {rate_hz:g} Hz per arm")
    figures = run_jog(model, arms, random_directions(), seconds, rate_hz)
    emit({k: v for k, v in figures.items() if not isinstance(v, dict)}, False)
    print(f"  ack_ms {figures['ack_ms']}  server_ms {figures['server_ms']}")
    exact: dict[str, Any] = {}
    for axis, name in enumerate("xyz"):
        exact[name] = run_jog(model, arms, along_axis(axis), exact_seconds, rate_hz)
        print(
            f"exact ±0.2 mm along {name}: ack_ms {exact[name]['ack_ms']}  server_ms "
            f"{exact[name]['server_ms']}  stale_dropped {exact[name]['stale_dropped']}"
        )
    return {**figures, "exact_increments": exact}


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
    p.add_argument("--arms", type=int, default=1, help="then N arms driven at once (2: issue 33)")
    p.add_argument("--arms-model", default="so101", help="the model of every arm (--arms)")
    p.add_argument("--arm-rate-hz", type=float, default=100.0, help="commands per arm (--arms)")
    p.add_argument(
        "--arms-seconds", type=float, default=30.0, help="per condition: one arm / every arm"
    )
    p.add_argument(
        "--block-seconds", type=float, default=1.0, help="one phase: one arm or every arm"
    )
    p.add_argument("--stagger", action="store_true", help="spread the arms' commands over a tick")
    p.add_argument(
        "--model",
        choices=("so101", "puma560"),
        help="the simulated arm (default: the PUMA; so101 with --random-directions)",
    )
    p.add_argument(
        "--random-directions",
        action="store_true",
        help="issue 50: 0.2 mm jogs in random directions and frames to --arms arms",
    )
    p.add_argument("--rate-hz", type=float, default=100.0, help="per arm (--random-directions)")
    p.add_argument("--seconds", type=float, default=20.0, help="random directions, measured")
    p.add_argument("--exact-seconds", type=float, default=10.0, help="each exact axis, measured")
    args = p.parse_args()
    if args.random_directions:
        model = args.model or "so101"
        jog = jog_figures(model, args.arms, args.seconds, args.exact_seconds, args.rate_hz)
        if args.json:
            import json

            print(json.dumps({"model": model, "arms": args.arms, model: jog, "machine": machine()}))
        return
    period, every = args.period_ms / 1000, not args.batched_forces
    env = {"TELEROBOT_HOME_POSE": "qn"} if args.model is None else arms_env(1, args.model)
    figures = run_server(env, args.commands, period, every)
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
    if args.arms > 1:
        rounds = max(1, round(args.arms_seconds / args.block_seconds))
        arms = run_arms(
            args.arms,
            args.arms_model,
            args.arms_seconds,
            rounds,
            args.arm_rate_hz,
            args.stagger,
            every,
        )
        print(f"{args.arms} arms ({args.arms_model}) at {args.arm_rate_hz:g} Hz each, one client:")
        emit(arms, False)
        for k in ("p99_ms_per_arm", "p99_ratio_two_vs_one", "p99_ms_one_arm"):
            result[k] = arms[k]
        result["arms"] = arms
        print(f"p99 per arm: {arms['p99_ms_per_arm']}")
    if args.json:
        import json

        print(json.dumps({**result, "machine": machine()}))


if __name__ == "__main__":
    main()
