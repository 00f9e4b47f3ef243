"""One arm as the DecisionServer keeps it safe (docs/arms.md).

A server drives one arm or more. What belongs to each arm is here: its driver, its
model, its limits (workspace box, steps, speeds, force limit, contact rule), its force
sensor and what that sensor last said, and the lock that lets one command at a time
reach its driver. What is shared by every arm stays in the DecisionServer: the clients,
the one operator lease, the e-stop, the dead-man and the supervision of a policy. So a
force stop or a fault on one arm stops that arm alone, while the e-stop, the dead-man
and a lease lost stop them all.
"""

from __future__ import annotations

import asyncio
import copy
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Concatenate, ParamSpec, TypeVar

import numpy as np

from telerobot.drivers.base import FloatArray, ForceSensor, Robot
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.server.control.limits import SafetyLimits

P = ParamSpec("P")
R = TypeVar("R")


@dataclass(eq=False)
class ArmGuard:
    name: str  # left, right… ("arm" on a one-arm server)
    index: int  # on the wire: 1 for the first arm (0 there means "the only arm")
    robot: Robot
    kinematics: ArmKinematics  # the DecisionServer's own (Pinocchio data is per instance)
    limits: SafetyLimits
    force: ForceSensor | None = None
    # Where its base stands in the workcell (4×4); commands and its state are in its
    # own base frame, so this is only for what draws or records the arms together.
    mount: FloatArray = field(default_factory=lambda: np.eye(4))
    force_limited: bool = False
    force_base: FloatArray = field(default_factory=lambda: np.zeros(3))  # base frame
    contact_at: float | None = None  # when a contact force was last felt
    contact_sensor: tuple[float, float, float] = (0.0, 0.0, 0.0)  # and that force
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)  # one command at a time
    unsubscribe: Callable[[], None] | None = None
    # The full IK (absolute moves, a task's approach) runs on a thread of its own with a
    # copy of the model (Pinocchio data is per instance): the SO-101's numeric solver
    # takes milliseconds, which on the event loop every other client's command, the
    # e-stop and the forces would wait for (docs/architecture.md, "Threads").
    _solver: ArmKinematics | None = field(default=None, repr=False)
    _solver_thread: ThreadPoolExecutor | None = field(default=None, repr=False)

    @property
    def dof(self) -> int:
        return len(self.kinematics.qlim)

    async def off_loop(
        self, fn: Callable[Concatenate[ArmKinematics, P], R], *args: P.args, **kwargs: P.kwargs
    ) -> R:
        """``fn(model, *args)`` on this arm's solver thread, ``model`` its own copy of the
        arm's kinematics with the current tool (a calibration may have changed it)."""
        if self._solver is None or self._solver_thread is None:
            self._solver = copy.deepcopy(self.kinematics)
            self._solver_thread = ThreadPoolExecutor(1, thread_name_prefix=f"ik-{self.name}")
        solver = self._solver
        solver.tool = self.kinematics.tool

        def run() -> R:
            return fn(solver, *args, **kwargs)

        return await asyncio.get_running_loop().run_in_executor(self._solver_thread, run)

    def close(self) -> None:
        """The solver's thread ended (the server stops)."""
        if self._solver_thread is not None:
            self._solver_thread.shutdown(wait=False, cancel_futures=True)
            self._solver_thread = None

    def said(self, text: str, arms: int) -> str:
        """``text`` about this arm, named when the server drives more than one."""
        return text if arms == 1 else f"{self.name}: {text}"


def arm_sensors(
    arms: Sequence[ArmGuard], first: ForceSensor | None
) -> list[tuple[int, ForceSensor]]:
    """Every arm's force sensor with the arm's wire index, the first arm's being
    ``first`` (the one a transport was given: a test's may differ from the arm's own);
    arms with no sensor left out."""
    sensors = [(1, first), *((guard.index, guard.force) for guard in arms[1:])]
    return [(index, sensor) for index, sensor in sensors if sensor is not None]
