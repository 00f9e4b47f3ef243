"""A master arm pressing the simulated gripper onto the stiff block, for
bench.master_contact and the tests (tests/test_master.py, tests/test_passivity.py).

The simulated master (a 0.2 kg handle held by a hand that is a spring) drives the
server's simulated arm through the master-arm bridge over its injected round trip (half
on the commands, half on the forces), with the bridge's passivity controller in one of
``MODES``: the two-port, the one-port, none. The hand (``pressing_hand``) grips after
0.5 s 2 cm above the block, goes down at 2 cm/s to 5 mm above it, then at 5 mm/s to
``press_m`` below the block's top, and holds; the block's push is rendered on the
device at 1/20.

- ``one_run``: in real time, against a served server of its own (``press``: against
  one already running), through the priority channel, the bridge's 1 kHz thread.
- ``stepped_run``: the same press in virtual time (``stepped_press``): the server's
  parts, the bridge, the master and the hand on one stepped clock in this process, so
  the same figures on every machine.

Both return the figures bench.master_contact's docstring lists.
"""

from __future__ import annotations

import asyncio
import dataclasses
import secrets
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

import httpx
import numpy as np

from harness.servers import serve_for_bench
from telerobot.client.master.bridge import BridgeSettings, MasterBridge
from telerobot.client.master.cli import CPU_PRIORITY, open_link
from telerobot.client.master.link import Reply
from telerobot.drivers.base import FloatArray, ForceSample, TelerobotError, WorkingFrame
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.force.sim import SimForceSensor
from telerobot.drivers.master.sim import SimMaster
from telerobot.protocol import messages as m
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.devices import (
    build_force_sensor,
    build_robot,
    build_workcell,
    make_kinematics,
)
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.session import FRAMES
from telerobot.server.services import safety_limits
from telerobot.server.settings import Settings
from telerobot.server.telemetry.stats import Telemetry
from telerobot.tuning import thread_priority_raised

FORCE_LIMIT_N = 60.0
START_ABOVE_M = 0.02
SPEED_M_S = 0.02  # the approach, down to SLOW_ABOVE_M above the block's top
SLOW_ABOVE_M = 0.005
SLOW_M_S = 0.005  # then, as a careful operator near a contact (≈ 1 mm per 200 ms)


def pressing_hand(press_m: float) -> Callable[[float], tuple[FloatArray, bool]]:
    """Grips after 0.5 s, goes down at 2 cm/s to 5 mm above the block's top (which is
    2 cm below the start), on at 5 mm/s to ``press_m`` below the top, then holds."""
    fast = START_ABOVE_M - SLOW_ABOVE_M
    t_fast = fast / SPEED_M_S
    depth = START_ABOVE_M + press_m

    def hand(t: float) -> tuple[FloatArray, bool]:
        if t < 0.5:
            return np.zeros(3), False
        s = t - 0.5
        z = SPEED_M_S * s if s < t_fast else fast + SLOW_M_S * (s - t_fast)
        return np.array([0.0, 0.0, -min(z, depth)]), True

    return hand


def band(values: FloatArray, rate_hz: float) -> FloatArray:
    """0.5–20 Hz: the signal minus its 2 s moving average, then a 25 ms moving average."""

    def smooth(x: FloatArray, n: int) -> FloatArray:
        # The mean of the samples within the window, fewer at the ends: a zero-padded
        # average (np.convolve alone) fell to half the force at either end of the hold,
        # and the band then "oscillated" by half the mean force there (a still 20 N
        # press measured 3.4 N).
        n = max(1, min(n, len(x)))
        window = np.ones(n)
        return np.asarray(
            np.convolve(x, window, mode="same") / np.convolve(np.ones(len(x)), window, mode="same"),
            dtype=float,
        )

    return smooth(values - smooth(values, int(2.0 * rate_hz)), int(0.025 * rate_hz))


# What each mode sets in the bridge: (passivity, two_port).
MODES: dict[str, tuple[bool, bool]] = {
    "passivity": (True, True),
    "one_port": (True, False),
    "none": (False, False),
}


