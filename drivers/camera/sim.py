"""``SimStereoCamera``: renders the simulated workcell through the ground-truth
stereo pair (drivers/sim/workcell.py), so calibration and AR can be checked against
known projections.

The static scene (background, table, block, fiducials, each arm's pedestal) is
rendered once per eye; each frame copies it and draws every arm (``DrawnArm``: its own
model's drawing, kinematics and state, placed at its mount) at its current joints,
plus an optional visual timecode and, beside it, a motion mark (motion_mark.py: the
first arm's tool position as rulers, for bench.hand_to_eye). Rendering runs in its own
thread on an absolute schedule and hands frames over through a newest-wins slot.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Self

import cv2
import numpy as np

from telerobot.drivers.base import (
    ArmSnapshot,
    CameraStatus,
    DeviceContext,
    FloatArray,
    StereoFrame,
)
from telerobot.drivers.camera import motion_mark, timecode
from telerobot.drivers.camera.charuco_board import BoardSpec, board_poses, draw_board, view_distance
from telerobot.drivers.camera.slot import FrameSlot
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.drivers.robot.models import DEFAULT_MODEL, load_model
from telerobot.drivers.robot.models.drawing import ArmDrawing
from telerobot.drivers.sim.workcell import Box, PinholeCamera, Workcell
from telerobot.drivers.threads import WorkerThread

log = logging.getLogger(__name__)

FIDUCIAL_RADIUS = 0.015  # m
FIDUCIAL_COLOURS = (  # RGB, in the workcell's order: the affine basis first
    (255, 220, 0),
    (0, 200, 80),
    (40, 120, 255),
    (230, 0, 200),
    (0, 220, 220),
    (255, 255, 255),
    (120, 60, 220),
    (255, 110, 110),
    (150, 255, 0),
    (0, 90, 160),
    (255, 150, 200),
    (200, 200, 90),
)
BOARD = BoardSpec()  # the ChArUco board the calibration page asks for
GRIPPER_COLOUR = (255, 140, 0)


def _shade(colour: tuple[int, int, int], k: float) -> tuple[int, int, int]:
    return (int(colour[0] * k), int(colour[1] * k), int(colour[2] * k))


IDLE_AFTER_S = 1.0  # no reader for this long: stop rendering until one asks
# The camera exposes on its own grid of 1/fps, like a triggered camera: a thread that
# was held up (a busy machine) renders the exposures it missed, each at its own time,
# as long as it is at most this far behind; further behind it skips to now (the frames
# between are missing, and the recording's export flags the rows they leave).
CATCH_UP_S = 0.2
EXTRAPOLATE_S = 0.05  # ahead of the newest arm sample, at most (its period is 1-20 ms)


@dataclass(frozen=True)
class DrawnArm:
    """One arm the camera draws: where its state comes from (any thread), its own
    kinematics and drawing (Pinocchio data is per thread: the camera's own), where its
    base stands in the workcell (4×4) and its pedestal (0: none)."""

    probe: Callable[[], ArmSnapshot]
    kinematics: ArmKinematics
    drawing: ArmDrawing
    mount: FloatArray = field(default_factory=lambda: np.eye(4))
    pedestal_m: float = 0.0  # from the floor up to the base, along the base's z
    scale: float = 1.0  # of the PUMA-sized scene: the gripper and pedestal are sized by it

    def placed(self, points: FloatArray) -> FloatArray:
        """Points in the arm's base frame (… × 3) in the workcell's frame."""
        if np.array_equal(self.mount, np.eye(4)):
            return points  # the first arm's base is the scene's frame: unchanged
        moved: FloatArray = points @ self.mount[:3, :3].T + self.mount[:3, 3]
        return moved


@dataclass(frozen=True)
class SimStereoCameraConfig:
    """What ``SimStereoCamera`` reads from the settings (its image size is the
    workcell's cameras', made for the video's size)."""

    fps: float = 30.0

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        return cls(fps=float(settings["video_fps"]))


class SimStereoCamera:
    name = "sim-stereo"

    def __init__(
        self,
        workcell: Workcell,
        probe: Callable[[], ArmSnapshot],
        kinematics: ArmKinematics,
        *,
        drawing: ArmDrawing | None = None,
        more_arms: Sequence[DrawnArm] = (),
        fps: float = 30.0,
        show_timecode: bool = True,
        show_motion_mark: bool | None = None,
        time_source: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.workcell = workcell
        self.cameras = (workcell.rig.left, workcell.rig.right)
        self.width, self.height = self.cameras[0].width, self.cameras[0].height
        self.fps = fps
        self.probe = probe
        self.kinematics = kinematics  # this camera's own (Pinocchio data is per thread)
        # The arm's links as its model draws them (the PUMA if not said).
        self.drawing = drawing or ArmDrawing(load_model(DEFAULT_MODEL))
        # Every arm drawn, the first (the one above) first: at the workcell's first mount,
        # on the workcell's pedestal, sized with its scene.
        first = DrawnArm(
            probe,
            kinematics,
            self.drawing,
            workcell.mounts[0] if workcell.mounts else np.eye(4),
            workcell.pedestal_m,
            workcell.scale,
        )
        self.arms: tuple[DrawnArm, ...] = (first, *more_arms)
        self.show_timecode = show_timecode
        # The motion mark goes with the timecode unless said (it is read beside it).
        self.show_motion_mark = show_timecode if show_motion_mark is None else show_motion_mark
        self._now = time_source
        self._sleep = sleep
        self._slot = FrameSlot()
        self._seq = 0
        self.board: tuple[np.ndarray, np.ndarray] | None = None  # pose, while shown
        self._worker = WorkerThread(self._run, "sim-stereo-camera")
        self._stop = self._worker.stopping
        self._status = CameraStatus.STOPPED
        self._background = np.concatenate([self._render_static(c) for c in self.cameras], axis=1)
        self.render_ms = 0.0  # last frame's render time
        self._wanted_at = -math.inf  # when a reader last asked for a frame

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        """The workcell's ground-truth pair, drawing the arm the context follows and the
        server's other arms, each from its own model at its mount."""
        config = SimStereoCameraConfig.from_settings(settings)
        drawing = ArmDrawing(load_model(str(settings.get("robot_model", DEFAULT_MODEL))))
        others = []
        for arm in context.other_arms:
            model = load_model(arm.model)
            others.append(
                DrawnArm(
                    arm.probe,
                    arm.kinematics(),
                    ArmDrawing(model),
                    mount=arm.mount,
                    pedestal_m=model.pedestal_m,
                    scale=model.scene_scale,
                )
            )
        return cls(
            context.workcell(),
            context.arm_probe,
            context.kinematics(),
            drawing=drawing,
            more_arms=others,
            fps=config.fps,
        )

    @classmethod
    def default_rig(cls, settings: Mapping[str, Any]) -> str:
        return "sim"

    # ------------------------------------------------------------ status
    @property
    def status(self) -> CameraStatus:
        return self._status

    @property
    def status_message(self) -> str:
        return {CameraStatus.RUNNING: f"rendering {self.fps:g} fps"}.get(
            self._status, self._status.value.lower()
        )

    @property
    def background(self) -> np.ndarray:
        """The static scene, side by side, as every frame starts from it."""
        return self._background.copy()

    # ------------------------------------------------------------ rendering
    def _render_static(self, cam: PinholeCamera) -> np.ndarray:
        h, w = cam.height, cam.width
        img = np.empty((h, w, 3), np.uint8)
        ramp = np.linspace(0, 1, h)[:, None]
        img[:] = (np.array([200, 205, 212]) * (1 - ramp) + np.array([120, 124, 130]) * ramp).astype(
            np.uint8
        )[:, None]
        # The pedestals first: seen from the cameras they stand behind the table.
        for k in self._far_first(cam):
            arm = self.arms[k]
            if arm.pedestal_m > 0:
                foot, top = arm.placed(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, arm.pedestal_m]]))
                self._draw_link(img, cam, foot, top, 0.09 * arm.scale, (90, 90, 96))
        # The table, its grid, then what stands on it. A box's visible faces never
        # overlap each other, so they need no sorting.
        for i, box in enumerate(self.workcell.obstacles):
            for _, pts, colour in self._box_faces(cam, box):
                cv2.fillConvexPoly(img, pts, colour, lineType=cv2.LINE_AA)
            if i == 0:
                self._draw_table_grid(img, cam)
        for colour, p in zip(itertools.cycle(FIDUCIAL_COLOURS), self.workcell.fiducials):
            self._draw_ball(img, cam, p, FIDUCIAL_RADIUS * self.workcell.scale, colour)
        return img

    def _box_faces(
        self, cam: PinholeCamera, box: Box
    ) -> list[tuple[float, np.ndarray, tuple[int, int, int]]]:
        lo, hi = box.lower, box.upper
        faces = []
        for axis in range(3):
            for side, value in ((-1, lo[axis]), (1, hi[axis])):
                normal = np.zeros(3)
                normal[axis] = side
                centre = (lo + hi) / 2
                centre[axis] = value
                if (cam.position - centre) @ normal <= 0:
                    continue  # back face
                u, v = [a for a in range(3) if a != axis]
                corners = []
                for a, b in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    c = centre.copy()
                    c[u] = (lo[u], hi[u])[a]
                    c[v] = (lo[v], hi[v])[b]
                    corners.append(c)
                pts = cam.project(np.array(corners))
                if np.isnan(pts).any():
                    continue
                shade = 1.0 if axis == 2 else (0.75 if axis == 0 else 0.6)
                depth = float(cam.to_camera(centre[None])[0, 2])
                faces.append((depth, np.round(pts).astype(np.int32), _shade(box.colour, shade)))
        return faces

    def _draw_table_grid(self, img: np.ndarray, cam: PinholeCamera) -> None:
        table = self.workcell.table
        z = table.upper[2] + 1e-4
        lo, hi = table.lower, table.upper
        colour = _shade(table.colour, 0.8)
        for x in np.arange(lo[0], hi[0] + 1e-9, 0.05 * self.workcell.scale):
            self._line(img, cam, np.array([x, lo[1], z]), np.array([x, hi[1], z]), colour, 1)
        for y in np.arange(lo[1], hi[1] + 1e-9, 0.05 * self.workcell.scale):
            self._line(img, cam, np.array([lo[0], y, z]), np.array([hi[0], y, z]), colour, 1)

    @staticmethod
    def _line(
        img: np.ndarray,
        cam: PinholeCamera,
        a: np.ndarray,
        b: np.ndarray,
        colour: tuple[int, int, int],
        width: int,
    ) -> None:
        pa, pb = cam.project(np.array([a, b]))
        if not (np.isnan(pa).any() or np.isnan(pb).any()):
            cv2.line(
                img,
                tuple(np.round(pa).astype(int)),
                tuple(np.round(pb).astype(int)),
                colour,
                width,
                cv2.LINE_AA,
            )

    @staticmethod
    def _radius_px(cam: PinholeCamera, p: np.ndarray, radius: float) -> int:
        z = float(cam.to_camera(p[None])[0, 2])
        return max(1, round(cam.K[0, 0] * radius / z)) if z > 0 else 1

    def _draw_link(
        self,
        img: np.ndarray,
        cam: PinholeCamera,
        a: np.ndarray,
        b: np.ndarray,
        radius: float,
        colour: tuple[int, int, int],
    ) -> None:
        width = 2 * self._radius_px(cam, (a + b) / 2, radius)
        self._line(img, cam, a, b, colour, width)

    def _draw_ball(
        self,
        img: np.ndarray,
        cam: PinholeCamera,
        p: np.ndarray,
        radius: float,
        colour: tuple[int, int, int],
    ) -> None:
        uv = cam.project(p[None])[0]
        if not np.isnan(uv).any():
            cv2.circle(
                img,
                tuple(np.round(uv).astype(int)),
                self._radius_px(cam, p, radius),
                colour,
                -1,
                cv2.LINE_AA,
            )

    def _far_first(self, cam: PinholeCamera) -> list[int]:
        """The arms' indices, the one whose base is farthest from ``cam`` first (painted
        over by the nearer ones)."""
        if len(self.arms) == 1:
            return [0]
        depth = [float(cam.to_camera(arm.mount[None, :3, 3])[0, 2]) for arm in self.arms]
        return [int(k) for k in np.argsort(depth, kind="stable")[::-1]]

    def _draw_arm(self, img: np.ndarray, cam: PinholeCamera, arm: DrawnArm, q: FloatArray) -> None:
        pts = arm.placed(arm.kinematics.link_origins(q))
        drawing = arm.drawing
        for (a, b), radius in zip(arm.placed(drawing.segments(q)), drawing.radii, strict=True):
            if np.linalg.norm(b - a) > 1e-6:
                self._draw_link(img, cam, a, b, radius, (160, 162, 170))
        joint_radius = 1.1 * float(drawing.radii.max())
        for p in pts[1:-1]:  # each joint
            self._draw_ball(img, cam, p, joint_radius, (110, 112, 120))
        scale = arm.scale
        self._draw_link(img, cam, pts[-2], pts[-1], 0.012 * scale, GRIPPER_COLOUR)
        self._draw_ball(img, cam, pts[-1], 0.018 * scale, GRIPPER_COLOUR)

    def render(self, t: float) -> np.ndarray:
        """The side-by-side image at time ``t`` (each arm at its joints extrapolated from
        its newest sample, back to ``t`` for an exposure the thread renders late)."""
        joints = []
        for arm in self.arms:
            snap = arm.probe()
            dt = min(max(t - snap.time, -CATCH_UP_S), EXTRAPOLATE_S)
            joints.append(snap.joints + snap.velocities * dt)
        sbs = self._background.copy()
        board = self.board
        for i, cam in enumerate(self.cameras):
            eye = sbs[:, i * self.width : (i + 1) * self.width]
            for k in self._far_first(cam):
                self._draw_arm(eye, cam, self.arms[k], joints[k])
            if board is not None:  # held up in front of the cameras, for calibration
                draw_board(eye, cam.K, cam.R, cam.t, board[0], board[1], BOARD)
        if self.show_timecode:
            timecode.draw(sbs[:, : self.width], t)
        if self.show_motion_mark:
            motion_mark.draw(sbs[:, : self.width], self.tool_in_left_camera(joints[0]))
        return sbs

    def tool_in_left_camera(self, q: FloatArray) -> FloatArray:
        """The first arm's tool (where its gripper is drawn) at joints ``q``, in the left
        camera's frame (x right, y down, z forward; metres)."""
        arm = self.arms[0]
        tool = arm.placed(arm.kinematics.link_origins(q))[-1]
        at: FloatArray = self.cameras[0].to_camera(tool[None])[0]
        return at

    # ------------------------------------------------------------ calibration board
    def show_board(self, view: int | None, views: int = 12) -> None:
        """Hold the ChArUco board up in front of both cameras, at the ``view``-th of
        ``views`` calibration poses (tilted, spread over the image); None puts it away."""
        if view is None:
            self.board = None
            return
        left = self.cameras[0]
        distance = view_distance(left.K, self.width, BOARD)
        poses = board_poses(left.R, left.t, distance, BOARD, views=views, seed=7)
        self.board = poses[view % views]

    # ------------------------------------------------------------ capture thread
    def start(self) -> None:
        self._worker.start()
        self._status = CameraStatus.RUNNING

    def stop(self) -> None:
        self._worker.stop()
        self._status = CameraStatus.STOPPED

    @property
    def wanted(self) -> bool:
        """Whether a reader asked for a frame within ``IDLE_AFTER_S``: the thread renders
        only then. With nobody watching, 2×1280×720 at 30 fps would take ~10 % of a
        core from the 1 kHz force path for nothing (bench.force_stream)."""
        return self._now() - self._wanted_at <= IDLE_AFTER_S

    def next_frame(self, after_seq: int, timeout: float, every: bool = False) -> StereoFrame | None:
        self._wanted_at = self._now()
        return self._slot.next_frame(after_seq, timeout, every)

    @property
    def dropped(self) -> int:
        return self._slot.dropped

    def capture(self, at: float | None = None) -> StereoFrame:
        """Render one frame exposed at ``at`` (now if None) and publish it (the thread
        calls this on its grid of ``1/fps``)."""
        t = self._now() if at is None else at
        started = time.perf_counter()
        sbs = self.render(t)
        self.render_ms = (time.perf_counter() - started) * 1000
        self._seq += 1
        frame = StereoFrame(self._seq, t, sbs)
        self._slot.put(frame)
        return frame

    def _run(self) -> None:
        period = 1.0 / self.fps
        next_t = self._now()
        while not self._stop.is_set():
            if self._now() - next_t > CATCH_UP_S:
                next_t = self._now()  # too far behind: skip to now (the frames between lost)
            try:
                if self.wanted:
                    self.capture(next_t)
            except Exception:  # keep going: a bad frame must not end the stream
                log.exception("simulated camera failed to render")
                self._status = CameraStatus.FAILED
                time.sleep(0.5)
                continue
            next_t += period
            delay = next_t - self._now()
            if delay > 0:
                self._sleep(delay)
