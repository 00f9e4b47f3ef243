"""The media worker: a process of its own running capture, the encoder and every
WebRTC peer, so video can never stall the control and force channel on the server's
event loop. The server talks to it over a pipe (``MediaSupervisor``) and shares every
arm's state with it through shared memory, one array per arm (for the simulated camera).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import functools
import logging
import multiprocessing
import multiprocessing.connection
import signal
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, assert_never

import numpy as np

from telerobot.drivers.base import ArmSnapshot, OtherArm, StereoCamera, TelerobotError
from telerobot.drivers.registry import load_driver
from telerobot.server.devices import (
    arm_mounts,
    build_camera,
    build_workcell,
    device_context,
    make_kinematics,
)
from telerobot.server.media import rpc
from telerobot.server.settings import Settings
from telerobot.tuning import yield_cpu

if TYPE_CHECKING:
    from telerobot.server.media.pipeline import VideoPipeline
    from telerobot.server.media.relay import JanusRelay
    from telerobot.server.media.tap import PacketPipe

log = logging.getLogger(__name__)


class NoMediaServer(TelerobotError):
    """A relay request (the observers' media server) to a server started without one:
    a request for what is not there (503, as for video that is off), not a failure."""

    code = "no_media_server"
    http_status = 503


def arm_fields(dof: int) -> int:
    """The shared arm state's length: time, the joints, their velocities."""
    return 1 + 2 * dof


def shared_arm_probe(arm: Any) -> Callable[[], ArmSnapshot]:
    def probe() -> ArmSnapshot:
        with arm.get_lock():
            values = np.frombuffer(arm.get_obj(), dtype=np.float64).copy()
        dof = (len(values) - 1) // 2
        return ArmSnapshot(float(values[0]), values[1 : 1 + dof], values[1 + dof :])

    return probe


def build_arms_camera(
    settings: Settings, probes: Sequence[Callable[[], ArmSnapshot]]
) -> StereoCamera:
    """The camera the settings name, following every arm (``probes``, in the settings'
    arm order). With two arms or more it is built for the first arm (its model, its
    kinematics) in the two-arm workcell; a simulated one draws the others too, each from
    its own model at its mount (a real camera films them as they are)."""
    if len(probes) == 1:
        return build_camera(settings, probes[0])
    arms = settings.arm_settings()
    first = arms[0][1]
    others = tuple(
        OtherArm(probe, functools.partial(make_kinematics, own), own.robot_model, mount)
        for (_, own), mount, probe in zip(
            arms[1:], arm_mounts(settings)[1:], probes[1:], strict=True
        )
    )
    context = dataclasses.replace(
        device_context(first, workcell=build_workcell(settings), arm_probe=probes[0]),
        other_arms=others,
    )
    camera: StereoCamera = load_driver("camera", settings.camera).from_settings(
        first.model_dump(), context
    )
    return camera


def worker_main(
    conn: multiprocessing.connection.Connection,
    settings_json: str,
    arms: Sequence[Any],
    video: multiprocessing.connection.Connection | None = None,
) -> None:
    """``conn`` carries requests and replies; ``arms`` is every arm's shared state (time,
    joints, velocities; ``arm_fields``), in the settings' arm order; ``video`` (send
    only) the recording's packets while one runs (``backend/media/tap.py``)."""
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s media-worker: %(message)s"
    )
    logging.getLogger("httpx").setLevel(logging.WARNING)  # each media server request
    # Video yields the CPU to forces and control: on a busy machine the scheduler runs
    # the server's sensor and priority-channel threads first (a frame late by a
    # millisecond is not seen; a force sample late by one is felt).
    # Ctrl+C at the terminal reaches every process of the group: the server stops this
    # worker itself, in order; interrupted here, it printed a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    settings = Settings.model_validate_json(settings_json)
    yield_cpu(settings.video_nice)
    try:
        import uvloop

        uvloop.install()
    except ImportError:
        pass
    asyncio.run(_serve(conn, settings, arms, video))


async def _serve(
    conn: multiprocessing.connection.Connection,
    settings: Settings,
    arms: Sequence[Any],
    video: multiprocessing.connection.Connection | None = None,
) -> None:
    from telerobot.server.media.pipeline import VideoPipeline, VideoSettings
    from telerobot.server.media.tap import PacketPipe

    camera = build_arms_camera(settings, [shared_arm_probe(arm) for arm in arms])
    pipeline = VideoPipeline(
        camera,
        VideoSettings.of(settings),
        max_viewers=settings.video_max_viewers,
    )
    pipeline.start()
    relay = _start_relay(settings, pipeline)
    tap = (
        PacketPipe(video.send_bytes, pipeline.encoding.broadcaster.request_keyframe)
        if video is not None
        else None
    )
    served = _Served(pipeline, camera, relay, tap)
    loop = asyncio.get_running_loop()
    requests: asyncio.Queue[rpc.Envelope] = asyncio.Queue()

    def readable() -> None:
        try:
            requests.put_nowait(conn.recv())
        except EOFError:  # the server is gone
            loop.remove_reader(conn.fileno())
            requests.put_nowait(rpc.Envelope(None, rpc.Shutdown()))

    loop.add_reader(conn.fileno(), readable)
    conn.send(rpc.Ready(time.monotonic()))

    async def handle(envelope: rpc.Envelope) -> None:
        try:
            reply = rpc.Reply(envelope.id, True, await served.serve(envelope.request))
        except TelerobotError as exc:
            reply = rpc.Reply(envelope.id, False, code=exc.code, error=str(exc))
        except Exception as exc:  # a bug must not take the worker down with it
            log.exception("media request failed")
            reply = rpc.Reply(
                envelope.id, False, code="media_error", error=f"{type(exc).__name__}: {exc}"
            )
        with contextlib.suppress(OSError):
            conn.send(reply)

    tasks: set[asyncio.Task[None]] = set()
    while True:
        envelope = await requests.get()
        if isinstance(envelope.request, rpc.Shutdown):
            break
        task = asyncio.create_task(handle(envelope))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
    if relay is not None:
        await relay.shutdown()
    await pipeline.close()