def server_settings(stiffness: float, contact_speed: float | None = None) -> dict[str, Any]:
    """The server's settings for the press (a served one gets them as TELEROBOT_*)."""
    settings: dict[str, Any] = {"home_pose": "qn", "block_stiffness_n_m": stiffness}
    if contact_speed is not None:
        settings["contact_speed_m_s"] = contact_speed
    return settings


def server_env(token: str, stiffness: float, contact_speed: float | None = None) -> dict[str, str]:
    return {
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_PRIORITY_PORT": "0",
        **{
            f"TELEROBOT_{name.upper()}": str(value)
            for name, value in server_settings(stiffness, contact_speed).items()
        },
    }


def bridge_settings(rtt_s: float, mode: str, jitter_s: float = 0.0) -> BridgeSettings:
    """The bridge's, for either press: the block's push at 1/20, the injected round trip,
    the passivity ``mode`` (``MODES``)."""
    passivity, two_port = MODES[mode]
    return BridgeSettings(
        force_scale=0.05, passivity=passivity, two_port=two_port, delay_rtt_s=rtt_s,
        delay_jitter_s=jitter_s,
        # "none": the bare loop (no passivity, and no contact damper either)
        contact_damping_n_s_m=BridgeSettings.contact_damping_n_s_m if passivity else 0.0,
    )  # fmt: skip


def press_figures(
    samples: list[tuple[float, float]],
    bridge: MasterBridge,
    moved_master: FloatArray,
    moved_arm: FloatArray,
    depth_m: float,
) -> dict[str, Any]:
    """What either press reports (see the module's text)."""
    return {
        **force_figures(samples),
        "energy_j": bridge.passivity.generated,
        "damped_j": bridge.passivity.dissipated,
        "drift_mm": float(np.linalg.norm(moved_arm - moved_master) * 1000.0),
        "depth_mm": max(0.0, depth_m * 1000.0),  # (for --contact-rule)
    }


def one_run(
    *,
    rtt_s: float,
    passivity: str,
    seconds: float,
    press_m: float,
    hand_stiffness: float,
    stiffness: float,
    jitter_s: float = 0.0,
    contact_speed: float | None = None,
    hand: Callable[[float], tuple[FloatArray, bool]] | None = None,
) -> dict[str, Any]:
    """One press against a server of its own."""
    token = secrets.token_hex(16)
    with serve_for_bench(env=server_env(token, stiffness, contact_speed)) as (_, base):
        return press(
            base, token, rtt_s=rtt_s, passivity=passivity, seconds=seconds, press_m=press_m,
            hand_stiffness=hand_stiffness, jitter_s=jitter_s, hand=hand,
        )  # fmt: skip


def press(base: str, token: str, **kwargs: Any) -> dict[str, Any]:
    """``_press`` with the bridge's threads at the CPU priority ``telerobot master``
    gives them (``--cpu-priority``, 5 nice steps where allowed): on the operator's
    machine the 1 kHz loop runs ahead of its other programs."""
    with thread_priority_raised(CPU_PRIORITY):
        return _press(base, token, **kwargs)


