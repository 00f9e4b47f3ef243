"""``SimArm``: a simulated arm of any model that moves as the real one does (the
PUMA 560 by default; ``SimPuma`` is that case).

Joints follow ``JointMotion`` (velocity and acceleration limits; a move takes the
time it takes) on the injected clock. The arm reports where it is ("moved") every
``report_period`` seconds while it moves and once when it stops, as a controller
streaming its position would.

``stop()`` is a controlled stop at the drives' limit (``stop_decel``): every joint
decelerates together, the slowest at its limit, so the tool stops on its path; the
arm is then held where it stopped (IEC 60204-1 stop category 2).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Mapping
from typing import Any, Self

import numpy as np

from telerobot.drivers.base import (
    ArmSnapshot,
    DeviceContext,
    FloatArray,
    RobotStatus,
    StopCategory,
    StopSpec,
)
from telerobot.drivers.clock import Clock
from telerobot.drivers.robot.arm import ArmConfig, ModelArm
from telerobot.drivers.robot.kinematics import ArmKinematics, check_vector
from telerobot.drivers.robot.models import RobotModel, load_model
from telerobot.drivers.robot.motion import JointMotion


class SimArm(ModelArm):
    """Joint limits of speed, acceleration and stopping default to the model's."""

    def __init__(
        self,
        *,
        model: RobotModel | None = None,
        kinematics: ArmKinematics | None = None,
        clock: Clock | None = None,
        home: FloatArray | None = None,
        joint_offsets: FloatArray | None = None,
        start_joints: FloatArray | None = None,
        vmax: FloatArray | None = None,
        amax: FloatArray | None = None,
        stop_decel: FloatArray | None = None,
        report_period: float = 0.02,
    ) -> None:
        super().__init__(
            model=model, kinematics=kinematics, clock=clock, home=home, joint_offsets=joint_offsets
        )
        m = self.model
        start = (
            m.pose(m.start_pose)
            if start_joints is None
            else check_vector("start_joints", start_joints, self.dof)
        )
        self._motion = JointMotion(
            start,
            m.vmax if vmax is None else vmax,
            m.amax if amax is None else amax,
            stop_decel=m.stop_decel if stop_decel is None else stop_decel,
        )
        self._updated_at = self.clock.now()
        self._snapshot = ArmSnapshot(
            self._updated_at, self._motion.q + self._offsets, self._motion.v
        )
        self.report_period = report_period
        self._reporter: asyncio.Task[None] | None = None
        self._wake = asyncio.Event()

    @property
    def name(self) -> str:  # type: ignore[override]  # one class, any model
        return f"sim-{self.model.name}"

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        config = ArmConfig.from_settings(settings)
        return cls(
            model=config.model,
            kinematics=context.kinematics(),
            clock=context.clock,
            home=config.home,
            start_joints=config.home if settings.get("sim_starts_at_home") else None,
        )

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        model = ArmConfig.from_settings(settings).model
        return "the simulation" if model.name == "puma560" else f"the simulated {model.title}"

    def _sync(self) -> None:
        now = self.clock.now()
        self._motion.advance(now - self._updated_at)
        self._updated_at = now
        self._snapshot = ArmSnapshot(now, self._motion.q + self._offsets, self._motion.v)

    @property
    def stop_spec(self) -> StopSpec:
        return StopSpec(
            category=StopCategory.CONTROLLED_HOLDING,
            decel=self._motion.stop_decel.copy(),
            vmax=np.array(self._motion.vmax),
            reaction_s=0.0,
            summary=(
                "the simulated drives brake every joint together, the slowest at its limit, "
                "and hold the arm where it stopped"
            ),
        )

    def snapshot(self) -> ArmSnapshot:
        """The state at the last update (thread-safe; extrapolate with ``velocities``)."""
        return self._snapshot

    def _measured_raw(self) -> FloatArray:
        self._sync()
        return self._motion.q

    @property
    def joint_velocities(self) -> FloatArray:
        self._sync()
        return self._motion.v

    async def _open(self) -> None:
        self._sync()
        self._reporter = asyncio.create_task(self._report_loop(), name="sim-arm-reporter")

    async def _close(self) -> None:
        if self._reporter is not None:
            self._reporter.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reporter
            self._reporter = None

    async def _prepare(self) -> None:
        self._sync()

    async def _send_target(self, raw_target: FloatArray) -> None:
        self._sync()
        self._motion.set_target(np.asarray(raw_target, dtype=float))
        self._wake.set()

    async def _halt(self) -> None:
        self._sync()
        self._motion.brake()
        self._wake.set()

    async def _report_loop(self) -> None:
        while True:
            # Wait only when at rest *and* reported at rest: the motion may end inside
            # _report_moved (reading the joints syncs the motion), and the status
            # must still go back to READY then.
            if not self._motion.moving and self._status is not RobotStatus.MOVING:
                await self._wake.wait()
            self._wake.clear()
            await self.clock.sleep(self.report_period)
            self._sync()
            if self._motion.moving:
                self._report_moved()
            elif self._status is RobotStatus.MOVING:
                self._motion_finished()


class SimPuma(SimArm):
    """The simulated PUMA 560 (the default model, named for the tests and benches)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(model=load_model("puma560"), **kwargs)
