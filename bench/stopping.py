"""Stopping time and distance after the link to the operator is lost.

Starts ``telerobot serve`` on the simulation as its own process (state at 1 kHz, no
video). For every pose, speed and way of losing the link, an operator client takes
control over ``/ws`` and drives the tool in a straight line at that speed (100
Cartesian increments a second, as a gamepad does) for 0.5 s; then its link is lost:

* ``kill``: the connection closes when the next command was due, as when the
  client's process is SIGKILLed (the server sees the socket close: the lease lapses);
* ``silent``: the client just stops sending with its socket open (a frozen client
  or a dead network): the dead-man lapses the lease after 150 ms.

An observer receives every STATE (server time, joints, tool position) and EVENT.
Figures, medians over ``--repeats`` runs:

* ``time_s``: from the server taking the last command to the arm at rest;
* ``distance_m``: how far the tool moved in that time (straight line);
* ``stop_s``: from the lease lapsing (the stop) to the arm at rest (negative: the
  arm had reached its last target, at rest, before the dead-man lapsed the lease);
* ``stated_stop``: what GET /api/v1/safety states for that speed at that pose, worst
  direction, for the stop alone (from the lapse).

"at rest" is the first state after which no joint moves by more than 10 µrad.
Then ``max``: a scripted joint move at the arm's full speed (joint 1 at 1 rad/s)
stopped by the e-stop (POST /api/v1/safety/estop), timed from the e-stop.

Then ``val_serial_stop_s``: the VAL serial driver (``ValSerialPuma``) against its
controller emulator in this process, over a pseudo-terminal and over TCP (9600 baud,
moves at a quarter of their real time): joint 1 cruising on a 2.5 rad increment, from
``stop()`` (ABORT on the wire) to the driver idle at where the arm braked to, median
over the repeats (tests/test_val_serial.py asserts that it stops short, not this time).

    python -m bench.stopping [--json] [--repeats 3]

The baseline (``BASELINE``) was measured with this bench before the stop decelerated
at the arm's limit (it braked at the 2 rad/s² planning acceleration, joints apart).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import secrets
import statistics
import time
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np

from bench.common import emit, machine, parser
from harness.servers import serve_for_bench
from harness.wsclient import RealtimeClient
from telerobot.protocol import messages as m

PERIOD_S = 0.01  # one command every 10 ms
DRIVE_S = 0.5  # driven this long before the link is lost
WATCH_S = 1.5  # states watched after the last command
REST_RAD = 1e-5  # "at rest": no joint moves more than this afterwards


@dataclass(frozen=True)
class Pose:
    name: str
    joints: tuple[float, ...]
    direction: tuple[float, float, float]  # base frame


QN = (0.0, math.pi / 4, -math.pi, 0.0, math.pi / 4, 0.0)
POSES = (
    Pose("qn_sideways", QN, (0, 1, 0)),  # joints 1, 4, 6 turn (0.4-0.6 rad/s at 0.25 m/s)
    Pose("low_reaching_out", (0.5, 0.9, -2.6, 0.3, 0.5, 0.0), (1, 0, 0)),  # the elbow, 1 rad/s
)
SPEEDS = (0.05, 0.1, 0.25)
MODES = ("kill", "silent")

# Before the stop braked at the drives' limit: (time_s, distance_m), the medians of
# 3 runs of this bench (3 repeats each) on the code of commit 683b878, interleaved
# with the runs after the change on the same machine.
BASELINE: dict[str, tuple[float, float]] = {
    "qn_sideways/0.05/kill": (0.0563, 0.00155),
    "qn_sideways/0.05/silent": (0.0562, 0.00144),
    "qn_sideways/0.1/kill": (0.1031, 0.00537),
    "qn_sideways/0.1/silent": (0.1032, 0.00500),
    "qn_sideways/0.25/kill": (0.2381, 0.02922),
    "qn_sideways/0.25/silent": (0.2231, 0.02746),
    "low_reaching_out/0.05/kill": (0.1324, 0.00342),
    "low_reaching_out/0.05/silent": (0.1321, 0.00314),
    "low_reaching_out/0.1/kill": (0.2710, 0.01461),
    "low_reaching_out/0.1/silent": (0.2571, 0.01139),
    "low_reaching_out/0.25/kill": (0.5471, 0.06658),
    "low_reaching_out/0.25/silent": (0.7001, 0.07259),
    "max/joint1_full_speed/estop": (0.5375, 0.17786),
}


class Observer:
    """Every STATE and EVENT the server sends, with its server time."""

    def __init__(self, client: RealtimeClient) -> None:
        self.client = client
        self.states: list[tuple[float, np.ndarray, np.ndarray]] = []  # time, joints, position
        self.events: list[tuple[float, int, str]] = []
        self._task = asyncio.create_task(self._run())

    async def _run(self) -> None:
        while True:
            data = await self.client.ws.recv()
            if data[0] == m.STATE.type_id:
                _, f, _ = m.decode(data)
                q = np.array(f["joints"])
                p = np.array([f["x"], f["y"], f["z"]])
                self.states.append((float(f["server_time"]), q, p))
            elif data[0] == m.EVENT.type_id:
                _, f, text = m.decode(data)
                self.events.append((float(f["server_time"]), int(f["kind"]), text))

    def mark(self) -> int:
        return len(self.states)

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        await self.client.close()


def at_rest(states: list[tuple[float, np.ndarray, np.ndarray]], after: float) -> int:
    """Index of the first state after ``after`` from which no joint moves any more."""
    final = states[-1][1]
    i = len(states) - 1
    while (
        i > 0 and states[i - 1][0] > after and np.max(np.abs(states[i - 1][1] - final)) < REST_RAD
    ):
        i -= 1
    return i


def state_at(
    states: list[tuple[float, np.ndarray, np.ndarray]], t: float
) -> tuple[float, np.ndarray, np.ndarray]:
    """The last state at or before ``t``."""
    best = states[0]
    for s in states:
        if s[0] > t:
            break
        best = s
    return best


class Bench:
    def __init__(self, base: str, token: str) -> None:
        self.base = base
        self.url = base.replace("http://", "ws://") + "ws"
        self.token = token
        self.http = httpx.AsyncClient(base_url=base + "api/v1/", timeout=30.0)
        self.auth = {"Authorization": f"Bearer {token}"}

    async def wait_ready(self) -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if (await self.http.get("robot/state")).json()["status"] == "READY":
                return
            await asyncio.sleep(0.1)
        raise RuntimeError("the simulated arm did not become READY within 60 s")

    async def lease(self) -> dict[str, str]:
        r = await self.http.post("lease", json={"name": "bench"}, headers=self.auth)
        r.raise_for_status()
        return {**self.auth, "X-Client-Id": r.json()["client_id"]}

    async def move_to(self, joints: tuple[float, ...]) -> dict[str, Any]:
        """Move there by a scripted move; returns GET /api/v1/safety at that pose. On a
        busy machine the lease may lapse between the two requests: then again."""
        for attempt in range(3):
            h = await self.lease()
            r = await self.http.post(
                "robot/move",
                json={"space": "joint", "mode": "absolute", "joints": list(joints)},
                headers=h,
            )
            await self.http.request("DELETE", "lease", headers=h)
            if r.status_code == 200:
                break
            if attempt == 2:
                r.raise_for_status()
        await asyncio.sleep(0.1)
        safety: dict[str, Any] = (await self.http.get("safety")).json()
        return safety

    async def link_loss(
        self, obs: Observer, pose: Pose, speed: float, mode: str
    ) -> dict[str, float]:
        op = await RealtimeClient.connect(self.url, token=self.token)
        await op.take_lease()
        step = np.array(pose.direction, dtype=float) * speed * PERIOD_S
        last_applied = 0.0
        next_send = time.monotonic()
        for _ in range(round(DRIVE_S / PERIOD_S)):
            seq = op.next_seq()
            await op.ws.send(
                m.encode(m.CART_INC, seq, time.monotonic(), m.Frame.BASE, *step, 0.0, 0.0, 0.0)
            )
            ack = await op.expect(m.ACK)
            last_applied = float(ack["server_time"])
            next_send += PERIOD_S
            await asyncio.sleep(max(0.0, next_send - time.monotonic()))
        if mode == "kill":
            op.ws.transport.abort()  # as the kernel does for a SIGKILLed process
        await asyncio.sleep(WATCH_S)
        if mode == "silent":
            op.ws.transport.abort()
        states = [s for s in obs.states if s[0] >= last_applied - 0.1]
        rest = states[at_rest(states, last_applied)]
        at_last = state_at(states, last_applied)
        before = state_at(states, last_applied - 0.05)
        lapse = next(
            (
                t
                for t, kind, text in obs.events
                if t >= last_applied and kind == m.EventKind.SAFETY and "nobody" in text
            ),
            float("nan"),
        )
        return {
            "time_s": rest[0] - last_applied,
            "distance_m": float(np.linalg.norm(rest[2] - at_last[2])),
            "stop_s": rest[0] - lapse,
            "lapse_s": lapse - last_applied,
            "speed_reached_m_s": float(
                np.linalg.norm(at_last[2] - before[2]) / max(at_last[0] - before[0], 1e-6)
            ),
        }

    async def full_speed_estop(self, obs: Observer, pose: Pose) -> dict[str, float]:
        """Joint 1 at its full speed (1 rad/s), stopped by the e-stop."""
        h = await self.lease()

        async def heartbeat() -> None:  # a move that does not wait keeps no lease alive
            while True:
                await self.http.post("lease/heartbeat", headers=h)
                await asyncio.sleep(0.04)

        beating = asyncio.create_task(heartbeat())
        try:
            target = list(pose.joints)
            target[0] += 1.4
            r = await self.http.post(
                "robot/move",
                json={"space": "joint", "mode": "absolute", "joints": target, "wait": False},
                headers=h,
            )
            r.raise_for_status()
            await asyncio.sleep(1.0)  # 0.5 s to reach 1 rad/s, then cruising
            events = len(obs.events)
            await self.http.post("safety/estop", json={})
            await asyncio.sleep(WATCH_S)
            estop = next(
                t for t, kind, text in obs.events[events:]
                if kind == m.EventKind.SAFETY and "E-STOP" in text
            )  # fmt: skip
            states = [s for s in obs.states if s[0] >= estop - 0.1]
            rest = states[at_rest(states, estop)]
            at_stop = state_at(states, estop)
            prior = state_at(states, estop - 0.02)
            await self.http.post("safety/reset", headers=h)
        finally:
            beating.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await beating
        await self.http.request("DELETE", "lease", headers=h)
        return {
            "time_s": rest[0] - estop,
            "joint1_rad": float(abs(rest[1][0] - at_stop[1][0])),
            "distance_m": float(np.linalg.norm(rest[2] - at_stop[2])),
            "joint1_speed_rad_s": float(
                abs(at_stop[1][0] - prior[1][0]) / max(at_stop[0] - prior[0], 1e-6)
            ),
        }

    async def run(self, repeats: int) -> dict[str, Any]:
        await self.wait_ready()
        obs = Observer(await RealtimeClient.connect(self.url))
        results: dict[str, Any] = {}
        predicted: dict[str, Any] = {}
        try:
            for pose in POSES:
                for speed in SPEEDS:
                    for mode in MODES:
                        runs = []
                        for _ in range(repeats):
                            safety = await self.move_to(pose.joints)
                            runs.append(await self.link_loss(obs, pose, speed, mode))
                        key = f"{pose.name}/{speed:g}/{mode}"
                        results[key] = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
                        stated = next(
                            (
                                s
                                for s in safety.get("stopping", [])
                                if abs(s["speed_m_s"] - speed) < 1e-9
                            ),
                            None,
                        )
                        if stated is not None:
                            predicted[f"{pose.name}/{speed:g}"] = stated
                            results[key]["predicted_time_s"] = stated["time_s"]
                            results[key]["predicted_distance_m"] = stated["distance_m"]
                        print(key, {k: round(v, 4) for k, v in results[key].items()}, flush=True)
            runs = []
            for _ in range(repeats):
                await self.move_to(POSES[0].joints)
                runs.append(await self.full_speed_estop(obs, POSES[0]))
            results["max/joint1_full_speed/estop"] = {
                k: statistics.median(r[k] for r in runs) for k in runs[0]
            }
            print("max", results["max/joint1_full_speed/estop"], flush=True)
            safety = (await self.http.get("safety")).json()
        finally:
            await obs.close()
            await self.http.aclose()
        return {"results": results, "predicted": predicted, "safety": safety}


async def val_serial_stop_s(make_link: str) -> float:
    """stop() → idle of the VAL serial driver on its emulator, joint 1 cruising."""
    from telerobot.drivers.base import SerialSettings
    from telerobot.drivers.robot.puma560.kinematics import NAMED_POSES
    from telerobot.drivers.robot.puma560.val_emulator import EmulatorLink, ValControllerEmulator
    from telerobot.drivers.robot.puma560.val_serial import ValSerialPuma

    emulator = ValControllerEmulator(list(np.degrees(NAMED_POSES["qn"])), time_scale=0.25)
    with getattr(EmulatorLink, make_link)(emulator) as link:
        robot = ValSerialPuma(SerialSettings(port=link.url, reply_timeout=1.0, move_margin=0.5))
        await robot.connect()
        await robot.initialize()
        try:
            await robot.move_joints(np.array([2.5, 0, 0, 0, 0, 0]), relative=True)
            await asyncio.sleep(0.3)
            t0 = time.monotonic()
            await robot.stop()
            await robot.wait_idle(timeout=5)
            return time.monotonic() - t0
        finally:
            await robot.disconnect()


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_HOME_POSE": "qn",
        "TELEROBOT_STATE_RATE_HZ": "1000",
        "TELEROBOT_VIDEO": "false",
    }
    with serve_for_bench(env=env) as (_, base):
        out = asyncio.run(Bench(base, token).run(args.repeats))
    results = out["results"]
    val_stop = {
        where: statistics.median(
            asyncio.run(val_serial_stop_s(f"on_{where}")) for _ in range(args.repeats)
        )
        for where in ("pty", "tcp")
    }
    emit({f"val_serial_stop_ms {k}": v * 1000 for k, v in val_stop.items()}, False)
    summary: dict[str, dict[str, float]] = {}
    for key, r in results.items():
        row = {"time_ms": r["time_s"] * 1000, "distance_mm": r["distance_m"] * 1000}
        if "stop_s" in r:
            row["stop_ms"] = r["stop_s"] * 1000
        if "predicted_time_s" in r:
            row["stated_stop_ms"] = r["predicted_time_s"] * 1000
            row["stated_stop_mm"] = r["predicted_distance_m"] * 1000
        if key in BASELINE:
            base_time_s, base_distance_m = BASELINE[key]
            row["baseline_time_ms"] = base_time_s * 1000
            row["baseline_distance_mm"] = base_distance_m * 1000
            row["time_ratio"] = r["time_s"] / base_time_s
            row["distance_ratio"] = r["distance_m"] / base_distance_m
        summary[key] = {k: round(v, 3) for k, v in row.items()}
    emit({f"{k} {f}": v for k, row in summary.items() for f, v in row.items()}, False)
    if args.json:
        print(
            json.dumps(
                {
                    "stopping": summary,
                    "details": results,
                    "stop_category": out["safety"].get("stop_category"),
                    "stated": out["safety"].get("stopping"),
                    "val_serial_stop_s": val_stop,
                    "machine": machine(),
                    "repeats": args.repeats,
                }
            )
        )


if __name__ == "__main__":
    main()
