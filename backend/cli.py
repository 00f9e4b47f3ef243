"""``telerobot`` subcommands: serve, media-server, recording, val-emulator,
so101-emulator, so101-calibrate, master, netft-emulator, move, policy-token, policy demo,
export, bench."""

from __future__ import annotations

import argparse
import ast
import asyncio
import contextlib
import errno
import logging
import os
import runpy
import signal
import socket
import sys
import threading
import time
import warnings
from pathlib import Path

from pydantic import ValidationError

from telerobot.drivers.registry import driver_names
from telerobot.drivers.robot.models import model_names
from telerobot.tuning import raise_cpu_priority, tune_for_realtime

# The largest /ws message the server reads: a FORCE batch from a client is the largest
# legitimate one (< 16 kB); uvicorn's default (16 MiB) let one message hold 16 MiB.
WS_MAX_MESSAGE = 64 * 1024


# The event loop shares the GIL with the force sensor's, the priority channel's and the
# recorder's threads: a thread that wants it waits at most this long for a busy one to
# let go (CPython's default is 5 ms, a long time beside a 1 ms force period).
GIL_SWITCH_INTERVAL_S = 0.0005


# uvicorn's `websockets` implementation is chosen on purpose (`ws=` below: the sans-I/O
# one parses a whole read of a frame flood at once, docs/PERFORMANCE.md); it, and the
# websockets.legacy it runs on, say at every start that they are deprecated: news for
# whoever upgrades uvicorn (pyproject pins it), not for the person starting the server.
QUIET_WARNINGS = (
    r"The `websockets` implementation is deprecated",
    r"websockets\.legacy is deprecated",
)


def _quiet_known_warnings() -> None:
    for message in QUIET_WARNINGS:
        warnings.filterwarnings("ignore", message=message)


def _cannot_listen(host: str, port: int) -> OSError | None:
    """Why ``host:port`` cannot be listened on now (in use, not this machine's address,
    a privileged port), or None; port 0 (any free one) always can. Bound with
    SO_REUSEADDR as uvicorn and the priority channel bind, so a port left in TIME_WAIT
    by a server just stopped is free."""
    if port == 0:
        return None
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except OSError:
        return None  # (the server says it in its own words)
    for family, kind, proto, _, address in infos:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(address)
            except OSError as exc:
                return exc
    return None


def _ports_refused(host: str, ports: list[tuple[str, int, str, str]]) -> str | None:
    """One line for the first port of ``ports`` (what, port, flag, variable) that cannot
    be listened on, or None."""
    for what, port, flag, variable in ports:
        exc = _cannot_listen(host, port)
        if exc is None:
            continue
        if exc.errno == errno.EADDRINUSE:
            why = "is in use (another `telerobot serve`?)"
        else:
            why = f"cannot be listened on ({exc.strerror})"
        return (
            f"telerobot serve: {what} port {port} on {host} {why}: pick another with"
            f" {flag} PORT (or {variable}; 0: any free port), or stop what holds it"
        )
    return None