def _press(
    base: str,
    token: str,
    *,
    rtt_s: float,
    passivity: str,
    seconds: float,
    press_m: float,
    hand_stiffness: float,
    jitter_s: float = 0.0,
    hand: Callable[[float], tuple[FloatArray, bool]] | None = None,
) -> dict[str, Any]:
    """One press against the server at ``base``: the tool placed 2 cm above the block,
    then the simulated hand on the master for ``seconds``."""
    api = httpx.Client(
        base_url=base + "api/v1/", headers={"Authorization": f"Bearer {token}"}, timeout=20
    )
    deadline = time.monotonic() + 30
    while api.get("robot/state").json()["status"] != "READY":
        assert time.monotonic() < deadline, "the simulated arm never became ready"
        time.sleep(0.1)
    block = next(b for b in api.get("workcell").json()["boxes"] if b["name"] == "block")
    top = block["centre"][2] + block["size"][2] / 2
    lease = api.post("lease", json={"name": "setup", "force": True}).json()
    api.headers["X-Client-Id"] = lease["client_id"]
    api.post(
        "robot/move",
        json={
            "space": "cartesian",
            "mode": "absolute",
            "position": [*block["centre"][:2], top + START_ABOVE_M],
        },
    ).raise_for_status()
    api.delete("lease")
    start = np.array(api.get("robot/state").json()["position"], dtype=float)
    device = SimMaster(hand or pressing_hand(press_m), hand_stiffness_n_m=hand_stiffness)
    link = open_link(base, token)
    bridge = MasterBridge(device, link, bridge_settings(rtt_s, passivity, jitter_s))
    forces: list[tuple[float, float]] = []  # (sensor time, |F|)
    lock = threading.Lock()

    def keep(sample: ForceSample, received: float) -> None:
        with lock:
            forces.append((sample.time, float(np.linalg.norm(sample.values[:3]))))

    bridge.on_sample = keep
    ticks: list[tuple[float, float]] = []  # (this machine's time, age of the force used)
    tick = bridge.tick

    def timed_tick() -> None:
        tick()
        now = time.monotonic()
        used = bridge._force
        ticks.append((now, now + bridge.link.offset - used.time if used else float("nan")))

    bridge.tick = timed_tick  # type: ignore[method-assign]
    bridge.start()
    p0 = device.position.copy()
    try:
        time.sleep(seconds)
    finally:
        bridge.stop()
        bridge.link.close()
    moved_master = device.position - p0
    end = np.array(api.get("robot/state").json()["position"], dtype=float)
    safety = api.get("safety").json()
    with lock:
        samples = sorted(forces)
    return {
        **press_figures(samples, bridge, moved_master, end - start, top - end[2]),
        "estop_at_end": bool(safety.get("estop")),
        "ping_rtt_ms": bridge.link.best_rtt * 1000.0,
        "force_transport": bridge.link.datagrams,
        # How punctually this machine ran it (tests/test_master.py asserts none of these):
        "forces_per_s": bridge.forces_received / seconds,
        "commands_per_s": bridge.commands_sent / seconds,
        "overruns": bridge.overruns,
        **loop_figures(ticks),
    }


def loop_figures(ticks: list[tuple[float, float]]) -> dict[str, float | None]:
    """How punctually the bridge's loop ran, and how old the force it rendered was."""
    if len(ticks) < 2:
        return {"tick_gap_ms_p99": None, "tick_gap_ms_max": None,
                "force_age_ms_p50": None, "force_age_ms_p99": None}  # fmt: skip
    times = np.array([t for t, _ in ticks])
    gaps = np.diff(times) * 1000.0
    ages = np.array([a for _, a in ticks if np.isfinite(a)]) * 1000.0
    return {
        "tick_gap_ms_p99": float(np.percentile(gaps, 99)),
        "tick_gap_ms_max": float(gaps.max()),
        "force_age_ms_p50": float(np.percentile(ages, 50)) if len(ages) else None,
        "force_age_ms_p99": float(np.percentile(ages, 99)) if len(ages) else None,
    }


