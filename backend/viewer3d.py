"""A 3D view of the workcell (viser), served on its own port and linked from the
operator page: every arm as it is (live, each at its mount), its predicted gripper
(where the commanded target puts it), the cameras as frusta from the calibration (or the
simulated ground truth), the fiducials, the table and block, and each arm's contact
force as an arrow.

viser runs its own server thread; the event loop refreshes the scene at 20 Hz by
setting the properties of what moves (the arm, the target, the force).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from telerobot.calibration.model import CameraModel
from telerobot.calibration.store import CalibrationStore
from telerobot.drivers.base import FloatArray, ForceSensor, Robot
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.drivers.sim.workcell import Workcell

log = logging.getLogger(__name__)

FORCE_M_PER_N = 0.005  # arrow length: 60 N → 0.3 m
REFRESH_S = 0.05


@dataclass(frozen=True)
class ViewedArm:
    """An arm the view draws: its driver, its own kinematics (read on the event loop),
    where its base stands in the workcell (4×4) and its force sensor."""

    robot: Robot
    kinematics: ArmKinematics
    mount: FloatArray = field(default_factory=lambda: np.eye(4))
    force: ForceSensor | None = None


@dataclass
class ArmNodes:
    """One arm's scene nodes, made once; each refresh sets their properties."""

    arm: ViewedArm
    links: Any
    gripper: Any
    predicted: Any
    force: Any


def camera_pose(
    K: FloatArray, R: FloatArray, t: FloatArray, height: int
) -> tuple[FloatArray, FloatArray, float]:
    """Camera-to-world rotation, position, and vertical field of view (rad)."""
    return R.T, -R.T @ t, 2 * math.atan(height / (2 * K[1, 1]))


