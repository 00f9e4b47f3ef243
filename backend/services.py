"""The composition root (docs/architecture.md, rule 13): every service the server runs, built
once from the settings and a clock into a frozen, typed ``Services``; routers get
them only through the typed dependencies in ``backend/api/deps.py``.

``build_services`` makes them (devices, safety, transports, video, the 3D view);
``start_services`` and ``stop_services`` run them on the event loop, in order. The
small stores a client can write to (captured intrinsics, per-viewer alignments) are
classes here that own their data and its limit.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from telerobot.calibration.model import CalibrationError
from telerobot.calibration.store import CalibrationStore
from telerobot.drivers.base import DeviceError, Robot, TelerobotError
from telerobot.drivers.clock import Clock
from telerobot.drivers.events import Event
from telerobot.drivers.sim.workcell import Workcell
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.autonomy import ReleaseTo
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.control.policy_tokens import PolicyTokens
from telerobot.server.devices import (
    ArmDevices,
    build_arms,
    build_workcell,
    make_kinematics,
)
from telerobot.server.media.media_server import MediaServerSupervisor
from telerobot.server.media.media_server import resolve as resolve_media_server
from telerobot.server.media.observer_feed import ObserverFeed
from telerobot.server.media.supervisor import MediaSupervisor
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.priority import PriorityChannel
from telerobot.server.realtime.ratelimit import PeerLimits
from telerobot.server.recording.recorder import Recorder, RecordingEvent, RecordingTaps, transform
from telerobot.server.recording.video import VideoTap, follow_recorder
from telerobot.server.security import policy_tokens_path, state_dir
from telerobot.server.settings import Settings
from telerobot.server.tasks.runner import TaskRunner
from telerobot.server.telemetry.stats import Telemetry
from telerobot.server.viewer3d import ViewedArm, Workcell3DView
from telerobot.tuning import realtime_summary

log = logging.getLogger("telerobot")

CameraName = Literal["left", "right"]
MAX_ALIGNMENTS = 1000  # viewer names with a saved shift; the oldest written goes first


@dataclass(frozen=True)
class OperatorToken:
    value: str = field(repr=False)
    is_new: bool  # made at this start: printed once


@dataclass
class CalibrationRecord:
    """The rig's saved calibration and, if its file could not be read, why (the file
    is kept as it is and the cameras' ground truth stands in)."""

    store: CalibrationStore
    load_error: str | None = None
    # Emitted (on the event loop) when a fit is kept or the calibration is cleared.
    changed: Event[CalibrationStore] = field(default_factory=lambda: Event("calibration"))

    @classmethod
    def load(cls, settings: Settings) -> CalibrationRecord:
        rig = settings.rig_name
        store = CalibrationStore(state_dir(settings) / f"calibration-{rig}.json", rig)
        try:
            return cls(store.load())
        except CalibrationError as exc:
            log.error("%s", exc)
            return cls(store, str(exc))