def _start_relay(settings: Settings, pipeline: VideoPipeline) -> JanusRelay | None:
    """Observers through the media server (``--media-server janus``), fed the pipeline's
    packets while any watch; None without one."""
    if settings.media_server != "janus":
        return None
    from telerobot.server.media.relay import JanusRelay, RelayLimits

    assert settings.media_server_url is not None  # resolved by the server

    def start_feed() -> None:
        pipeline.encoding.start_tap(relay.send, "relay")

    relay = JanusRelay(
        settings.media_server_url,
        settings.media_server_rtp_port,
        settings.media_server_rtcp_port or None,
        pipeline.encoding.broadcaster.request_keyframe,
        start_feed=start_feed,
        stop_feed=lambda: pipeline.encoding.stop_tap("relay"),
        limits=RelayLimits.of(settings),
        api_secret=settings.media_server_api_secret,
        host=settings.media_server_host or "127.0.0.1",
        mountpoint=settings.media_server_mountpoint,
    )
    relay.start()
    return relay


@dataclasses.dataclass
class _Served:
    """What the worker answers the server's requests about: the pipeline, its camera, the
    relay to the media server (None: none) and the recording's pipe (None: none)."""

    pipeline: VideoPipeline
    camera: Any
    relay: JanusRelay | None
    tap: PacketPipe | None

    async def serve(self, req: rpc.MediaRequest) -> dict[str, Any]:
        """One request's answer (its reply's fields); a ``TelerobotError`` refuses it."""
        from telerobot.server.media.relay import RELAY_PREFIX

        pipeline, relay, tap = self.pipeline, self.relay, self.tap
        match req:
            case rpc.Answer(sdp, kind, layer, operator):
                return await pipeline.answer(sdp, kind, layer, operator)
            case rpc.Offer(layer, operator):
                return await pipeline.offer(layer, operator)
            case rpc.Accept(peer_id, sdp, kind, secret):
                return await pipeline.accept(peer_id, sdp, kind, secret)
            case rpc.ClosePeer(peer_id, secret, operator):
                # The server checked the operator token; anyone else shows the secret.
                if operator:
                    await pipeline.close_peer(peer_id)
                else:
                    await pipeline.close_own_peer(peer_id, secret)
            case rpc.ClaimViewer(peer_id, secret, viewer):
                if relay is not None and peer_id.startswith(RELAY_PREFIX):
                    relay.claim_viewer(peer_id, secret, viewer)
                else:
                    pipeline.claim_viewer(peer_id, secret, viewer)
            case rpc.Stats(peer_ids):
                stats = pipeline.stats(peer_ids=peer_ids)
                if relay is not None:
                    stats["relay"] = relay.stats()
                return {"stats": stats}
            case rpc.RelayOffer() | rpc.RelayAccept() | rpc.RelayAlive() | rpc.RelayClose():
                if relay is None:
                    raise NoMediaServer("this server has no media server (--media-server)")
                return await serve_relay(relay, req)
            case rpc.Keyframe():
                pipeline.encoding.broadcaster.request_keyframe()  # shared and rate-limited like any
            case rpc.Record(on):
                if tap is None:
                    raise TelerobotError("this media worker has no pipe for the recording")
                if on:
                    tap.restart()
                    pipeline.encoding.start_tap(tap.push)
                else:
                    pipeline.encoding.stop_tap()
                return {"sent": tap.sent, "dropped": tap.dropped}
            case rpc.Board(view):
                self.camera.show_board(view)
            case rpc.Shutdown():
                pass  # handled by the worker's loop
            case _:
                assert_never(req)
        return {}


async def serve_relay(
    relay: JanusRelay,
    req: rpc.RelayOffer | rpc.RelayAccept | rpc.RelayAlive | rpc.RelayClose,
) -> dict[str, Any]:
    """A request about an observer watching through the media server."""
    match req:
        case rpc.RelayOffer(address):
            return await relay.offer(address)
        case rpc.RelayAccept(peer_id, secret, sdp):
            await relay.accept(peer_id, secret, sdp)
        case rpc.RelayAlive(peer_id, secret):
            relay.alive(peer_id, secret)
        case rpc.RelayClose(peer_id, secret, operator):
            await relay.close_viewer(peer_id, secret, operator)
        case _:
            assert_never(req)
    return {}
