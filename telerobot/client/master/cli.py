"""``telerobot master``: the master-arm bridge as a command."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import threading

import httpx
import numpy as np

from telerobot.client import local_url, stored_token
from telerobot.client.master.bridge import BridgeSettings, MasterBridge
from telerobot.client.master.link import open_link
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
        default="/dev/ttyACM1",
        help="so101-leader: its servo bus (a device, a pty or socket://host:port)",
    )
    p.add_argument("--leader-baudrate", type=int, default=1_000_000)
    p.add_argument("--leader-calibration", help="so101-leader: its joint calibration (JSON) file")
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


def run_leader(args: argparse.Namespace, token: str) -> int:
    """A leader arm mirrored joint for joint (``--device <name>-leader``)."""
    from telerobot.client.master.joints import JointMirror, MirrorSettings
    from telerobot.drivers.robot.models import load_model

    base = args.server if args.server.endswith("/") else args.server + "/"
    kind = args.device.removesuffix("-leader")
    mirror: JointMirror | None = None
    try:
        try:
            described = httpx.get(base + "api/v1/robot/model", timeout=5, verify=False).json()
        except (httpx.HTTPError, ValueError) as exc:
            raise TelerobotError(f"cannot ask {base} for its arm's model: {exc}") from None
        model = load_model(str(described["model"]))
        leader = load_driver("leader", kind).from_options(
            model,
            port=args.leader_port,
            baudrate=args.leader_baudrate,
            calibration=args.leader_calibration,
        )
        link = open_link(args.server, token, datagrams=False, name=args.name)  # no forces
        settings = MirrorSettings(align_rad=math.radians(args.align_deg)).check()
        mirror = JointMirror(leader, link, model.joint_names, settings)
        # Why the arm is as it is, should it be in ERROR already: STATE carries only
        # its status, and the EVENT that said why came before this client joined.
        with contextlib.suppress(httpx.HTTPError, ValueError, KeyError, TypeError):
            arm = httpx.get(base + "api/v1/robot/state", timeout=5, verify=False).json()
            mirror.arm_message = f"{arm['status']}: {arm['message']}"
        mirror.start(take_control=bool(token), take_over=args.take_over)
    except TelerobotError as exc:
        print(f"telerobot master: {exc}", file=sys.stderr)
        return 1
    role = "operator" if link.operator else "observer (no token: watching only)"
    print(
        f"Leader {leader.name} mirrored onto the {model.title} at {args.server} as {role}",
        flush=True,
    )
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with contextlib.suppress(KeyboardInterrupt):
        while not stop.wait(1.0):
            print(
                f"control {'yes' if mirror.has_control else 'no '}"
                f" · commands {mirror.commands_sent} · {mirror.status}"
                + _supervision(mirror.link.autonomy, clutch=False)
                + (f" · last error: {mirror.last_error}" if mirror.last_error else ""),
                flush=True,
            )
    mirror.stop()
    mirror.link.close()
    return 0


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
        # A server restart or a cut: connect again (with backoff) rather than exit.
        bridge = MasterBridge(
            device,
            link,
            settings,
            reconnect=lambda: open_link(args.server, token, datagrams=udp, name=args.name),
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