class _OneLineStartupError(logging.Filter):
    """A server that cannot start says why in one line, not in the traceback Starlette
    hands uvicorn as the message (-v: the whole traceback)."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.msg
        if isinstance(text, str) and text.startswith("Traceback (most recent call last):"):
            last = text.rstrip().splitlines()[-1]
            kind, _, why = last.partition(": ")
            if kind.startswith("telerobot.") and why:
                last = why  # ours say what to do; their class is no news
            record.msg, record.args = f"the server cannot start: {last}", ()
        return True


def _settings_error(exc: Exception) -> str:
    """What is wrong with the settings, each field and why, never the value given (it
    may be a token)."""
    if not isinstance(exc, ValidationError):
        return str(exc)
    return "; ".join(
        f"{'.'.join(str(x) for x in e['loc']) or 'settings'}: {e['msg']}"
        for e in exc.errors(include_url=False, include_input=False)
    )


def _token_hint(settings: object, url: str, path: Path, is_new: bool) -> list[str]:
    """Where the operator token is kept and how the page takes it: never the token."""
    secret = getattr(settings, "operator_token", None)
    configured = secret.get_secret_value() if secret is not None else None
    if configured and os.environ.get("TELEROBOT_OPERATOR_TOKEN") == configured:
        where, placeholder = "set by TELEROBOT_OPERATOR_TOKEN", "$TELEROBOT_OPERATOR_TOKEN"
    elif configured:
        where, placeholder = "set in the settings (operator_token)", "the configured operator token"
    else:
        where, placeholder = f"kept in {path}", f"the token in {path}"
    lines = [] if is_new else [f"Operator token: {where}"]
    lines.append(f"Take control: open {url}?token=<{placeholder}> (without it the page watches)")
    return lines


def _serve(args: argparse.Namespace) -> int:
    _quiet_known_warnings()
    import uvicorn

    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)

    from telerobot.server.app import create_app, services_of
    from telerobot.server.devices import describe_robot
    from telerobot.server.settings import load_settings

    try:
        settings = load_settings(
            args.config,
            host=args.host,
            http_port=args.http_port,
            priority_port=args.priority_port,
            viewer_port=args.viewer_port,
            robot=args.robot,
            robot_model=args.model,
            arms=args.arms,
            serial_port=args.port,
            serial_baudrate=args.baudrate,
            auto_initialize=False if args.no_init else None,
            tls=True if args.tls else None,
            state_dir=args.state_dir,
            media_server=args.media_server,
            media_server_url=args.media_server_url,
            media_server_rtp_port=args.media_server_rtp_port,
        )
    except (ValidationError, FileNotFoundError, ValueError) as exc:
        print(f"telerobot: bad settings: {_settings_error(exc)}", file=sys.stderr)
        return 2
    if args.port is not None and settings.robot != "val" and not args.arms:
        # `--port 8765` read as the page's port started a server on 8000 and said nothing
        print(
            f"telerobot serve: --port is a robot's serial port (--robot val); the"
            f" {settings.robot} robot has none. The page's port is --http-port PORT",
            file=sys.stderr,
        )
        return 2
    from telerobot.server.accesslog import limit_refusals_logged
    from telerobot.server.security import ensure_certificate, redact_server_logs, state_dir

    refused = _ports_refused(
        settings.host,
        [
            ("the HTTP", settings.http_port, "--http-port", "TELEROBOT_HTTP_PORT"),
            ("the priority channel's", settings.priority_port, "--priority-port",
             "TELEROBOT_PRIORITY_PORT"),
        ],
    )  # fmt: skip
    if refused:
        print(refused, file=sys.stderr)
        return 1
    app = create_app(settings, record=args.record)
    ssl: dict[str, str] = {}
    if settings.tls:
        cert, key = ensure_certificate(settings)
        ssl = {"ssl_certfile": str(cert), "ssl_keyfile": str(key)}
    scheme = "https" if settings.tls else "http"
    host = settings.host
    shown = "localhost" if host in ("127.0.0.1", "0.0.0.0", "::") else host
    where = describe_robot(settings)
    config = uvicorn.Config(
        app,
        host=host,
        port=settings.http_port,
        log_level="info",
        ws_max_size=WS_MAX_MESSAGE,
        # The websockets implementation that parses a frame only when the app reads
        # one (32 queued at most, then TCP pushes back). The sans-I/O one parses all a
        # read brings at once: a flood of 3-byte frames (21,000 in one 64 kB read)
        # held the event loop for 3 s and queued them all. No compression: the
        # messages are binary and small, and inflating is work a client can make us do.
        ws="websockets",
        ws_max_queue=32,
        ws_per_message_deflate=False,
        **ssl,  # type: ignore[arg-type]
    )
    redact_server_logs()  # after uvicorn has configured its loggers
    limit_refusals_logged()
    if not args.verbose:
        logging.getLogger("uvicorn.error").addFilter(_OneLineStartupError())
    server = uvicorn.Server(config)

    async def run() -> None:
        task = asyncio.create_task(server.serve())
        # A start that fails ends the task with SystemExit, raised out of the loop as
        # well: taken here, it is not logged again as "never retrieved".
        task.add_done_callback(lambda t: t.cancelled() or t.exception())
        while not server.started and not task.done():  # noqa: ASYNC110 (uvicorn only has a flag)
            await asyncio.sleep(0.05)
        if server.started:
            port = (
                server.servers[0].sockets[0].getsockname()[1]
                if server.servers
                else settings.http_port
            )
            print(f"\nTelerobot is running on {where}: {scheme}://{shown}:{port}/", flush=True)
            services = services_of(app)
            print(
                f"Priority channel (forces, master arm): tcp://{shown}:{services.priority.port}",
                flush=True,
            )
            if services.viewer.view is not None:
                print(f"3D view: http://{shown}:{services.viewer.view.port}/", flush=True)
            path = state_dir(settings) / "operator-token"
            if services.token.is_new:
                print(
                    f"Operator token (shown this once, kept in {path}): {services.token.value}",
                    flush=True,
                )
            url = f"{scheme}://{shown}:{port}/"
            for line in _token_hint(settings, url, path, services.token.is_new):
                print(line, flush=True)
            print(flush=True)
        await task

    tune_for_realtime()
    logging.getLogger("telerobot.tuning").info("%s", raise_cpu_priority(settings.cpu_priority))
    # Ctrl+C: uvicorn shuts the server down cleanly, then (mostly) raises the signal
    # again for whoever called it; at a terminal that is the way to stop, no error.
    try:
        with contextlib.suppress(KeyboardInterrupt):
            asyncio.run(run())
    except SystemExit as exc:  # it did not start: uvicorn has said why (one line)
        code = exc.code if isinstance(exc.code, int) else 1
        print(f"telerobot serve: the server did not start (exit {code})", file=sys.stderr)
        return code or 1
    print("Telerobot stopped.", flush=True)
    return 0


def wait_until_stopped() -> None:
    """Block until Ctrl-C or SIGTERM."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with contextlib.suppress(KeyboardInterrupt):
        stop.wait()


