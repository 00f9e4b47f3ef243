"""What every arm driver shares, whichever arm: the thesis's PUMA component (§4.3.1)
made general over robot models (``telerobot.drivers.robot.models``).

``ModelArm`` validates every command, turns Cartesian moves (in the base, wrist or
tool frame) into joint targets through the kinematic model, applies joint-angle
corrections, keeps the status and fires the events. A concrete driver only says
how joint targets reach the arm and how positions come back
(``_open``/``_close``/``_prepare``/``_send_target``/``_halt``/``_measured_raw``).

Relative moves accumulate on the last commanded target, not on the last measured
position, so a stream of small increments sent while the arm is still moving is
never lost nor applied twice.

``ArmConfig`` is what every arm driver reads from the settings (which model, its home
pose); a driver's own config extends it beside its class.
"""

from __future__ import annotations

import asyncio
import logging
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from telerobot.drivers.base import (
    ArmSnapshot,
    DeviceError,
    FloatArray,
    InvalidCommand,
    NotReady,
    Pose,
    RobotEvents,
    RobotFault,
    RobotMoved,
    RobotStatus,
    StatusChanged,
    TelerobotError,
    WorkingFrame,
)
from telerobot.drivers.clock import Clock, MonotonicClock
from telerobot.drivers.robot.kinematics import ArmKinematics, check_rotation, check_vector
from telerobot.drivers.robot.models import DEFAULT_MODEL, RobotModel, load_model

log = logging.getLogger(__name__)

_ACCEPTS_MOVES = (RobotStatus.READY, RobotStatus.MOVING)


@dataclass(frozen=True)
class ArmConfig:
    """What every arm driver reads from the settings: the model, and the named pose it
    initialises to (None: the model's own home pose)."""

    robot_model: str = DEFAULT_MODEL
    home_pose: str | None = None

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        home = settings.get("home_pose")
        return cls(
            robot_model=str(settings.get("robot_model", DEFAULT_MODEL)),
            home_pose=None if home is None else str(home),
        )

    @property
    def model(self) -> RobotModel:
        return load_model(self.robot_model)

    @property
    def home(self) -> FloatArray:
        model = self.model
        return model.pose(self.home_pose or model.home_pose)