class VirtualLink:
    """What ``MasterBridge`` uses of a ``PriorityLink``, for ``stepped_press``: no socket
    and no reader thread. Commands wait in ``commands`` until the loop hands them to the
    DecisionServer; the loop calls ``on_force`` and ``on_state`` itself. Both sides
    are on one clock: no offset."""

    def __init__(self, decision: DecisionServer, client_id: str, now: Callable[[], float]) -> None:
        self.decision = decision
        self.client_id = client_id
        self._now = now
        self.on_force: Callable[[ForceSample, float], None] | None = None
        self.on_state: Callable[[dict[str, Any]], None] | None = None
        self.on_reply: Callable[[Reply], None] | None = None
        self.offset = 0.0
        self.closed_reason: str | None = None
        self.autonomy = "off"  # no policy here (PriorityLink says what the server said)
        # Sent, not yet handled, in order: (seq, send time, dX, rotation vector, frame),
        # or (seq, e_in, e_out) for an ENERGY.
        self.commands: list[
            tuple[int, float, FloatArray, FloatArray, WorkingFrame] | tuple[int, float, float]
        ] = []
        self._seq = 0

    def cartesian(
        self, dX: tuple[float, float, float], rotvec: tuple[float, float, float],
        frame: m.Frame = m.Frame.BASE,
    ) -> int:  # fmt: skip
        self._seq += 1
        self.commands.append(
            (self._seq, self._now(), np.array(dX), np.array(rotvec), FRAMES[frame])
        )
        return self._seq

    def energy(self, e_in: float, e_out: float) -> int:
        self._seq += 1
        self.commands.append((self._seq, e_in, e_out))
        return self._seq

    def heartbeat(self) -> None:
        self.decision.seen(self.client_id)  # what the server does with any message

    async def deliver(self) -> None:
        """Hand what was sent to the DecisionServer, as the priority channel does, and
        its answers back (PORT_ENERGY, ERROR)."""
        sent, self.commands = self.commands, []
        for item in sent:
            try:
                if len(item) == 3:
                    seq, e_in, e_out = item
                    given, out = self.decision.master_energy(self.client_id, e_in, e_out)
                    self._reply("PORT_ENERGY", {"seq": seq, "e_in": given, "e_out": out})
                    continue
                seq, sent_at, dX, rv, frame = item
                await self.decision.cartesian_increment(
                    self.client_id, dX, rv, frame=frame, seq=seq, client_time=sent_at
                )
            except TelerobotError as exc:  # the server's ERROR
                self._reply("ERROR", {"seq": item[0]}, str(exc))

    def _reply(self, name: str, fields: dict[str, Any], text: str = "") -> None:
        if self.on_reply is not None:
            self.on_reply(Reply(name, fields, text))


async def stepped_press(
    *,
    rtt_s: float,
    passivity: str,
    seconds: float,
    press_m: float,
    hand_stiffness: float,
    stiffness: float,
    jitter_s: float = 0.0,
    contact_speed: float | None = None,
    hand: Callable[[float], tuple[FloatArray, bool]] | None = None,
    contact_damping: float | None = None,
) -> dict[str, Any]:
    """``one_run``'s press in virtual time, for tests (and bench.master_contact's ``--virtual``);
    ``contact_damping``: the bridge's contact damper instead of the mode's.

    The same parts: the server's, built from the same settings by the server's own
    builders (the simulated PUMA, the block, the force sensor, the DecisionServer with
    its limits, force limit and dead-man), the same bridge with its injected round trip
    and passivity controller, the same simulated master and hand. All run on one
    ``ManualClock``, stepped 1 ms at a time: the arm moves, the sensor takes a sample
    (to the DecisionServer and the bridge, as the priority channel sends every one),
    STATE goes out every 20 ms as the hub's, the bridge ticks, and its commands are
    applied as the priority channel applies them. No thread, socket or sleep: the
    figures are the same on any machine. What it leaves out is what ``one_run``
    measures on top: how punctually a machine runs the 1 kHz loops (bridge, sensor,
    server), and the real link's transit."""
    settings = Settings(
        robot="sim", force="sim", robot_model="puma560", **server_settings(stiffness, contact_speed)
    )
    clock = ManualClock()
    token = secrets.token_hex(16)
    workcell = build_workcell(settings)
    robot = build_robot(settings, clock)
    sensor = build_force_sensor(settings, robot, workcell)
    assert isinstance(sensor, SimForceSensor)  # sampled here (sample_at), not by its thread
    limits = safety_limits(settings)
    decision = DecisionServer(
        [ArmGuard("arm", 1, robot, make_kinematics(settings), limits, sensor)],
        clock=clock,
        operator_token=token,
        limits=limits,
    )
    hub = RealtimeHub(decision, Telemetry(), clock)  # (only to encode STATE)

    async def until_done(work: Awaitable[Any]) -> None:
        task = asyncio.ensure_future(work)
        while not task.done():
            await clock.advance(0.01)
        task.result()

    await robot.connect()
    await until_done(robot.initialize())
    # The tool 2 cm above the block's middle, as ``press`` puts it (a REST client's
    # move, before the dead-man runs: this client says nothing while the arm moves).
    top = float(workcell.block.upper[2])
    setup = decision.join("setup", token, source="rest")
    await decision.take_lease(setup.id)
    above = np.array([*workcell.block.centre[:2], top + START_ABOVE_M])
    await decision.move_pose(setup.id, above, robot.pose.rotation)
    await until_done(robot.wait_idle())
    await decision.release_lease(setup.id)
    start = robot.pose.position.copy()
    decision.start()  # the force limit and the dead-man, as in the server
    try:
        client = decision.join("master", token, source="priority")
        await decision.take_lease(client.id)  # (the bridge's LEASE TAKE)
        link = VirtualLink(decision, client.id, clock.now)
        device = SimMaster(
            hand or pressing_hand(press_m), hand_stiffness_n_m=hand_stiffness,
            time_source=clock.now,
        )  # fmt: skip
        settings_ = bridge_settings(rtt_s, passivity, jitter_s)
        if contact_damping is not None:
            settings_ = dataclasses.replace(settings_, contact_damping_n_s_m=contact_damping)
        # (a VirtualLink has all of a PriorityLink that the bridge uses)
        bridge = MasterBridge(device, link, settings_, time_source=clock.now)  # type: ignore[arg-type]
        forces: list[tuple[float, float]] = []
        bridge.on_sample = lambda s, _: forces.append((s.time, float(np.linalg.norm(s.values[:3]))))

        def to_bridge(sample: ForceSample) -> None:
            if link.on_force is not None:
                link.on_force(sample, clock.now())

        sensor.subscribe(to_bridge)
        device.open()
        p0 = device.position.copy()
        period = 1.0 / settings_.rate_hz
        state_every = round(hub.state_period / period)
        for n in range(round(seconds / period)):
            await clock.advance(period)
            sensor.sample_at(clock.now())
            if n % state_every == 0 and link.on_state is not None:
                link.on_state(m.decode(hub.encode_state_for(client.id, True))[1])
            bridge.tick()
            await link.deliver()
        end = robot.pose.position.copy()
        return {
            **press_figures(forces, bridge, device.position - p0, end - start, top - end[2]),
            "estop_at_end": decision.state().estop,
            "ping_rtt_ms": 0.0,
            "force_transport": "virtual",
        }
    finally:
        await decision.stop()
        await robot.disconnect()