def _val_emulator(args: argparse.Namespace) -> int:
    from telerobot.drivers.robot.puma560.val_emulator import EmulatorLink, ValControllerEmulator

    emulator = ValControllerEmulator(time_scale=args.time_scale)
    if args.tcp:
        host, _, port = args.tcp.rpartition(":")
        link = EmulatorLink.on_tcp(emulator, host or "127.0.0.1", int(port))
    else:
        link = EmulatorLink.on_pty(emulator)
    link.start()
    print(f"VAL controller emulator listening on {link.url}", flush=True)
    print(f"  run the server against it: telerobot serve --robot val --port {link.url}", flush=True)
    wait_until_stopped()
    link.stop()
    return 0


def _so101_emulator(args: argparse.Namespace) -> int:
    from telerobot.drivers.robot.models import load_model
    from telerobot.drivers.robot.so101.calibration import So101Calibration
    from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator

    model = load_model("so101")
    # The emulated arm is assembled as the nominal calibration says (zero at mid-scale).
    nominal = So101Calibration.nominal(model.joint_names)
    steps = nominal.to_steps(model.pose(args.pose))
    bus = FeetechBusEmulator(start=dict(zip(nominal.ids, map(float, steps), strict=True)))
    if args.tcp:
        host, _, port = args.tcp.rpartition(":")
        link = BusLink.on_tcp(bus, host or "127.0.0.1", int(port))
    else:
        link = BusLink.on_pty(bus)
    if args.calibration:
        nominal.save(Path(args.calibration))
    link.start()
    print(f"SO-101 bus emulator listening on {link.url}", flush=True)
    print(
        "  run the server against it: telerobot serve --robot so101 --model so101 "
        f"with TELEROBOT_SO101_PORT={link.url}"
        + (f" TELEROBOT_SO101_CALIBRATION={args.calibration}" if args.calibration else ""),
        flush=True,
    )
    wait_until_stopped()
    link.stop()
    return 0


def _so101_calibrate(args: argparse.Namespace) -> int:
    from telerobot.drivers.robot.so101.calibrate import main
    from telerobot.drivers.robot.so101.leader import default_leader_calibration
    from telerobot.drivers.robot.so101.settings import default_calibration_path

    if args.out is not None:
        out = Path(args.out)
    elif args.leader:
        out = default_leader_calibration()
    else:
        out = default_calibration_path({"state_dir": args.state_dir})
    return main(args.port, out, args.baudrate, tuple(args.poses.split(",")))


def _netft_emulator(args: argparse.Namespace) -> int:
    from telerobot.drivers.force.netft_emulator import NetFtEmulator

    emulator = NetFtEmulator(args.host, args.port, rate_hz=args.rate).start()
    print(f"Net F/T emulator listening on udp://{emulator.url}", flush=True)
    print(
        f"  run the server against it: TELEROBOT_FORCE=netft TELEROBOT_NETFT_ADDRESS={emulator.url}"
        " telerobot serve",
        flush=True,
    )
    wait_until_stopped()
    emulator.close()
    return 0


