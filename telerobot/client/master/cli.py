"""``telerobot master``: the master-arm bridge as a command.

A leader arm (``--device <name>-leader``) is mirrored joint for joint; on a server that
drives two arms (docs/arms.md) two leaders are, each into its own arm, each on its own
bus and calibration, named by the arm (``--leader-port left=/dev/ttyACM0
--leader-port right=/dev/ttyACM1``), over one link and one lease."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import signal
import sys
import threading
from dataclasses import dataclass

import httpx
import numpy as np

from telerobot.client import local_url, stored_token
from telerobot.client.master.bridge import BridgeSettings, MasterBridge
from telerobot.client.master.joints import JointMirrors
from telerobot.client.master.link import PriorityLink, open_link
from telerobot.drivers.base import FloatArray, MasterArm, TelerobotError
from telerobot.drivers.registry import driver_names, load_driver
from telerobot.protocol.names import client_name


def demo_hand(t: float) -> tuple[FloatArray, bool]:
    """The simulated operator: after 1 s, grips and draws a 3 cm circle every 5 s."""
    if t < 1.0:
        return np.zeros(3), False
    a = 2 * math.pi * 0.2 * (t - 1.0)
    return np.array([0.03 * (math.cos(a) - 1.0), 0.03 * math.sin(a), 0.0]), True


CPU_PRIORITY = 5  # nice steps the bridge raises itself by (as the server: cpu_priority)
LEADER_PORT = "/dev/ttyACM1"  # a leader's bus unless said (the follower's is ttyACM0)
ARM_NAME = re.compile(r"[A-Za-z0-9_-]{1,32}")  # as the server's settings take them
# Leaders with no bus and no calibration (scripted): any number may share the options.
BUSLESS_LEADERS = frozenset({"sim"})


def add_arguments(p: argparse.ArgumentParser) -> None:
    # The server and the token are named as for `telerobot move` and the Python client.
    p.add_argument(
        "--url",
        "--server",
        dest="server",
        help="the server (default: TELEROBOT_URL or http://localhost:8000); the bridge asks"
        " it where its priority channel listens",
    )
    p.add_argument(
        "--token",
        help="operator token (default: TELEROBOT_OPERATOR_TOKEN, else the one the server"
        " keeps on this machine; none: watch only)",
    )
    p.add_argument(
        "--name",
        help="the name others see for this bridge while it has control (default: master"
        " DEVICE; 1–64 letters, digits, spaces and . , : _ - @ # + / ')",
    )
    p.add_argument(
        "--device",
        default="sim",
        choices=[*driver_names("master"), *(f"{n}-leader" for n in driver_names("leader"))],
        help="a haptic master (sim, touch) or a leader arm mirrored joint for joint"
        " (so101-leader: the SO-101 leader on --leader-port; sim-leader: a scripted one)",
    )
    p.add_argument(
        "--leader-port",
        action="append",
        metavar="[ARM=]PORT",
        help=f"so101-leader: its servo bus (a device, a pty or socket://host:port; default"
        f" {LEADER_PORT}). Two leaders for a server's two arms: one each, named by the arm"
        " it drives (--leader-port left=/dev/ttyACM0 --leader-port right=/dev/ttyACM2)",
    )
    p.add_argument("--leader-baudrate", type=int, default=1_000_000)
    p.add_argument(
        "--leader-calibration",
        action="append",
        metavar="[ARM=]FILE",
        help="so101-leader: its joint calibration (JSON; default: the file `telerobot"
        " so101-calibrate --leader` writes). Two leaders: one each, named by arm"
        " (--leader-calibration left=left-leader.json), as `so101-calibrate --leader"
        " --out FILE` recorded them",
    )
    p.add_argument(
        "--arm",
        action="append",
        metavar="NAME",
        help="on a server that drives two arms or more (GET /api/v1/robot/arms): the arm"
        " this device drives (a haptic master, or one leader on --leader-port PORT);"
        " sim-leader: once per arm, a scripted leader for each",
    )
    p.add_argument(
        "--align-deg",
        type=float,
        default=8.6,
        help="a leader: every joint this near the arm's before the arm follows",
    )
    p.add_argument("--motion-scale", type=float, default=1.0, help="robot m per device m")
    p.add_argument("--force-scale", type=float, default=0.05, help="device N per remote N")
    p.add_argument("--no-force", action="store_true", help="do not render the remote force")
    p.add_argument("--alpha", type=float, default=0.0, help="compensation α (N·s/m)")
    p.add_argument("--beta", type=float, default=0.0, help="compensation β (kg)")
    p.add_argument("--no-compensation", action="store_true")
    p.add_argument("--virtual-delay-ms", type=float, default=0.0, help="constant force delay")
    p.add_argument(
        "--passivity",
        choices=("on", "one-port", "off"),
        default="on",
        help="keep the contact passive: on both sides of the link (on: the handle is damped"
        " when a delayed contact would push back more energy than was put in, and the arm"
        " puts into a contact no more than the operator put in), at the master only"
        " (one-port), or not at all",
    )
    p.add_argument(
        "--max-damping",
        type=float,
        default=BridgeSettings.max_damping_n_s_m,
        help="the passivity damper's cap (N·s/m)",
    )
    p.add_argument(
        "--contact-damping",
        type=float,
        default=BridgeSettings.contact_damping_n_s_m,
        help="a damper on the handle while in contact (N·s/m at the device; 0: none): it"
        " stills a contact that a delayed link would keep ringing",
    )
    p.add_argument(
        "--delay-ms",
        type=float,
        default=0.0,
        help="add this round trip inside the bridge (testing: half out, half back)",
    )
    p.add_argument("--delay-jitter-ms", type=float, default=0.0, help="σ of each half's jitter")
    p.add_argument("--command-rate", type=float, default=100.0, help="commands per second")
    p.add_argument("--take-over", action="store_true", help="take control from whoever has it")
    p.add_argument(
        "--cpu-priority",
        type=int,
        default=CPU_PRIORITY,
        help="nice steps to raise the bridge's 1 kHz loop by, where allowed (root or"
        " CAP_SYS_NICE; 0: as started)",
    )
    p.add_argument(
        "--forces",
        choices=("udp", "tcp"),
        default="udp",
        help="forces as UDP datagrams (a lost one is lost, not late; TCP if none arrive)"
        " or on the TCP channel",
    )


@dataclass(frozen=True)
class LeaderPlan:
    """One leader to mirror: into which arm (its name; "": a one-arm server's arm), read
    from which bus, with which calibration (None: the driver's default)."""

    arm: str
    port: str
    calibration: str | None


def _by_arm(values: list[str] | None, option: str) -> tuple[str | None, dict[str, str]]:
    """``[ARM=]VALUE`` options: the one value without an arm (or None), and the named ones."""
    plain: list[str] = []
    named: dict[str, str] = {}
    for value in values or []:
        name, eq, rest = value.partition("=")
        if eq and rest and ARM_NAME.fullmatch(name):
            if name in named:
                raise TelerobotError(f"{option}: {name} is given twice")
            named[name] = rest
        else:
            plain.append(value)
    if len(plain) > 1:
        raise TelerobotError(
            f"{option}: {len(plain)} given without their arms: name each one's"
            f" ({option} left=… {option} right=…)"
        )
    return (plain[0] if plain else None), named


def plan_leaders(
    kind: str,
    ports: list[str] | None,
    calibrations: list[str] | None,
    arms: list[str] | None,
    server_arms: list[str],
) -> list[LeaderPlan]:
    """Which leaders to mirror into which of the server's arms (``server_arms``: their
    names, in order), from the command line's options; a ``TelerobotError`` saying what
    to give when they do not add up."""
    port, port_of = _by_arm(ports, "--leader-port")
    calibration, calibration_of = _by_arm(calibrations, "--leader-calibration")
    chosen = list(dict.fromkeys([*port_of, *(arms or [])]))
    listed = ", ".join(server_arms)
    for name in (*chosen, *calibration_of):
        if name not in server_arms:
            raise TelerobotError(f"the server has no arm {name!r}: it drives {listed}")
    for name in calibration_of:
        if chosen and name not in chosen:
            raise TelerobotError(f"--leader-calibration {name}=…: no leader drives {name}")
    if not chosen:
        if len(server_arms) > 1:
            a, b = server_arms[:2]
            raise TelerobotError(
                f"the server drives {len(server_arms)} arms ({listed}): give each leader"
                f" the bus of its arm (--leader-port {a}=PORT --leader-port {b}=PORT, and"
                f" --leader-calibration {a}=FILE …), or choose the arm of one leader"
                " (--arm NAME)"
            )
        only = server_arms[0]
        return [LeaderPlan("", port or LEADER_PORT, calibration_of.get(only, calibration))]
    if len(chosen) == 1:
        arm = chosen[0]
        return [
            LeaderPlan(
                arm, port_of.get(arm, port or LEADER_PORT), calibration_of.get(arm, calibration)
            )
        ]
    plans = [
        LeaderPlan(arm, port_of.get(arm, port or LEADER_PORT), calibration_of.get(arm))
        for arm in chosen
    ]
    if kind in BUSLESS_LEADERS:
        return plans
    for i, plan in enumerate(plans):
        for other in plans[:i]:
            if other.port == plan.port:
                raise TelerobotError(
                    f"the {other.arm} and {plan.arm} leaders would read one bus ({plan.port}):"
                    f" give each its own (--leader-port {other.arm}=PORT"
                    f" --leader-port {plan.arm}=PORT)"
                )
    missing = [plan.arm for plan in plans if plan.calibration is None]
    if missing or calibration is not None:
        raise TelerobotError(
            "each leader has its own calibration (its zeros are its own): give one for"
            f" each arm, {' '.join(f'--leader-calibration {p.arm}=FILE' for p in plans)}"
            " (`telerobot so101-calibrate --leader --out FILE` records one)"
        )
    return plans


def run_leader(args: argparse.Namespace, token: str) -> int:
    """Leader arms mirrored joint for joint (``--device <name>-leader``): one, or one
    for each of the server's arms."""
    from telerobot.client.master.joints import JointMirror, MirrorSettings
    from telerobot.drivers.robot.models import load_model

    base = args.server if args.server.endswith("/") else args.server + "/"
    kind = args.device.removesuffix("-leader")
    link = None
    lines: list[str] = []
    try:
        try:
            server_arms = httpx.get(base + "api/v1/robot/arms", timeout=5, verify=False)
            server_arms.raise_for_status()
            names = [str(a["name"]) for a in server_arms.json()]
        except (httpx.HTTPError, ValueError, KeyError, TypeError) as exc:
            raise TelerobotError(f"cannot ask {base} for its arms: {exc}") from None
        plans = plan_leaders(
            kind, args.leader_port, args.leader_calibration, args.arm, server_arms=names
        )
        built = []
        for plan in plans:
            query = {"arm": plan.arm} if plan.arm else {}
            try:
                described = httpx.get(
                    base + "api/v1/robot/model", params=query, timeout=5, verify=False
                ).json()
                model = load_model(str(described["model"]))
            except (httpx.HTTPError, ValueError, KeyError, TypeError) as exc:
                raise TelerobotError(f"cannot ask {base} for its arm's model: {exc}") from None
            leader = load_driver("leader", kind).from_options(
                model,
                port=plan.port,
                baudrate=args.leader_baudrate,
                calibration=plan.calibration,
            )
            built.append((plan, model, leader))
        link = open_link(args.server, token, datagrams=False, name=args.name)  # no forces
        settings = MirrorSettings(align_rad=math.radians(args.align_deg)).check()
        mirrors = []
        several = len(link.arms) > 1
        for plan, model, leader in built:
            mirror = JointMirror(leader, link, model.joint_names, settings, arm=plan.arm or 0)
            # Why the arm is as it is, should it be in ERROR already: STATE carries only
            # its status, and the EVENT that said why came before this client joined.
            with contextlib.suppress(httpx.HTTPError, ValueError, KeyError, TypeError):
                query = {"arm": plan.arm} if plan.arm else {}
                arm = httpx.get(
                    base + "api/v1/robot/state", params=query, timeout=5, verify=False
                ).json()
                mirror.arm_message = f"{arm['status']}: {arm['message']}"
            mirrors.append(mirror)
            onto = f"{plan.arm} {model.title}" if several else model.title
            lines.append(f"Leader {leader.name} mirrored onto the {onto}")
        group = JointMirrors(mirrors)
        group.start(take_control=bool(token), take_over=args.take_over)
    except TelerobotError as exc:
        print(f"telerobot master: {exc}", file=sys.stderr)
        if link is not None:
            link.close()
        return 1
    role = "operator" if link.operator else "observer (no token: watching only)"
    for line in lines:
        print(f"{line} at {args.server} as {role}", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with contextlib.suppress(KeyboardInterrupt):
        while not stop.wait(1.0):
            print(_leaders_status(group), flush=True)
    group.stop()
    group.link.close()
    return 0


def _leaders_status(group: JointMirrors) -> str:
    """The leaders' status line: control, commands, each mirror's state and errors."""
    said = [
        f"{mirror.arm_name}: {mirror.status}" if mirror.arm_name else mirror.status
        for mirror in group.mirrors
    ]
    errors = [
        f"{mirror.arm_name + ' ' if mirror.arm_name else ''}last error: {mirror.last_error}"
        for mirror in group.mirrors
        if mirror.last_error
    ]
    if group.last_error:
        errors.append(f"last error: {group.last_error}")
    return (
        f"control {'yes' if group.has_control else 'no '}"
        f" · commands {group.commands_sent} · "
        + " · ".join(said)
        + _supervision(group.link.autonomy, clutch=False)
        + "".join(f" · {e}" for e in errors)
    )


def _supervision(mode: str, clutch: bool = True) -> str:
    """A policy's supervision on the status line (lerobot's DAgger names), and what the
    clutch does now (a leader has none: started, it takes over; stopped, it hands back)."""
    take = " (grip the clutch to take over)" if clutch else ""
    said = {
        "autonomous": f" · AUTONOMOUS: a policy drives{take}",
        "paused": f" · PAUSED: the policy holds still{take}",
        "correcting": " · CORRECTING: an operator drives"
        + (" (let go 0.6 s to hand back)" if clutch else ""),
    }
    return said.get(mode, "")


def master_arm(link: PriorityLink, arms: list[str] | None) -> int:
    """The arm a haptic master drives (its index; 0 on a one-arm server unless named)."""
    if arms and len(arms) > 1:
        raise TelerobotError(f"--arm: a haptic master drives one arm, not {', '.join(arms)}")
    if arms:
        return link.arm_index(arms[0])
    if len(link.arms) > 1:
        raise TelerobotError(
            f"the server drives {len(link.arms)} arms ({', '.join(link.arm_names)}): choose"
            " the one this master drives (--arm NAME)"
        )
    return 0


def run(args: argparse.Namespace) -> int:
    from telerobot.tuning import raise_thread_priority, tune_for_realtime

    tune_for_realtime()  # a short GIL switch interval: the reader thread gets each sample at once
    # Before any thread starts (they inherit it): the 1 kHz loop and the force reader
    # ahead of the machine's other programs, as the server raises itself. With a core
    # busy at the same priority, the loop's ticks came late and a hard contact rang.
    niceness = os.getpriority(os.PRIO_PROCESS, 0)
    if args.cpu_priority > 0 and raise_thread_priority(args.cpu_priority) == niceness > -20:
        print(
            "telerobot master: running at the CPU priority it was started with: raising it"
            " needs root or CAP_SYS_NICE (--cpu-priority 0 silences this)",
            file=sys.stderr,
        )
    args.server = args.server or local_url()
    token = args.token or stored_token() or ""
    try:  # refused here, before anything connects, rather than by the server
        args.name = client_name(args.name if args.name is not None else f"master {args.device}")
    except TelerobotError as exc:
        print(f"telerobot master: --name: {exc}", file=sys.stderr)
        return 2
    if args.device.endswith("-leader"):
        return run_leader(args, token)
    try:
        settings = BridgeSettings(
            command_rate_hz=args.command_rate,
            motion_scale=args.motion_scale,
            render_force=not args.no_force,
            force_scale=args.force_scale,
            compensation=not args.no_compensation,
            alpha=args.alpha,
            beta=args.beta,
            virtual_delay_s=args.virtual_delay_ms / 1000.0,
            passivity=args.passivity != "off",
            two_port=args.passivity == "on",
            max_damping_n_s_m=args.max_damping,
            contact_damping_n_s_m=args.contact_damping,
            delay_rtt_s=args.delay_ms / 1000.0,
            delay_jitter_s=args.delay_jitter_ms / 1000.0,
        ).check()
        cls = load_driver("master", args.device)
        device: MasterArm = cls(demo_hand) if args.device == "sim" else cls()
        udp = args.forces == "udp"
        link = open_link(args.server, token, datagrams=udp, name=args.name)
        try:
            arm = master_arm(link, args.arm)
        except TelerobotError:
            link.close()
            raise
        # A server restart or a cut: connect again (with backoff) rather than exit.
        bridge = MasterBridge(
            device,
            link,
            settings,
            reconnect=lambda: open_link(args.server, token, datagrams=udp, name=args.name),
            arm=arm,
        )
        bridge.start(take_control=bool(token), take_over=args.take_over)
    except TelerobotError as exc:
        print(f"telerobot master: {exc}", file=sys.stderr)
        return 1
    role = "operator" if link.operator else "observer (no token: watching only)"
    print(f"Master arm {device.name} bridged to {args.server} as {role}", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with contextlib.suppress(KeyboardInterrupt):
        while not stop.wait(1.0):
            f = bridge.last_rendered
            pc = bridge.passivity
            print(
                f"control {'yes' if bridge.has_control else 'no '}"
                f" · commands {bridge.commands_sent}"
                f" · forces {bridge.forces_received} ({bridge.link.datagrams})"
                f" · rendering {np.linalg.norm(f):.2f} N"
                f" · passivity {'on' if pc.settings.enabled else 'off'}: port {pc.energy:+.3f} J,"
                f" damped {pc.dissipated:.3f} J, α {pc.damping:.1f} N·s/m"
                + (
                    f" · arm: put in {bridge.arm_energy_out:.3f} J, got back"
                    f" {bridge.arm_energy_in:.3f} J"
                    if bridge.two_port
                    else ""
                )
                + ("" if bridge.connected else " · reconnecting")
                + _supervision(bridge.link.autonomy)
                + (f" · last error: {bridge.last_error}" if bridge.last_error else ""),
                flush=True,
            )
    bridge.stop()
    bridge.link.close()
    return 0