class ModelArm(ABC):
    name = "arm"  # a driver says which it is

    def __init__(
        self,
        *,
        model: RobotModel | None = None,
        kinematics: ArmKinematics | None = None,
        clock: Clock | None = None,
        home: FloatArray | None = None,
        joint_offsets: FloatArray | None = None,
    ) -> None:
        self.model = model or load_model(DEFAULT_MODEL)
        self.dof = self.model.dof
        self.kinematics = kinematics or self.model.kinematics()
        self.clock: Clock = clock or MonotonicClock()
        self.events = RobotEvents()
        self.frame = WorkingFrame.BASE
        self.home = (
            self.model.pose(self.model.home_pose)
            if home is None
            else check_vector("home", home, self.dof)
        )
        self._offsets = (
            np.zeros(self.dof)
            if joint_offsets is None
            else check_vector("joint_offsets", joint_offsets, self.dof)
        )
        self._status = RobotStatus.NOT_CONNECTED
        self._status_message = "not connected"
        self._target: FloatArray | None = None  # model joints last commanded
        self._reported: ArmSnapshot | None = None  # where the arm last reported it was
        self._idle = asyncio.Event()
        self._idle.set()

    # ------------------------------------------------------------ driver hooks
    @abstractmethod
    async def _open(self) -> None:
        """Open the link to the arm (raise DeviceError with a reason on failure)."""

    @abstractmethod
    async def _close(self) -> None: ...

    @abstractmethod
    async def _prepare(self) -> None:
        """Make the arm ready to take joint targets (e.g. load the resident program)."""

    @abstractmethod
    async def _send_target(self, raw_target: FloatArray) -> None:
        """Start moving toward ``raw_target`` (controller angles); return once accepted."""

    @abstractmethod
    async def _halt(self) -> None:
        """Stop motion as soon as the arm can."""

    @abstractmethod
    def _measured_raw(self) -> FloatArray:
        """Latest joint angles the arm reported (controller angles)."""

    # ------------------------------------------------------------ state
    @property
    def status(self) -> RobotStatus:
        return self._status

    def status_is(self, status: RobotStatus) -> bool:
        # A method, not `self._status is …`, so type checkers do not carry a status
        # narrowed before an `await` past it.
        return self._status is status

    @property
    def status_message(self) -> str:
        return self._status_message

    @property
    def joints(self) -> FloatArray:
        """Corrected joint angles, radians."""
        return self._measured_raw() + self._offsets

    @property
    def pose(self) -> Pose:
        return Pose.from_matrix(self.kinematics.fk(self.joints))

    @property
    def target_joints(self) -> FloatArray:
        return self.joints if self._target is None else self._target.copy()

    def snapshot(self) -> ArmSnapshot:
        """Where the arm last reported it was ("moved" events), safe to read from any
        thread (one reference swapped); a driver that knows the joints' velocities
        overrides this (here they are zero)."""
        snap = self._reported
        if snap is None:  # nothing reported yet: where the arm is now
            snap = self._reported = ArmSnapshot(0.0, self.joints, np.zeros(self.dof))
        return snap

    def diagnostics(self) -> dict[str, Any]:
        return {}  # a driver with hardware to report on says more

    @property
    def joint_offsets(self) -> FloatArray:
        """Joint-angle corrections: model angle = controller angle + offset."""
        return self._offsets.copy()

    @joint_offsets.setter
    def joint_offsets(self, offsets: FloatArray) -> None:
        if self._status is RobotStatus.MOVING:
            raise NotReady("joint corrections cannot change while the arm moves")
        self._offsets = check_vector("joint_offsets", offsets, self.dof)
        self._target = None
        self._reported = None  # the same arm, other model angles

    def _set_status(self, status: RobotStatus, message: str = "") -> None:
        if status is self._status and message == self._status_message:
            return
        old, self._status, self._status_message = self._status, status, message
        if status in (RobotStatus.MOVING, RobotStatus.WAITING):
            self._idle.clear()
        else:
            self._idle.set()
        self.events.status_changed.emit(StatusChanged(old, status, message))

    def _fail(self, error: TelerobotError) -> None:
        """Enter ERROR with a message a person can act on."""
        log.error("%s: %s", self.name, error)
        self._target = None
        self._set_status(RobotStatus.ERROR, str(error))
        self.events.error.emit(RobotFault(error.code, str(error)))

    def _report_moved(self) -> None:
        q = self.joints
        now = self.clock.now()
        self._reported = ArmSnapshot(now, q, np.zeros(self.dof))
        self.events.moved.emit(RobotMoved(q, Pose.from_matrix(self.kinematics.fk(q)), now))

    def _motion_finished(self) -> None:
        self._report_moved()
        if self._status is RobotStatus.MOVING:
            self._set_status(RobotStatus.READY, "ready")

    # ------------------------------------------------------------ lifecycle
    async def connect(self) -> None:
        if self._status not in (RobotStatus.NOT_CONNECTED, RobotStatus.ERROR):
            return
        try:
            await self._close()
            await self._open()
        except TelerobotError as exc:
            await self._close()  # leave no half-open port or reader behind
            self._fail(exc)
            raise
        self._set_status(RobotStatus.CONNECTED, "connected, not initialised")

    async def disconnect(self) -> None:
        await self._close()
        self._target = None
        self._set_status(RobotStatus.NOT_CONNECTED, "not connected")

    async def initialize(self, joints: FloatArray | None = None) -> None:
        """Prepare the arm and move it to ``joints`` (default: the home pose)."""
        if self._status in (RobotStatus.NOT_CONNECTED, RobotStatus.ERROR):
            raise NotReady(f"robot is {self._status}: connect it before initialising")
        if self._status is RobotStatus.MOVING:
            raise NotReady("robot is moving: stop it before initialising")
        target = self.home if joints is None else check_vector("joints", joints, self.dof)
        self.kinematics.check_joint_limits(target)
        self._set_status(RobotStatus.WAITING, "initialising")
        try:
            await self._prepare()
            self._target = target.copy()
            await self._send_target(target - self._offsets)
            self._set_status(RobotStatus.MOVING, "moving to the initial pose")
        except TelerobotError as exc:
            self._fail(exc)
            raise
        await self.wait_idle()
        if self.status_is(RobotStatus.ERROR):
            raise DeviceError(f"initialisation failed: {self._status_message}")

    # ------------------------------------------------------------ moves
    def _require_ready(self) -> None:
        if self._status not in _ACCEPTS_MOVES:
            hint = {
                RobotStatus.NOT_CONNECTED: "connect and initialise it first",
                RobotStatus.CONNECTED: "initialise it first",
                RobotStatus.WAITING: "wait for initialisation to finish",
                RobotStatus.ERROR: f"reconnect and initialise it ({self._status_message})",
            }.get(self._status, "")
            raise NotReady(f"robot is {self._status}: {hint}")

    async def move_joints(self, q: FloatArray, *, relative: bool) -> FloatArray:
        """Move to joint angles ``q`` (or by ``q`` when relative); returns the target."""
        self._require_ready()
        q = check_vector("joint increment" if relative else "joints", q, self.dof)
        target = self.target_joints + q if relative else q
        return await self._go(target)

    async def move_cartesian(
        self,
        position: FloatArray,
        rotation: FloatArray,
        *,
        relative: bool,
        frame: WorkingFrame | None = None,
    ) -> FloatArray:
        """Move the tool to (position, rotation) in the base frame, or by
        (ΔX, ΔM) expressed in ``frame`` (default: the working frame) when relative."""
        self._require_ready()
        p = check_vector("position increment" if relative else "position", position, 3)
        R = check_rotation("orientation increment" if relative else "orientation", rotation)
        seed = self.target_joints
        if relative:
            T = self.kinematics.apply_increment(
                self.kinematics.fk(seed).copy(), p, R, frame or self.frame
            )
        else:
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, p
        target = self.kinematics.ik(T, seed)
        return await self._go(target)

    async def _go(self, target: FloatArray) -> FloatArray:
        self.kinematics.check_joint_limits(target)
        try:
            await self._send_target(target - self._offsets)
        except TelerobotError as exc:
            if not isinstance(exc, InvalidCommand):
                self._fail(exc)
            raise
        self._target = target.copy()
        self._set_status(RobotStatus.MOVING, "moving")
        return target.copy()

    async def stop(self) -> None:
        """Stop motion now; the target becomes where the arm comes to rest."""
        if self._status is not RobotStatus.MOVING:
            return
        await self._halt()
        self._target = None

    async def wait_idle(self, timeout: float | None = None) -> None:
        """Wait until the arm is not moving or initialising (``timeout`` in clock seconds)."""
        if self._idle.is_set():
            return
        waiter = asyncio.ensure_future(self._idle.wait())
        if timeout is None:
            await waiter
            return
        sleeper = asyncio.ensure_future(self.clock.sleep(timeout))
        done, _ = await asyncio.wait({waiter, sleeper}, return_when=asyncio.FIRST_COMPLETED)
        waiter.cancel()
        sleeper.cancel()
        if waiter not in done:
            raise TimeoutError(f"robot still {self._status} after {timeout:g} s")
