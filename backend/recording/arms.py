"""A recording's arms, read in one place for everything that reads a recording's
robot: the LeRobot export (lerobot.py) and the tasks (backend/tasks/trajectory.py),
and the recordings' list (recorder.py).

A recording names its arms in its ``/settings`` (its first message): a multi-arm
recording's ``arms`` (name → that arm's settings, its ``robot_model`` among them),
each arm's states and forces then on channels of its own, ``/arms/<name>/state`` and
``/arms/<name>/force``; a one-arm recording names none, and its one arm, "arm", is on
``/robot/state`` and ``/force`` (schemas.py, docs/recording.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from telerobot.server.recording.reader import read
from telerobot.server.recording.schemas import (
    ARM_FORCE,
    ARM_STATE,
    FORCE,
    ROBOT_STATE,
    SETTINGS,
    SINGLE_ARM,
    arm_of,
    arm_topic,
)


@dataclass(frozen=True)
class RecordedArm:
    """One arm of a recording."""

    name: str  # "arm": a one-arm recording's
    model: (
        str  # its robot model's name (its own ``robot_model``, else the server's); "" if not said
    )
    named: bool  # the recording's settings name its arms: its channels are its own
    state_topic: str  # /robot/state, or /arms/<name>/state
    force_topic: str  # /force, or /arms/<name>/force


def recorded_arms(settings: Mapping[str, Any]) -> list[RecordedArm]:
    """The arms a recording's ``/settings`` names, in order, each with its model and its
    channels; one arm, "arm" with the server's ``robot_model``, when they name none."""
    default = str(settings.get("robot_model") or "")
    arms = settings.get("arms")
    if not isinstance(arms, Mapping) or not arms:
        return [RecordedArm(SINGLE_ARM, default, False, ROBOT_STATE, FORCE)]
    out = []
    for key, own in arms.items():
        name = str(key)
        model = own.get("robot_model") if isinstance(own, Mapping) else None
        out.append(
            RecordedArm(
                name,
                str(model or default),
                True,
                arm_topic(name, ARM_STATE),
                arm_topic(name, ARM_FORCE),
            )
        )
    return out


def recorded_settings(path: Path) -> dict[str, Any]:
    """The recording's ``/settings`` (its first message), {} if it has none."""
    for _topic, _log_ns, m in read(path, [SETTINGS]):
        return m
    return {}


def arm_channel(topic: str) -> tuple[str, str] | None:
    """``(arm, kind)`` of any arm's channel, ``kind`` ``state`` or ``force``: a one-arm
    recording's ``/robot/state`` and ``/force`` are the arm "arm"'s; else None."""
    if topic == ROBOT_STATE:
        return SINGLE_ARM, ARM_STATE
    if topic == FORCE:
        return SINGLE_ARM, ARM_FORCE
    return arm_of(topic)