def _export_lerobot(args: argparse.Namespace) -> int:
    from telerobot.server.recording.lerobot import ExportError, export_lerobot
    from telerobot.server.recording.recover import recovered_path
    from telerobot.server.recording.salvage import has_summary, is_mcap

    what = "telerobot export lerobot"
    try:
        rec = _recording_file(args.recording, args.state_dir)
    except LookupError as exc:
        print(f"{what}: {exc}", file=sys.stderr)
        return 1
    try:
        if not is_mcap(rec):
            print(f"{what}: {rec} is not an MCAP recording", file=sys.stderr)
            return 1
        if not has_summary(rec):
            print(
                f"{what}: {rec} is torn (its writer did not finish it, or it is still being "
                f"written): run `telerobot recording recover {rec}`, then export "
                f"{recovered_path(rec)}",
                file=sys.stderr,
            )
            return 1
        summary = export_lerobot(
            rec,
            args.dir,
            fps=args.fps,
            allow_repeated_frames=args.allow_repeated_frames,
            progress=_ExportProgress(),
        )
    except (ExportError, OSError) as exc:
        print(f"{what}: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # a recording damaged inside: one line, not a traceback
        if args.verbose:
            raise
        print(
            f"{what}: cannot read {rec}: {type(exc).__name__}: {exc} (-v: details)"[:500],
            file=sys.stderr,
        )
        return 1
    print(
        f"{summary.out_dir}: {summary.episodes} episodes, {summary.frames} frames at "
        f"{summary.fps} fps, tasks {summary.tasks} ({summary.export_s:.1f} s)"
    )
    if summary.video_fps is not None:
        print(
            f"the recorded video ran at {summary.video_fps:.2f} fps; "
            f"{summary.repeated_frames} rows repeat the frame before them"
        )
    if summary.whole_recording:
        print("the recording has no episodes: exported the whole of it as one")
    for note in summary.skipped:
        print(f"left out: {note}")
    for warning in summary.warnings:
        print(f"warning: {warning}")
    return 0


def _recording_file(given: str, state: Path | None) -> Path:
    """The recording ``given`` names: a file, or a recording's id as the page and GET
    /api/v1/recordings show it (its file name, ``.mcap`` optional) in the server's
    recordings folder (``--state-dir``, TELEROBOT_STATE_DIR, else ~/.config/telerobot).
    LookupError saying where it looked otherwise."""
    from telerobot.server.recording.library import ID, MAX_ID_CHARS
    from telerobot.server.recording.recorder import recordings_folder
    from telerobot.server.security import state_dir
    from telerobot.server.settings import load_settings

    path = Path(given).expanduser()
    if path.is_file():
        return path
    try:
        folder = recordings_folder(state_dir(load_settings(None, state_dir=state)))
    except (ValidationError, ValueError) as exc:
        raise LookupError(
            f"no file {given}, and the settings name no recordings folder: {exc}"
        ) from None
    if len(given) <= MAX_ID_CHARS and ID.match(given):
        found = folder / (given if given.endswith(".mcap") else f"{given}.mcap")
        if found.is_file():
            return found
    raise LookupError(
        f"no recording {given!r}: not a file here, nor in the recordings folder {folder}"
        " (a recording's id is its file name, as the page's Recordings list and GET"
        " /api/v1/recordings show it; another server's folder: --state-dir)"
    )


EXPORT_PROGRESS_STEP = 10  # percent between the export's progress lines


class _ExportProgress:
    """A line every EXPORT_PROGRESS_STEP percent (an export takes minutes on a busy
    machine: say that it moves)."""

    def __init__(self) -> None:
        import time

        self.clock = time.monotonic
        self.started = self.clock()
        self.said = 0

    def __call__(self, fraction: float) -> None:
        percent = round(fraction * 100)
        if self.said + EXPORT_PROGRESS_STEP <= percent < 100:
            self.said = percent - percent % EXPORT_PROGRESS_STEP
            print(f"exporting: {self.said} % ({self.clock() - self.started:.0f} s)", flush=True)


def _media_server(args: argparse.Namespace) -> int:
    """Janus in the foreground with a generated configuration, until it exits (or ^C)."""
    import os
    import tempfile

    from telerobot.server.media.janus import JanusSettings, run_foreground

    secret = os.environ.get(args.secret_env, "")
    if len(secret) < 16:
        print(f"telerobot: set {args.secret_env} (at least 16 characters)", file=sys.stderr)
        return 2
    lo, _, hi = args.webrtc_ports.partition("-")
    if not (lo.isdigit() and (hi or lo).isdigit() and 1024 <= int(lo) <= int(hi or lo) <= 65535):
        print(
            f"telerobot: --webrtc-ports LOW-HIGH (1024…65535), got {args.webrtc_ports!r}",
            file=sys.stderr,
        )
        return 2
    if not secret.replace("-", "").replace("_", "").isalnum():
        print(f"telerobot: {args.secret_env}: letters, digits, - and _ only", file=sys.stderr)
        return 2
    settings = JanusSettings(
        http_port=args.http_port,
        rtp_port=args.rtp_port,
        secret=secret,
        rtp_ports=(int(lo), int(hi or lo)),
        rtcp_port=args.rtcp_port,
        data_port=args.data_port,
        api_host=args.api_host,
        feed_host=args.feed_host,
    )
    with tempfile.TemporaryDirectory(prefix="telerobot-janus-") as folder:
        return run_foreground(settings, Path(folder))


BENCH_LINE = 78  # characters of a benchmark's description in the listing


def _bench_folder() -> Path | None:
    """The benchmarks' folder: beside the package's folders in a checkout (an installed
    wheel has none)."""
    folder = Path(__file__).resolve().parents[1] / "bench"
    return folder if (folder / "__init__.py").is_file() else None


def benchmarks() -> dict[str, str]:
    """Each benchmark's name and what it measures (its docstring's first sentence), read
    from the files, not imported: every module in bench/ that runs as a program."""
    folder = _bench_folder()
    found: dict[str, str] = {}
    if folder is None:
        return found
    for path in sorted(folder.glob("*.py")):
        text = path.read_text(encoding="utf-8", errors="replace")
        if path.stem.startswith("_") or '__name__ == "__main__"' not in text:
            continue
        try:
            doc = ast.get_docstring(ast.parse(text)) or ""
        except SyntaxError:
            doc = ""
        first = " ".join(doc.split("\n\n")[0].replace("``", "").split())
        sentence = first.split(". ")[0].rstrip(".:")
        found[path.stem] = (
            sentence if len(sentence) <= BENCH_LINE else sentence[: BENCH_LINE - 1] + "…"
        )
    return found


def _bench_listing() -> str:
    listed = benchmarks()
    if not listed:
        return "the benchmarks run from a checkout of the repository"
    width = max(map(len, listed))
    return "benchmarks:\n" + "\n".join(f"  {n:<{width}}  {what}" for n, what in listed.items())


class _BenchHelp(argparse.Action):
    """``telerobot bench --help``: the usage, then each benchmark in one line."""

    def __init__(self, option_strings: list[str], dest: str, **kw: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="show this, with the benchmarks")

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        parser.print_help()
        print()
        print(_bench_listing())
        print("\neach takes its own options: telerobot bench NAME --help")
        parser.exit()


def _bench(args: argparse.Namespace) -> int:
    import importlib.util

    # In a checkout the benches are beside the package's folders (the console script's
    # path holds only its own bin/); an installed wheel has none.
    folder = _bench_folder()
    checkout = str(folder.parent) if folder is not None else None
    if checkout is not None and checkout not in sys.path:
        sys.path.insert(0, checkout)
    if folder is None or importlib.util.find_spec("bench") is None:
        print(
            "telerobot bench: the benchmarks run from a checkout of the repository"
            " (cd telerobot && make run once, then .venv/bin/telerobot bench …)",
            file=sys.stderr,
        )
        return 2
    listed = benchmarks()
    if args.name is None or args.name not in listed:
        said = "name one" if args.name is None else f"no benchmark {args.name!r}"
        print(
            f"telerobot bench: {said}: {', '.join(listed)} (telerobot bench --help says"
            " what each measures)",
            file=sys.stderr,
        )
        return 2
    sys.argv = [f"bench.{args.name}", *args.rest]
    runpy.run_module(f"bench.{args.name}", run_name="__main__", alter_sys=True)
    return 0


def _arm_named(url: str, token: str, wanted: str | None, what: str) -> tuple[str | None, int]:
    """The arm a command names (``--arm``), checked against the server's (GET
    /api/v1/robot/arms), and its joint count: none named is the only arm of a one-arm
    server; a two-arm server needs one. ValueError in one line naming the server's arms."""
    from telerobot.client import Telerobot

    robot = Telerobot(url, token, name=what)
    try:
        arms = robot.arms()
    finally:
        robot.close()
    names = [str(a["name"]) for a in arms]
    listed = ", ".join(names)
    if wanted is None:
        if len(arms) == 1:
            return None, int(arms[0]["dof"])
        raise ValueError(
            f"the server drives {len(arms)} arms ({listed}): name one with --arm NAME"
            f" ({what} --arm {names[0]} …)"
        )
    for arm in arms:
        if arm["name"] == wanted:
            return wanted, int(arm["dof"])
    raise ValueError(f"the server has no arm {wanted!r}: it drives {listed} (--arm NAME)")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _move(args: argparse.Namespace) -> int:
    """One bounded move from the shell, with the Python client (takes the lease,
    moves, releases it); ``--arm`` names the arm on a server that drives more."""
    import httpx

    from telerobot.client import Telerobot, TelerobotError, local_url, stored_token

    what = "telerobot move"
    token = args.token or stored_token()
    if not token:
        print(
            f"{what}: no operator token: pass --token, set TELEROBOT_OPERATOR_TOKEN,"
            " or run it where `telerobot serve` keeps it",
            file=sys.stderr,
        )
        return 2
    try:
        values = [float(v) for v in args.values]
    except ValueError:
        bad = next(v for v in args.values if not _is_number(v))
        print(f"{what}: {bad!r} is not a number (the arm: --arm NAME)", file=sys.stderr)
        return 2
    url = args.url or local_url()
    try:
        arm, dof = _arm_named(url, token, args.arm, what)
        want = dof if args.space == "joints" else 3
        if len(values) != want:
            said = f"an angle for each of the arm's {dof} joints (rad)"
            said = said if args.space == "joints" else "x y z (m)"
            print(f"{what}: {args.space} takes {want} numbers: {said}", file=sys.stderr)
            return 2
        with Telerobot(url, token, name=what, take_over=args.take_over) as robot:
            if args.space == "joints":
                result = robot.move_joints(values, relative=args.relative, arm=arm)
            else:
                result = robot.move_cartesian(
                    values, relative=args.relative, frame=args.frame, arm=arm
                )
    except ValueError as exc:
        print(f"{what}: {exc}", file=sys.stderr)
        return 2
    except TelerobotError as exc:
        print(f"{what}: {exc}", file=sys.stderr)
        return 1
    except httpx.HTTPError as exc:
        print(f"{what}: cannot reach {url}: {exc}", file=sys.stderr)
        return 1
    state = result["state"]
    on = f"{state['arm']}: " if arm is not None else ""
    print(f"{on}position (m):", " ".join(f"{v:.4f}" for v in state["position"]))
    print(f"{on}joints (deg):", " ".join(f"{v:.2f}" for v in state["joints_deg"]))
    return 0


def _policy_token(args: argparse.Namespace) -> int:
    """``telerobot policy-token new NAME | list | revoke ID`` over REST, as an operator."""
    import httpx

    from telerobot.client import local_url, stored_token

    what = f"telerobot policy-token {args.policy_command}"
    token = args.token or stored_token()
    if not token:
        print(
            f"{what}: no operator token: pass --token, set TELEROBOT_OPERATOR_TOKEN, or run"
            " it where `telerobot serve` keeps it",
            file=sys.stderr,
        )
        return 2
    url = (args.url or local_url()).rstrip("/") + "/api/v1/policy-tokens"
    headers = {"Authorization": f"Bearer {token}", "X-Telerobot-Client": "telerobot"}
    try:
        with httpx.Client(headers=headers, timeout=30, verify=False) as http:
            if args.policy_command == "new":
                r = http.post(url, json={"name": args.name})
            elif args.policy_command == "revoke":
                r = http.delete(f"{url}/{args.id}")
            else:
                r = http.get(url)
    except httpx.HTTPError as exc:
        print(f"{what}: cannot reach {args.url or local_url()}: {exc}", file=sys.stderr)
        return 1
    if r.is_error:
        try:
            detail = r.json().get("detail", r.text)
        except ValueError:
            detail = r.text
        print(f"{what}: {detail}", file=sys.stderr)
        return 1
    body = r.json()
    if args.policy_command == "new":
        print(body["token"])
        print(
            f"policy token {body['id']} for {body['name']!r}: shown this once. Give it to the"
            " policy (TELEROBOT_POLICY_TOKEN, or lerobot's --robot.policy_token); it drives"
            " only after a person lets it (P on the page). Revoke it with"
            f" `telerobot policy-token revoke {body['id']}`.",
            file=sys.stderr,
        )
    elif args.policy_command == "revoke":
        print(f"revoked {body['id']} ({body['name']}); {body['disconnected']} client(s) gone")
    else:
        for t in body:
            when = time.strftime("%Y-%m-%d %H:%M", time.localtime(t["created"]))
            print(f"{t['id']}  {when}  {t['name']}")
        if not body:
            print("no policy tokens issued", file=sys.stderr)
    return 0


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _policy_demo(args: argparse.Namespace) -> int:
    """``telerobot policy demo``: a scripted policy reaching for random targets, joined
    as a policy, supervised from the page (telerobot/client/policy_demo.py)."""
    from telerobot.client import local_url, stored_token
    from telerobot.client.policy_demo import DemoError, DemoOptions, run_demo

    what = "telerobot policy demo"
    options = DemoOptions(
        url=args.url or local_url(),
        policy_token=args.token or os.environ.get("TELEROBOT_POLICY_TOKEN") or None,
        operator_token=stored_token(),
        arms=args.arm or [],
        wait=args.wait,
        seed=args.seed,
        targets=args.targets,
    )

    def say(line: str) -> None:
        print(line, flush=True)

    # Ctrl+C (even where a shell started it ignoring SIGINT) and SIGTERM stop it alike:
    # control given back, the token it issued revoked.
    previous = {s: signal.signal(s, signal.default_int_handler) for s in STOP_SIGNALS}
    try:
        run_demo(options, say)
    except DemoError as exc:
        print(f"{what}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("stopped: control given back", flush=True)
        return 0
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    print(f"stopped after {args.targets} targets: control given back", flush=True)
    return 0


def _recording_recover(args: argparse.Namespace) -> int:
    """Copy a torn recording, as far as it is valid, into NAME.recovered.mcap beside
    it (the original is left as it is); a file that is not an MCAP is refused."""
    from telerobot.drivers.base import TelerobotError
    from telerobot.server.recording.recover import recover_copy
    from telerobot.server.recording.salvage import has_summary

    what = "telerobot recording recover"
    if not args.file.is_file():
        print(f"{what}: no file {args.file}", file=sys.stderr)
        return 2
    try:
        if has_summary(args.file):
            print(f"{args.file} is complete (it has its summary): nothing to do")
            return 0
        result = recover_copy(args.file)
    except (TelerobotError, OSError) as exc:
        print(f"{what}: {exc}", file=sys.stderr)
        return 1
    print(f"{result.source}: recovered {result.messages} messages into {result.out}")
    if result.stopped:
        print(f"the rest of {result.source.name} could not be read: {result.stopped}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """``telerobot``'s command line: each subcommand, its options and its function."""
    parser = argparse.ArgumentParser(
        prog="telerobot", description="Drive a robot arm from a browser."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    serve = sub.add_parser("serve", help="start the server (simulation by default)")
    serve.add_argument("--config", type=Path, help="TOML settings file")
    serve.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    serve.add_argument("--http-port", type=int, help="HTTP port (default 8000)")
    serve.add_argument(
        "--priority-port", type=int, help="TCP port of the priority channel (default 8001)"
    )
    serve.add_argument(
        "--viewer-port", type=int, help="HTTP port of the 3D view (default 8002; 0: any free)"
    )
    serve.add_argument("--robot", choices=driver_names("robot"), help="robot driver (default sim)")
    serve.add_argument(
        "--model", choices=model_names(), help="the arm's description (default puma560)"
    )
    serve.add_argument(
        "--arms",
        metavar="NAME=MODEL:DRIVER,…",
        help="two arms or more, e.g. left=so101:sim,right=so101:sim (docs/arms.md;"
        " a TOML [arms.NAME] table gives each its own settings)",
    )
    serve.add_argument(
        "--port", help="serial port for --robot val: /dev/ttyS0, a pty, socket://host:port"
    )
    serve.add_argument("--baudrate", type=int, help="serial baud rate (default 9600)")
    serve.add_argument(
        "--no-init", action="store_true", help="connect but do not initialise the robot"
    )
    serve.add_argument(
        "--tls", action="store_true", help="HTTPS with a self-signed certificate made on first use"
    )
    serve.add_argument(
        "--state-dir", type=Path, help="where the token and certificate live (~/.config/telerobot)"
    )
    serve.add_argument(
        "--record", metavar="NAME", help="record from the start (state folder/recordings)"
    )
    serve.add_argument(
        "--media-server",
        choices=("none", "janus"),
        help="observers watch through a media server (Janus, started and supervised here"
        " unless --media-server-url): the robot's computer sends the video once",
    )
    serve.add_argument(
        "--media-server-url",
        metavar="URL",
        help="a Janus elsewhere: its HTTP API (http://host:8088/janus); its mountpoint's RTP"
        " port is --media-server-rtp-port (settings: media_server_host, _mountpoint, _secret)",
    )
    serve.add_argument("--media-server-rtp-port", type=int, help="its mountpoint's RTP port")
    serve.set_defaults(func=_serve)

    janus = sub.add_parser(
        "media-server",
        help="run Janus for `telerobot serve --media-server-url` on another machine or container",
    )
    janus.add_argument("--http-port", type=int, default=8088, help="its HTTP API (on --api-host)")
    janus.add_argument(
        "--api-host", default="127.0.0.1", help="where its HTTP API listens (the robot's server)"
    )
    janus.add_argument(
        "--rtp-port", type=int, default=5004, help="the robot's H.264 RTP comes here"
    )
    janus.add_argument(
        "--rtcp-port", type=int, default=5005, help="key frame requests go back from here"
    )
    janus.add_argument("--data-port", type=int, default=5006, help="observers' state and forces")
    janus.add_argument(
        "--feed-host", default="127.0.0.1", help="where it takes the RTP and data (its interface)"
    )
    janus.add_argument("--webrtc-ports", default="20000-20999", help="its WebRTC UDP range")
    janus.add_argument(
        "--secret-env",
        default="TELEROBOT_MEDIA_SERVER_SECRET",
        help="the environment variable holding the mountpoint's secret (≥ 16 characters)",
    )
    janus.set_defaults(func=_media_server)

    recording = sub.add_parser(
        "recording", help="recordings: recover FILE (one with no summary) into a copy"
    )
    recording_sub = recording.add_subparsers(dest="recording_command", required=True)
    recover = recording_sub.add_parser(
        "recover",
        help="copy a recording whose writer was killed, as far as it is valid, into "
        "NAME.recovered.mcap beside it, with an index and a summary (the file is left as it is)",
    )
    recover.add_argument("file", type=Path)
    recover.set_defaults(func=_recording_recover)

    emu = sub.add_parser(
        "val-emulator", help="emulate a Unimation VAL controller on a pty or TCP port"
    )
    emu.add_argument(
        "--tcp", metavar="HOST:PORT", help="listen on TCP instead of a pseudo-terminal"
    )
    emu.add_argument(
        "--time-scale", type=float, default=1.0, help="scale move durations (0.1 = 10× faster)"
    )
    emu.set_defaults(func=_val_emulator)

    so101 = sub.add_parser(
        "so101-emulator", help="emulate an SO-101's Feetech servo bus on a pty or TCP port"
    )
    so101.add_argument("--tcp", metavar="HOST:PORT", help="listen on TCP instead of a pty")
    so101.add_argument("--pose", default="rest", help="where the arm is when switched on")
    so101.add_argument(
        "--calibration", metavar="FILE", help="write the emulated arm's calibration here"
    )
    so101.set_defaults(func=_so101_emulator)

    cal = sub.add_parser(
        "so101-calibrate", help="record an SO-101's joint calibration (or its leader's) by hand"
    )
    cal.add_argument("--port", required=True, help="its servo bus: /dev/ttyACM0, socket://…")
    cal.add_argument("--baudrate", type=int, default=1_000_000)
    cal.add_argument("--leader", action="store_true", help="the leader arm's (its own file)")
    cal.add_argument("--out", help="where to write it (default: where the server reads it)")
    cal.add_argument("--state-dir", type=Path, help="the server's state folder")
    cal.add_argument("--poses", default="zero,quarter", help="the poses to record, in order")
    cal.set_defaults(func=_so101_calibrate)

    master = sub.add_parser(
        "master", help="bridge a haptic master arm to a server (sim or a 3D Systems Touch)"
    )
    from telerobot.client.master.cli import add_arguments, run

    add_arguments(master)
    master.set_defaults(func=run)

    netft = sub.add_parser("netft-emulator", help="emulate an ATI Net F/T sensor (RDT over UDP)")
    netft.add_argument("--host", default="127.0.0.1", help="address to listen on")
    netft.add_argument("--port", type=int, default=49152, help="UDP port (0: any free port)")
    netft.add_argument("--rate", type=float, default=1000.0, help="samples per second")
    netft.set_defaults(func=_netft_emulator)

    move = sub.add_parser(
        "move", help="one move: telerobot move cartesian 0.6 -0.1 0.9 (or joints J1..J6)"
    )
    move.add_argument("space", choices=["joints", "cartesian"])
    move.add_argument(
        "values", nargs="+", help="an angle per joint (rad) or x y z (m, the arm's base)"
    )
    move.add_argument(
        "--arm",
        metavar="NAME",
        help="which arm, on a server that drives two or more (GET /api/v1/robot/arms)",
    )
    move.add_argument("--relative", action="store_true", help="by, not to")
    move.add_argument("--frame", choices=["base", "wrist", "tool"], help="of a relative move")
    # Named as for `telerobot master` and the Python client (telerobot/client/rest.py).
    move.add_argument("--url", help="the server (default: TELEROBOT_URL or http://localhost:8000)")
    move.add_argument(
        "--token",
        help="operator token (default: TELEROBOT_OPERATOR_TOKEN, else the one the server"
        " keeps on this machine)",
    )
    move.add_argument("--take-over", action="store_true", help="take control from its holder")
    move.set_defaults(func=_move)

    policy_token = sub.add_parser(
        "policy-token",
        help="issue, list or revoke a policy token: a credential that can only drive, and"
        " only while a person lets it (docs/lerobot.md)",
    )
    policy_sub = policy_token.add_subparsers(dest="policy_command", required=True)
    issue = policy_sub.add_parser("new", help="issue one: its secret is printed this once")
    issue.add_argument("name", help="what the policy is (shown on the page while it drives)")
    policy_sub.add_parser("list", help="the issued tokens (never their secrets)")
    revoke = policy_sub.add_parser("revoke", help="revoke one: its clients are gone at once")
    revoke.add_argument("id", help="the token's id (telerobot policy-token list)")
    for p in policy_sub.choices.values():
        p.add_argument("--url", help="the server (default: TELEROBOT_URL or http://localhost:8000)")
        p.add_argument(
            "--token",
            help="operator token (default: TELEROBOT_OPERATOR_TOKEN, else the one the server"
            " keeps on this machine)",
        )
    policy_token.set_defaults(func=_policy_token)

    policy = sub.add_parser(
        "policy",
        help="policies: demo (a scripted policy to try supervised autonomy with,"
        " docs/policy-demo.md)",
    )
    policy_cmds = policy.add_subparsers(dest="policy_run", required=True)
    demo = policy_cmds.add_parser(
        "demo",
        help="a scripted policy that reaches for random targets: watch AUTONOMOUS on the"
        " page, take over, correct, hand back",
        description="A scripted policy (no LeRobot, nothing learned) that reaches for"
        " random targets near where the arm is, joined to the server as a policy: the page"
        " says AUTONOMOUS; take over (T), correct, hand back (H), pause and resume (P)."
        " Ctrl+C stops it. docs/policy-demo.md",
    )
    demo.add_argument("--url", help="the server (default: TELEROBOT_URL or http://localhost:8000)")
    demo.add_argument(
        "--token",
        help="a policy token (default: TELEROBOT_POLICY_TOKEN, else one it issues itself"
        " with the operator token and revokes when it stops)",
    )
    demo.add_argument(
        "--arm",
        metavar="NAME",
        action="append",
        help="the arm it moves, on a server with two or more (again for another;"
        " default: every arm)",
    )
    demo.add_argument(
        "--wait",
        action="store_true",
        help="start paused: a person lets it drive (P on the page), not this command",
    )
    demo.add_argument("--seed", type=int, help="the targets' random seed (the same targets)")
    demo.add_argument(
        "--targets", type=int, default=0, help="stop after this many targets (default: Ctrl+C)"
    )
    demo.set_defaults(func=_policy_demo)

    export = sub.add_parser("export", help="export a recording: export lerobot RECORDING DIR")
    export_sub = export.add_subparsers(dest="export_format", required=True)
    lerobot = export_sub.add_parser(
        "lerobot", help="the recording's episodes as a LeRobot v3.0 dataset in a new folder"
    )
    lerobot.add_argument(
        "recording",
        help="the .mcap file, or a recording's id as the page lists it (its file name,"
        " looked up in the server's recordings folder)",
    )
    lerobot.add_argument("dir", type=Path, help="the dataset's folder (new or empty)")
    lerobot.add_argument("--fps", type=int, help="rows per second (default: the video's rate)")
    lerobot.add_argument(
        "--state-dir",
        type=Path,
        help="the server's state folder, whose recordings/ an id is looked up in"
        " (default: TELEROBOT_STATE_DIR, else ~/.config/telerobot)",
    )
    lerobot.add_argument(
        "--allow-repeated-frames",
        action="store_true",
        help="export at an --fps above the recorded video's rate (rows repeat its frames)",
    )
    lerobot.set_defaults(func=_export_lerobot)

    bench = sub.add_parser(
        "bench",
        help="run a benchmark: telerobot bench kinematics --json (--help lists them)",
        description="Run one of the benchmarks (a checkout's bench/): it prints figures,"
        " never pass or fail; --json ends with one JSON line. docs/PERFORMANCE.md has"
        " what they measured.",
        add_help=False,
    )
    bench.add_argument("-h", "--help", action=_BenchHelp)
    bench.add_argument("name", nargs="?", help="the benchmark (listed below)")
    bench.add_argument("rest", nargs=argparse.REMAINDER, help="its own options")
    bench.set_defaults(func=_bench)

    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    # httpx logs every request at INFO (the media server's API, polled): not news.
    logging.getLogger("httpx").setLevel(logging.WARNING)
    try:
        code: int = args.func(args)
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] == "telerobot":
            raise  # ours: a bug, not an install
        # A light install (the client and the bridge: docs/running.md) has not got
        # the server's dependencies.
        print(
            f"telerobot {args.command}: needs {exc.name}, which is not installed here: a"
            " client-only install runs `telerobot move` and `telerobot master`;"
            " `pip install telerobot` installs everything",
            file=sys.stderr,
        )
        return 2
    return code


if __name__ == "__main__":
    sys.exit(main())