def stepped_run(**kwargs: Any) -> dict[str, Any]:
    """``stepped_press`` from synchronous code: the same keywords as ``one_run``."""
    return asyncio.run(stepped_press(**kwargs))


def force_figures(samples: list[tuple[float, float]]) -> dict[str, Any]:
    """Peak, trips and the oscillation over the hold, from (sensor time, |F|) samples
    resampled to 1 kHz (a lossy link delivers fewer, and a thinned stream fewer still)."""
    if len(samples) < 2:
        return {"peak_n": 0.0, "limit_trips": 0, "oscillation": 0.0, "crossings_hz": 0.0,
                "contact_s": 0.0, "lift_offs": 0, "mean_force_n": 0.0,
                "samples": len(samples)}  # fmt: skip
    t = np.array([s for s, _ in samples])
    f = np.array([v for _, v in samples])
    grid = np.arange(t[0], t[-1], 0.001)
    g = np.interp(grid, t, f)
    touching = np.nonzero(g > 1.0)[0]
    hold = g[touching[0] + 1000 :] if len(touching) else np.array([])
    b = band(hold, 1000.0) if len(hold) > 100 else np.zeros(1)
    crossings = np.sum(np.signbit(b[1:]) != np.signbit(b[:-1])) if len(b) > 1 else 0
    pressed = g[touching[0] :] > 1.0 if len(touching) else np.zeros(0, dtype=bool)
    above = f > FORCE_LIMIT_N  # (trips from the samples themselves: no made-up crossings)
    return {
        "peak_n": float(f.max()),
        "limit_trips": int(np.sum(above[1:] & ~above[:-1]) + int(above[0])),
        "oscillation": float(np.sqrt(np.mean(b**2))),
        "crossings_hz": float(crossings / (len(hold) / 1000.0)) if len(hold) else 0.0,
        "contact_s": float(grid[-1] - grid[touching[0]]) if len(touching) else 0.0,
        "lift_offs": int(np.sum(pressed[:-1] & ~pressed[1:])),  # after the first contact
        "mean_force_n": float(np.mean(hold)) if len(hold) else 0.0,
        "samples": len(samples),
    }