def decompose(P: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """K, R, t of a perspective 3×4 projection (RQ decomposition); None for an affine one."""
    M = P[:, :3]
    if abs(np.linalg.det(M)) < 1e-12 or np.allclose(P[2, :3], 0):
        return None
    # RQ via QR of the reversed, transposed matrix.
    flip = np.eye(3)[::-1]
    q, r = np.linalg.qr((flip @ M).T)
    K = flip @ r.T @ flip
    R = flip @ q.T
    signs = np.diag(np.sign(np.diag(K)))
    K, R = K @ signs, signs @ R
    t = np.linalg.solve(K, P[:, 3])
    if np.linalg.det(R) < 0:
        R, t = -R, -t
    return K / K[2, 2], R, t


def _name(node: str, arm: int) -> str:
    """The scene node of the ``arm``-th arm: the first's as it always was, "/arm_2" …"""
    return node if arm == 0 else f"{node}_{arm + 1}"


class Workcell3DView:
    def __init__(
        self,
        host: str,
        port: int,
        workcell: Workcell,
        arms: Sequence[ViewedArm],
        calibration: CalibrationStore,
    ) -> None:
        """``arms`` in the server's order, each at its own mount."""
        import viser  # an optional part of the server: imported when the view is on

        self.workcell = workcell
        self.calibration = calibration
        self.arms = tuple(arms)
        self.server: Any = viser.ViserServer(host=host, port=port, label="Telerobot", verbose=False)
        self.port: int = self.server.get_port()
        self._task: asyncio.Task[None] | None = None
        self._calibration_seen: dict[str, float] | None = None
        self.refreshes = 0
        self.camera_updates = 0
        self._static()
        self._live()

    # ------------------------------------------------------------ the scene
    def _static(self) -> None:
        scene = self.server.scene
        scene.add_grid("/floor", width=3.0, height=3.0, cell_size=0.1, section_size=0.5)
        for box in (self.workcell.table, self.workcell.block):
            scene.add_box(
                f"/workcell/{box.name}",
                color=box.colour,
                dimensions=tuple(box.size),
                position=tuple(box.centre),
            )
        f = self.workcell.fiducials
        scene.add_point_cloud(
            "/workcell/fiducials", f, np.tile([[255, 220, 0]], (len(f), 1)), point_size=0.02
        )
        for i, p in enumerate(f):
            scene.add_label(f"/workcell/fiducials/{i + 1}", str(i + 1), position=tuple(p))
        import viser.transforms as tf

        for i, arm in enumerate(self.arms):
            scene.add_frame(
                _name("/base", i),
                axes_length=0.2,
                axes_radius=0.008,
                wxyz=tf.SO3.from_matrix(arm.mount[:3, :3]).wxyz,
                position=tuple(arm.mount[:3, 3]),
            )

    def _cameras(self) -> None:
        """Frusta from the calibration (perspective models) or the simulated ground truth."""
        import viser.transforms as tf

        self.camera_updates += 1
        for truth in (self.workcell.rig.left, self.workcell.rig.right):
            model: CameraModel | None = self.calibration.cameras.get(truth.name)
            parts = (truth.K, truth.R, truth.t) if model is None else decompose(model.P)
            name = f"/cameras/{truth.name}"
            if parts is None:  # an affine model has no centre: no frustum to draw
                self.server.scene.add_label(name, f"{truth.name}: affine model (no frustum)")
                continue
            R_cw, position, fov = camera_pose(*parts, truth.height)
            self.server.scene.add_camera_frustum(
                name,
                fov=fov,
                aspect=truth.width / truth.height,
                scale=0.15,
                color=(40, 160, 255) if model is not None else (120, 120, 120),
                wxyz=tf.SO3.from_matrix(R_cw).wxyz,
                position=tuple(position),
            )

    def _live(self) -> None:
        """The nodes that move, made once; each refresh only sets their properties
        (a tenth of the cost of adding them again)."""
        scene = self.server.scene
        self.nodes = [
            ArmNodes(
                arm,
                scene.add_line_segments(
                    _name("/arm", i), np.zeros((7, 2, 3)), (110, 110, 120), thickness=0.04
                ),
                scene.add_icosphere(_name("/gripper", i), radius=0.02, color=(255, 140, 0)),
                scene.add_icosphere(
                    _name("/predicted", i), radius=0.025, color=(0, 255, 102), opacity=0.6
                ),
                scene.add_line_segments(
                    _name("/force", i), np.zeros((1, 2, 3)), (255, 40, 40), thickness=0.012
                ),
            )
            for i, arm in enumerate(self.arms)
        ]

    def refresh(self) -> None:
        """Each arm, its predicted gripper, its force; the cameras when the calibration
        changed."""
        seen = {name: m.created for name, m in self.calibration.cameras.items()}
        if seen != self._calibration_seen:
            self._calibration_seen = seen
            self._cameras()
        for nodes in self.nodes:
            self._refresh_arm(nodes)
        self.refreshes += 1

    @staticmethod
    def _refresh_arm(nodes: ArmNodes) -> None:
        arm = nodes.arm
        R, t = arm.mount[:3, :3], arm.mount[:3, 3]  # the arm's base frame → the workcell's
        pts = arm.kinematics.link_origins(arm.robot.joints) @ R.T + t
        nodes.links.points = np.stack([pts[:-1], pts[1:]], axis=1)
        tool = pts[-1]
        nodes.gripper.position = tuple(tool)
        predicted = R @ arm.kinematics.fk(arm.robot.target_joints)[:3, 3] + t
        nodes.predicted.position = tuple(predicted)
        sample = arm.force.latest if arm.force is not None else None
        if sample is not None:
            f_cell = R @ arm.robot.pose.rotation @ np.array(sample.values[:3])
            nodes.force.points = np.array([[tool, tool + f_cell * FORCE_M_PER_N]])

    # ------------------------------------------------------------ running
    # On the event loop, where the robot's state may be read (the arm's kinematics and
    # motion state are not thread-safe). A refresh sets a few properties: ~0.9 ms
    # median (re-adding the nodes was ~3.4 ms), ~2 % of the loop at 20 Hz.
    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="viewer3d")

    async def _run(self) -> None:
        while True:
            try:
                self.refresh()
            except Exception:  # a view must never take the server down
                log.exception("3D view refresh failed")
            await asyncio.sleep(REFRESH_S)

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        await asyncio.to_thread(self.server.stop)
