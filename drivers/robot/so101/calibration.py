"""The SO-101's joint calibration: for each joint of the model, which servo turns it,
the servo's Present_Position at the joint's zero (``zero_steps``) and whether the
steps grow with the joint angle (``direction`` +1) or against it (−1). A joint angle
q (radians, the model's) is then ``zero_steps + direction · q · 4096 / 2π`` steps.

Recording: with torque off, a person moves the arm to named poses of the model (its
own ``zero``, ``ready``, ``rest``, plus ``quarter`` here: every joint a quarter turn
from its zero, square angles a person sets by eye) and ``CalibrationRecorder``
records the raw positions at each (``record_pose``); ``solve()`` fits each joint's
zero and direction from the poses in which it had different angles, checks that the
servo turned by about as much as the model says (a wrong pose or a slipped horn is
refused with the joint's name), and that the joint's whole range stays inside the
servo's 0..4095 (a range that crosses the wrap would make the servo turn the long
way round). ``zero`` + ``quarter`` differ in every joint; ``zero``/``ready``/``rest``
alone do not move shoulder_pan or wrist_roll, and ``solve`` says so.

Stored like the cameras' calibration (``telerobot.calibration.store``): one JSON file with a
format name and a version, written atomically (a crash leaves the previous file), and
a clear error for a file that is corrupt, of another format or another version.

LeRobot's calibration file (``<calibration dir>/robots/so_follower/<id>.json``:
motor → ``id``, ``drive_mode``, ``homing_offset``, ``range_min``, ``range_max``)
maps onto this: LeRobot writes ``homing_offset`` into each servo (Present_Position =
actual − offset) so that the middle of the joint's range reads ~2047, and in its
"degrees" mode a joint's angle is (steps − (range_min + range_max)/2) · 360/4095,
the same zero as the model's "new calib" URDF (zero = middle of the range). So
``zero_steps`` = (range_min + range_max)/2, ``direction`` = −1 if ``drive_mode`` else
+1, and ``homing_offset`` is kept to check, at connect, that the servos still hold
it. The gripper (LeRobot: 0–100 % of its range) takes its zero from ``range_min``
being the model's lower limit. ``from_lerobot(path)`` imports such a file. (LeRobot's
scale, 360°/4095 steps, differs from 4096 steps a turn by 0.02 %.)
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from telerobot.drivers.base import DeviceError, FloatArray, InvalidCommand
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.robot.models import RobotModel

FORMAT = "telerobot-so101-calibration"
VERSION = 1
STEPS_PER_RADIAN = ft.STEPS_PER_TURN / (2 * math.pi)
SERVO_IDS = (1, 2, 3, 4, 5, 6)  # shoulder_pan … gripper, LeRobot's numbering
# Poses for calibration besides the model's own: every joint a quarter turn from zero.
CALIBRATION_POSES: Mapping[str, FloatArray] = {"quarter": np.full(6, math.pi / 2)}
MIN_SPREAD_RAD = 0.3  # a joint needs poses at least this far apart to fit
SCALE_TOLERANCE = 0.25  # the servo turned within ±25 % of what the model says
FIT_TOLERANCE_RAD = math.radians(15)  # each pose within 15° of the fitted line


@dataclass(frozen=True)
class JointCalibration:
    id: int  # the servo's bus id
    zero_steps: float  # Present_Position at the joint's zero
    direction: int  # +1: steps grow with the joint angle; −1: against it
    homing_offset: int | None = None  # the servo's Homing_Offset when recorded

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "zero_steps": self.zero_steps,
            "direction": self.direction,
            "homing_offset": self.homing_offset,
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> JointCalibration:
        direction = int(doc["direction"])
        if direction not in (1, -1):
            raise ValueError(f"direction {direction} is not +1 or -1")
        servo = int(doc["id"])
        if not 0 <= servo <= ft.MAX_ID:
            raise ValueError(f"servo id {servo} is not a bus id (0…{ft.MAX_ID})")
        zero = float(doc["zero_steps"])
        if not (math.isfinite(zero) and 0 <= zero < ft.STEPS_PER_TURN):
            raise ValueError(f"zero_steps {zero} is not a position (0…{ft.STEPS_PER_TURN - 1})")
        offset = doc.get("homing_offset")
        return cls(
            id=servo,
            zero_steps=zero,
            direction=direction,
            homing_offset=None if offset is None else int(offset),
        )


@dataclass(frozen=True)
class So101Calibration:
    joint_names: tuple[str, ...]
    joints: tuple[JointCalibration, ...]  # in the model's joint order
    created: float = 0.0

    @classmethod
    def nominal(
        cls, joint_names: Sequence[str], ids: Sequence[int] = SERVO_IDS
    ) -> So101Calibration:
        """Zero at mid-scale (2048), steps growing with the angle: LeRobot's convention
        after its homing. Only to show an uncalibrated arm; never to move one."""
        return cls(tuple(joint_names), tuple(JointCalibration(i, 2048.0, 1) for i in ids))

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(j.id for j in self.joints)

    def name_of(self, servo_id: int) -> str:
        for name, joint in zip(self.joint_names, self.joints, strict=True):
            if joint.id == servo_id:
                return name
        return f"servo {servo_id}"

    def label(self, servo_id: int) -> str:
        """ "servo 3 (elbow_flex)", for messages."""
        return f"servo {servo_id} ({self.name_of(servo_id)})"

    def to_radians(self, steps: Sequence[float] | FloatArray) -> FloatArray:
        """Model joint angles from Present_Position values (wrapping at a turn)."""
        raw = np.asarray(steps, dtype=float)
        zero = np.array([j.zero_steps for j in self.joints])
        sign = np.array([j.direction for j in self.joints], dtype=float)
        delta = np.mod(raw - zero + ft.STEPS_PER_TURN / 2, ft.STEPS_PER_TURN) - (
            ft.STEPS_PER_TURN / 2
        )
        result: FloatArray = sign * delta / STEPS_PER_RADIAN
        return result

    def to_steps(self, q: Sequence[float] | FloatArray) -> list[int]:
        """Goal_Position values for model joint angles ``q`` (clamped to 0..4095)."""
        out = []
        for joint, angle in zip(self.joints, np.asarray(q, dtype=float), strict=True):
            steps = joint.zero_steps + joint.direction * angle * STEPS_PER_RADIAN
            out.append(int(min(ft.STEPS_PER_TURN - 1, max(0, round(steps)))))
        return out

    def speeds_to_steps(self, v: FloatArray) -> list[int]:
        return [round(abs(float(x)) * STEPS_PER_RADIAN) for x in v]

    # ---------------------------------------------------------- file
    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "created": self.created,
            "joints": {
                name: joint.to_json()
                for name, joint in zip(self.joint_names, self.joints, strict=True)
            },
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], joint_names: Sequence[str]) -> So101Calibration:
        if doc.get("format") != FORMAT or doc.get("version") != VERSION:
            raise ValueError(
                f"not a version-{VERSION} {FORMAT} file "
                f"(format {doc.get('format')!r}, version {doc.get('version')!r})"
            )
        joints = doc["joints"]
        missing = [n for n in joint_names if n not in joints]
        if missing:
            raise ValueError(f"no calibration for {', '.join(missing)}")
        calibrated = tuple(JointCalibration.from_json(joints[n]) for n in joint_names)
        ids = [j.id for j in calibrated]
        if len(set(ids)) != len(ids):
            raise ValueError(f"two joints name the same servo (ids {ids})")
        return cls(tuple(joint_names), calibrated, float(doc.get("created", 0.0)))

    def save(self, path: Path) -> None:
        """Write atomically: a crash mid-write leaves the previous file."""
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".so101-calibration-", suffix=".json")
        try:
            with os.fdopen(fd, "w") as f:
                json.dump(self.to_json(), f, indent=1)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path: Path, joint_names: Sequence[str]) -> So101Calibration | None:
        """The calibration in ``path`` (None if there is no file: not calibrated yet)."""
        if not path.exists():
            return None
        try:
            return cls.from_json(json.loads(path.read_text()), joint_names)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            what = f"{type(exc).__name__}: {exc}" if isinstance(exc, KeyError) else str(exc)
            raise DeviceError(
                f"the SO-101 calibration {path} cannot be used ({what}): "
                "record it again, or remove the file"
            ) from None


# ---------------------------------------------------------------- recording
class CalibrationRecorder:
    """Raw positions at named poses → zero and direction per joint (see the module)."""

    def __init__(self, model: RobotModel, ids: Sequence[int] = SERVO_IDS) -> None:
        if len(ids) != model.dof:
            raise InvalidCommand(f"{len(ids)} servo ids for the {model.dof} joints")
        self.model = model
        self.ids = tuple(ids)
        self.recorded: dict[str, tuple[FloatArray, list[int]]] = {}
        self.homing_offsets: list[int] | None = None

    @property
    def poses(self) -> dict[str, FloatArray]:
        return {**dict(self.model.named_poses), **dict(CALIBRATION_POSES)}

    def record_pose(
        self,
        name: str,
        raw_positions: Sequence[int],
        homing_offsets: Sequence[int] | None = None,
    ) -> None:
        """The arm is at pose ``name``; ``raw_positions`` are the servos' Present_Position
        (joint order) and ``homing_offsets`` their Homing_Offset, if read."""
        poses = self.poses
        if name not in poses:
            raise InvalidCommand(f"no pose {name!r} to calibrate at (known: {', '.join(poses)})")
        if len(raw_positions) != self.model.dof:
            raise InvalidCommand(f"{len(raw_positions)} positions for {self.model.dof} joints")
        self.recorded[name] = (poses[name], [int(r) for r in raw_positions])
        if homing_offsets is not None:
            self.homing_offsets = [int(h) for h in homing_offsets]

    def solve(self) -> So101Calibration:
        problems: list[str] = []
        joints: list[JointCalibration] = []
        if len(self.recorded) < 2:
            raise InvalidCommand(
                "record the arm at two poses at least (e.g. 'zero' and 'quarter'); "
                f"recorded: {', '.join(self.recorded) or 'none'}"
            )
        for j, name in enumerate(self.model.joint_names):
            try:
                joints.append(self._solve_joint(j))
            except ValueError as exc:
                problems.append(f"{name} (servo {self.ids[j]}): {exc}")
        if problems:
            raise InvalidCommand("cannot calibrate " + "; ".join(problems))
        return So101Calibration(tuple(self.model.joint_names), tuple(joints), time.time())

    def _solve_joint(self, j: int) -> JointCalibration:
        q = np.array([pose[j] for pose, _ in self.recorded.values()])
        raw = np.array([steps[j] for _, steps in self.recorded.values()], dtype=float)
        if np.ptp(q) < MIN_SPREAD_RAD:
            raise ValueError(
                f"it has the same angle in every pose recorded ({', '.join(self.recorded)}); "
                "record 'quarter' too"
            )
        half = ft.STEPS_PER_TURN / 2
        raw = raw[0] + np.mod(raw - raw[0] + half, ft.STEPS_PER_TURN) - half  # unwrapped
        slope = float(np.polyfit(q, raw, 1)[0]) / STEPS_PER_RADIAN
        if abs(abs(slope) - 1.0) > SCALE_TOLERANCE:
            raise ValueError(
                f"the servo turned {abs(slope) * 100:.0f} % of the angle between the poses, "
                "not 100 %: was the arm at each pose when it was recorded?"
            )
        direction = 1 if slope > 0 else -1
        zero = float(np.mean(raw - direction * q * STEPS_PER_RADIAN))
        worst = float(np.max(np.abs(raw - (zero + direction * q * STEPS_PER_RADIAN))))
        if worst / STEPS_PER_RADIAN > FIT_TOLERANCE_RAD:
            raise ValueError(
                f"one pose is {math.degrees(worst / STEPS_PER_RADIAN):.0f}° off the others: "
                "record the poses again"
            )
        zero = float(np.mod(zero, ft.STEPS_PER_TURN))
        lo, hi = self.model.qlim[j]
        ends = sorted(zero + direction * np.array([lo, hi]) * STEPS_PER_RADIAN)
        if ends[0] < 0 or ends[1] > ft.STEPS_PER_TURN - 1:
            raise ValueError(
                f"its range would span steps {ends[0]:.0f}..{ends[1]:.0f}, across the servo's "
                "0/4095 wrap: set the servo's Homing_Offset so the joint's middle reads 2048 "
                "(LeRobot's calibration does), then record again"
            )
        offset = None if self.homing_offsets is None else self.homing_offsets[j]
        return JointCalibration(self.ids[j], round(zero, 2), direction, offset)


# ---------------------------------------------------------------- LeRobot
def from_lerobot(path: Path, model: RobotModel) -> So101Calibration:
    """Import LeRobot's calibration JSON of an SO-101 follower (see the module)."""
    try:
        doc = json.loads(path.read_text())
        joints = []
        for j, name in enumerate(model.joint_names):
            motor = doc[name]
            direction = -1 if int(motor["drive_mode"]) else 1
            lo_steps, hi_steps = int(motor["range_min"]), int(motor["range_max"])
            if name == "gripper":
                lower = float(model.qlim[j][0])
                start = lo_steps if direction > 0 else hi_steps
                zero = start - direction * lower * STEPS_PER_RADIAN
            else:
                zero = (lo_steps + hi_steps) / 2
            joints.append(
                JointCalibration(int(motor["id"]), zero, direction, int(motor["homing_offset"]))
            )
    except (OSError, ValueError, KeyError, TypeError) as exc:
        what = f"no {exc}" if isinstance(exc, KeyError) else str(exc)
        raise DeviceError(f"cannot import the LeRobot calibration {path}: {what}") from None
    return So101Calibration(tuple(model.joint_names), tuple(joints), time.time())