@dataclass
class Intrinsics:
    """Each camera's K and distortion from a ChArUco capture, kept until its fiducial
    fit uses them: one entry per camera at most."""

    _by_camera: dict[CameraName, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def get(self, camera: CameraName) -> tuple[np.ndarray, np.ndarray] | None:
        return self._by_camera.get(camera)

    def put(self, camera: CameraName, K: np.ndarray, dist: np.ndarray) -> None:
        self._by_camera[camera] = (K, dist)

    def pending(self) -> list[str]:
        return sorted(self._by_camera)

    def clear(self) -> None:
        self._by_camera.clear()


@dataclass
class Alignments:
    """Each viewer's shift of the right image (dx, dy pixels), bounded: writing one
    beyond ``limit`` drops the one written longest ago."""

    limit: int = MAX_ALIGNMENTS
    _saved: OrderedDict[str, tuple[int, int]] = field(default_factory=OrderedDict)

    def get(self, viewer: str) -> tuple[int, int] | None:
        return self._saved.get(viewer)

    def remember(self, viewer: str, shift: tuple[int, int]) -> None:
        self._saved.pop(viewer, None)
        self._saved[viewer] = shift
        while len(self._saved) > self.limit:
            self._saved.popitem(last=False)

    def __len__(self) -> int:
        return len(self._saved)


@dataclass
class Viewer3D:
    """The 3D view, or why there is none (off, or its port taken)."""

    view: Workcell3DView | None
    error: str | None


@dataclass(frozen=True)
class Services:
    settings: Settings
    clock: Clock
    token: OperatorToken
    telemetry: Telemetry
    workcell: Workcell
    calibration: CalibrationRecord
    intrinsics: Intrinsics
    alignments: Alignments
    decision: DecisionServer
    hub: RealtimeHub
    priority: PriorityChannel
    media: MediaSupervisor | None
    media_server: MediaServerSupervisor | None  # observers' video through Janus
    observer_feed: ObserverFeed | None  # their state and forces, through its data channel
    viewer: Viewer3D
    recorder: Recorder
    recording_taps: RecordingTaps
    task_runner: TaskRunner  # supervisory tasks: taught motions repeated under guards
    # Every arm (docs/arms.md): names, drivers, sensors, mounts.
    arms: list[ArmDevices] = field(default_factory=list)
    ws_limits: PeerLimits = field(default_factory=PeerLimits)  # per address, on /ws
    tasks: list[asyncio.Task[None]] = field(default_factory=list)


def safety_limits(settings: Settings) -> SafetyLimits:
    """The settings' limits; the rest of ``SafetyLimits`` keeps its defaults."""
    model = settings.model
    return SafetyLimits(
        workspace_min=np.array(model.workspace_min),
        workspace_max=np.array(model.workspace_max),
        force_limit_n=settings.force_limit_n,
        deadman_timeout_s=settings.deadman_timeout_s,
        lease_grace_s=settings.lease_grace_s,
        max_command_age_s=settings.max_command_age_ms / 1000,
        max_speed_m_s=settings.max_speed_m_s,
        contact_speed_m_s=settings.contact_speed_m_s,
    )


def build_viewer(
    settings: Settings,
    workcell: Workcell,
    arms: list[ArmDevices],
    calibration: CalibrationStore,
) -> Viewer3D:
    """The 3D view of every arm, if on; one that cannot start (port taken) is reported,
    and the server runs without it."""
    if not settings.viewer:
        return Viewer3D(None, "the 3D view is off (setting viewer)")
    try:
        view = Workcell3DView(
            settings.host,
            settings.viewer_port,
            workcell,
            # each arm's own model, not the server's default
            [ViewedArm(a.robot, make_kinematics(a.settings), a.mount, a.force) for a in arms],
            calibration,
        )
    except (OSError, ImportError) as exc:
        log.error("the 3D view cannot start on port %s: %s", settings.viewer_port, exc)
        return Viewer3D(None, f"the 3D view cannot start on port {settings.viewer_port}: {exc}")
    return Viewer3D(view, None)


def build_services(settings: Settings, clock: Clock, token: OperatorToken) -> Services:
    """Every service, made once; nothing runs until ``start_services``."""
    telemetry = Telemetry()
    workcell = build_workcell(settings)
    arms = build_arms(settings, clock, workcell)
    # The DecisionServer's own models (same tool): Pinocchio data is per instance.
    decision = DecisionServer(
        [
            ArmGuard(
                arm.name,
                i + 1,
                arm.robot,
                make_kinematics(arm.settings),
                safety_limits(arm.settings),
                arm.force,
                arm.mount,
            )
            for i, arm in enumerate(arms)
        ],
        clock=clock,
        operator_token=token.value,
        policy_tokens=PolicyTokens(policy_tokens_path(settings)),
        limits=safety_limits(settings),
    )
    decision.supervision.release_to = ReleaseTo(settings.autonomy_release)
    hub = RealtimeHub(decision, telemetry, clock, state_rate_hz=settings.state_rate_hz)
    try:
        priority = PriorityChannel(settings.host, settings.priority_port, hub, decision)
    except OSError as exc:
        raise DeviceError(
            f"the priority channel cannot listen on {settings.host}:{settings.priority_port}"
            f" ({exc.strerror}): set TELEROBOT_PRIORITY_PORT or --priority-port"
        ) from None
    calibration = CalibrationRecord.load(settings)
    recorder = Recorder(
        state_dir(settings) / "recordings",
        clock,
        max_bytes=settings.recording_max_bytes,
        min_free_bytes=settings.recording_min_free_bytes,
    )
    recorder.snapshot = lambda: [
        *recording_snapshot(settings, workcell, calibration, recorder),
        ("/autonomy", decision.autonomy.state().as_dict()),  # who drives as it starts
    ]
    # A recalibration mid-recording is in the file from that moment on.
    calibration.changed.subscribe(
        lambda _store: recorder.log("/calibration", calibration_payload(workcell, calibration))
    )
    recorder.events.subscribe(lambda e: _announce_recording(hub, e))
    media_server = None
    media_settings = settings
    if settings.video and settings.media_server != "none":
        media_settings = resolve_media_server(settings, token.value)
        media_server = MediaServerSupervisor(media_settings, settings.media_server_url is None)
    media = MediaSupervisor(media_settings, [a.robot for a in arms]) if settings.video else None
    if media is not None:  # the video as sent, while a recording runs
        follow_recorder(VideoTap(media), recorder)
    task_runner = TaskRunner(decision, clock, operator_token=token.value)
    return Services(
        settings=settings,
        clock=clock,
        token=token,
        telemetry=telemetry,
        workcell=workcell,
        calibration=calibration,
        intrinsics=Intrinsics(),
        alignments=Alignments(),
        decision=decision,
        hub=hub,
        priority=priority,
        media=media,
        media_server=media_server,
        observer_feed=ObserverFeed(
            hub,
            media_settings.media_server_host or "127.0.0.1",
            media_settings.media_server_data_port,
        )
        if media_server is not None and media_settings.media_server_data_port
        else None,
        viewer=build_viewer(settings, workcell, arms, calibration.store),
        recorder=recorder,
        recording_taps=RecordingTaps(
            recorder,
            decision=decision,
            clock=clock,
            state_period=1.0 / settings.state_rate_hz,
            tasks=task_runner.events.changed,
        ),
        task_runner=task_runner,
        arms=arms,
    )


def recording_snapshot(
    settings: Settings, workcell: Workcell, calibration: CalibrationRecord, recorder: Recorder
) -> list[tuple[str, dict[str, Any]]]:
    """What a recording starts with: the settings in force (no token or TURN secret), the
    calibration, and the cameras' poses in the base frame (the rig's ground truth)."""
    wall = recorder.wall_ns()
    cams = []
    for cam in (workcell.rig.left, workcell.rig.right):
        # world → camera (R, t): the camera in the base frame is (Rᵀ, −Rᵀ t)
        cams.append(transform("base", f"camera_{cam.name}", cam.R.T, -cam.R.T @ cam.t, wall))
    return [
        (
            "/settings",
            settings.model_dump(
                mode="json",
                exclude={
                    "operator_token",
                    "turn_secret",
                    "media_server_secret",
                    "media_server_api_secret",
                },
            ),
        ),
        ("/calibration", calibration_payload(workcell, calibration)),
        ("/tf", {"transforms": cams}),
    ]


def calibration_payload(workcell: Workcell, calibration: CalibrationRecord) -> dict[str, Any]:
    """The recording's ``/calibration``: the fits in force and the rig's ground truth."""
    store = calibration.store
    return {
        "rig": store.rig,
        "cameras": {n: m.to_json() for n, m in store.cameras.items()},
        "ground_truth_P": {c.name: c.P.tolist() for c in (workcell.rig.left, workcell.rig.right)},
        "error": calibration.load_error,
    }


def _announce_recording(hub: RealtimeHub, e: RecordingEvent) -> None:
    """Every viewer sees a recording start and stop (and why it stopped)."""
    from telerobot.protocol.messages import EventKind

    if e.kind == "started":
        text = f"RECORDING started: {e.file}"
    else:
        text = f"RECORDING stopped: {e.file or e.name} ({e.reason})"
    hub.broadcast_event(EventKind.INFO, text)


async def bring_up_robot(robot: Robot, initialize: bool, arm: str | None = None) -> None:
    """Connect and initialise; a failure leaves the robot in ERROR with its reason
    (shown by the state endpoint) and the server keeps serving. ``arm``: its name on a
    server of several arms (each says which it is: two drivers of one model have one
    name)."""
    who = f"robot {robot.name}" if arm is None else f"arm {arm} (robot {robot.name})"
    try:
        await robot.connect()
        if initialize:
            await robot.initialize()
        log.info("%s is %s", who, robot.status)
    except TelerobotError as exc:
        log.error("%s could not be brought up: %s", who, exc)


async def start_services(s: Services) -> None:
    s.hub.start()
    s.decision.start()  # the force limit and the dead-man, whatever transports run
    s.priority.start()
    for arm in s.arms:
        arm.force.start()
    # What the 1 kHz threads got, said once at start (docs/running.md, "Realtime").
    summary = realtime_summary()
    (log.info if summary.startswith("force threads: realtime") else log.warning)("%s", summary)
    s.recording_taps.start()
    if s.viewer.view is not None:
        s.viewer.view.start()
    if s.media_server is not None:
        await s.media_server.start()
    if s.observer_feed is not None:
        s.observer_feed.start()
    if s.media is not None:
        await s.media.start()
    for arm in s.arms:
        s.tasks.append(
            asyncio.create_task(
                bring_up_robot(
                    arm.robot, s.settings.auto_initialize, arm.name if len(s.arms) > 1 else None
                ),
                name=f"bring-up-{arm.name}",
            )
        )


async def stop_services(s: Services) -> None:
    for task in s.tasks:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, TelerobotError):
            await task
    if s.recorder.active:
        await s.recorder.stop("the server stopped")
    await s.recording_taps.stop()
    for arm in s.arms:
        arm.force.stop()
    if s.viewer.view is not None:
        await s.viewer.view.stop()
    if s.media is not None:
        await s.media.stop()
    if s.observer_feed is not None:
        await s.observer_feed.stop()
    if s.media_server is not None:
        await s.media_server.stop()
    await s.priority.stop()
    await s.hub.stop()
    await s.task_runner.stop()
    await s.decision.stop()
    for arm in s.arms:
        await arm.robot.disconnect()
