"""One arm as the DecisionServer keeps it safe (docs/arms.md).

A server drives one arm or more. What belongs to each arm is here: its driver, its
model, its limits (workspace box, steps, speeds, force limit, contact rule), its force
sensor and what that sensor last said, and the lock that lets one command at a time
reach its driver; and the checks of one arm alone (its workspace, its force stop, a
move back into a contact). What is shared by every arm is not here: the clients
(clients.py), the one operator lease and the dead-man (lease.py), the supervision of a
policy (autonomy.py), the e-stop and the command pipeline (decision.py). So a force stop
or a fault on one arm stops that arm alone, while the e-stop, the dead-man and a lease
lost stop them all.
"""

from __future__ import annotations

import asyncio
import copy
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from enum import Enum
from typing import Concatenate, ParamSpec, TypeVar

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, ForceSensor, InvalidCommand, Robot, WorkingFrame
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.server.control.errors import LimitExceeded, SafetyStop
from telerobot.server.control.limits import SafetyLimits

P = ParamSpec("P")
R = TypeVar("R")


class Felt(Enum):
    """What a force sample changed of an arm's force stop."""

    LIMITED = "limited"  # above the limit: the arm is stopped from now
    RELEASED = "released"  # below the release level again: commands are taken again


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
    named: bool = False  # the server drives more than one arm: what is said names it
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

    def said(self, text: str) -> str:
        """``text`` about this arm, named when the server drives more than one."""
        return f"{self.name}: {text}" if self.named else text

    # ------------------------------------------------------------ its checks
    def check_not_force_limited(self) -> None:
        if self.force_limited:
            raise SafetyStop(self.said("force limit: back away with a Cartesian move first"))

    def check_workspace(self, p: FloatArray) -> None:
        lim = self.limits
        if not lim.in_workspace(p):
            lo, hi = lim.workspace_min, lim.workspace_max
            box = ", ".join(f"{a} {lo[i]:.2f}…{hi[i]:.2f}" for i, a in enumerate("xyz"))
            raise LimitExceeded(
                self.said(f"target {np.round(p, 3).tolist()} m is outside the workspace ({box} m)")
            )

    def joint_label(self, i: int) -> str:
        name = self.kinematics.joint_names[i]
        return f"joint {i + 1}" if name == f"joint{i + 1}" else f"joint {i + 1} ({name})"

    # ------------------------------------------------------------ its force
    def felt(self, fx: float, fy: float, fz: float, magnitude: float, now: float) -> Felt | None:
        """A force sample (sensor frame; ``magnitude`` of its force): a contact (above
        ``contact_force_n``) is remembered; above the force limit the arm is stopped
        (LIMITED the first time), and only moves that back away are taken until the
        force falls below the release level (RELEASED)."""
        lim = self.limits
        if magnitude > lim.contact_force_n:
            # Kept in the sensor frame: rotated only when a command asks (100 Hz, not 1 kHz).
            self.contact_sensor = (fx, fy, fz)
            self.contact_at = now
        if magnitude > lim.force_limit_n:
            self.force_base = self.robot.pose.rotation @ np.array([fx, fy, fz])
            if not self.force_limited:
                self.force_limited = True
                return Felt.LIMITED
        elif self.force_limited and magnitude < lim.force_limit_n * lim.force_release_ratio:
            self.force_limited = False
            return Felt.RELEASED
        return None

    def approaches_last_contact(
        self, T0: FloatArray, dX: FloatArray, rv: FloatArray, frame: WorkingFrame, now: float
    ) -> bool:
        """Whether the increment (``dX``, ``rv`` in ``frame`` from ``T0``) heads back into
        a surface the tool pressed on (above ``contact_force_n``) within the last
        ``contact_memory_s``: the contact force pushes the tool away from the surface,
        so moving against it approaches. With no recent contact nothing is computed."""
        if self.contact_at is None or now - self.contact_at >= self.limits.contact_memory_s:
            return False
        moved = self.kinematics.apply_increment(T0, dX, pin.exp3(rv), frame)[:3, 3] - T0[:3, 3]
        contact = self.robot.pose.rotation @ np.array(self.contact_sensor)
        return float(moved @ contact) < 0.0


class Arms(list[ArmGuard]):
    """A server's arms in order, numbered 1…N on the wire by their place and named in
    what is said when there is more than one; found by name or by wire index. A list,
    as every consumer takes it (``decision.arms``)."""

    def __init__(self, arms: Sequence[ArmGuard]) -> None:
        super().__init__(arms)
        if not self:
            raise ValueError("a DecisionServer needs at least one arm")
        for i, guard in enumerate(self):
            guard.index = i + 1
            guard.named = len(self) > 1
        self._by_name = {guard.name: guard for guard in self}
        if len(self._by_name) != len(self):
            raise ValueError("two arms have the same name")

    @property
    def names(self) -> list[str]:
        return [guard.name for guard in self]

    def named(self, name: str | None) -> ArmGuard:
        """The arm called ``name``; None: the only arm, refused on a server with more
        (a one-arm client must not drive whichever arm happens to be first)."""
        if name is None or name == "":
            if len(self) == 1:
                return self[0]
            raise InvalidCommand(
                f"this server drives {len(self)} arms ({', '.join(self.names)}):"
                " name the arm (REST: ?arm=NAME; the protocol: its index, from ARM)"
            )
        guard = self._by_name.get(name)
        if guard is None:
            raise InvalidCommand(
                f"no arm named {name[:40]!r}: this server drives {', '.join(self.names)}"
            )
        return guard

    def at(self, index: int) -> ArmGuard:
        """The arm by its index on the wire: 1…N, or 0 for the only one."""
        if index == 0:
            return self.named(None)
        if not 1 <= index <= len(self):
            raise InvalidCommand(
                f"no arm {index}: this server drives {len(self)}"
                f" ({', '.join(f'{g.index} {g.name}' for g in self)})"
            )
        return self[index - 1]


def arm_sensors(arms: Sequence[ArmGuard]) -> list[tuple[int, ForceSensor]]:
    """Every arm's force sensor with the arm's wire index; arms with no sensor left out."""
    return [(guard.index, guard.force) for guard in arms if guard.force is not None]
