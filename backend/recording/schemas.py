"""Every recording channel in one place: its topic, schema name and JSON Schema
(docs/recording.md is the contract; keep the two in step).

All channels are JSON (``message_encoding: json``). The video and the transforms use
Foxglove's well-known schemas in their JSON form (bytes as base64, as Foxglove's
JSON schemas say), so Foxglove and Lichtblick show them in their Image and 3D panels.

**Two arms or more** (docs/arms.md): each arm's state and forces are channels of its own,
``/arms/<name>/state`` and ``/arms/<name>/force`` (the schemas of ``/robot/state`` and
``/force``, with ``arm``), in place of ``/robot/state`` and ``/force``; ``/arms`` says
once, at the start, which arms there are (names, models, where each base stands). A
one-arm recording has none of these: its channels are as they always were.
"""

from __future__ import annotations

from typing import Any

ROBOT_STATE = "/robot/state"
FORCE = "/force"
COMMANDS = "/commands"
SAFETY = "/safety"
AUTONOMY = "/autonomy"
EPISODES = "/episodes"
VIDEO = "/video/stereo"
TF = "/tf"
CALIBRATION = "/calibration"
SETTINGS = "/settings"
TASKS = "/tasks"
ARMS = "/arms"  # a multi-arm recording's arms (once, at its start)
ARM_PREFIX = "/arms/"  # …and each arm's channels: /arms/<name>/state, /arms/<name>/force
ARM_STATE = "state"
ARM_FORCE = "force"
SINGLE_ARM = "arm"  # the one arm's name (the settings' SINGLE_ARM)

_num = {"type": "number"}
_vec = {"type": "array", "items": _num}
_str = {"type": "string"}
_bool = {"type": "boolean"}


def _obj(**props: Any) -> dict[str, Any]:
    return {"type": "object", "properties": props}


_time = _obj(sec={"type": "integer", "minimum": 0}, nsec={"type": "integer", "minimum": 0})
_xyz = _obj(x=_num, y=_num, z=_num)
_quat = _obj(x=_num, y=_num, z=_num, w=_num)

# topic → (schema name, JSON Schema)
CHANNELS: dict[str, tuple[str, dict[str, Any]]] = {
    ROBOT_STATE: (
        "telerobot.RobotState",
        _obj(t=_num, status=_str, joints=_vec, target_joints=_vec, position=_vec, rotation=_vec),
    ),
    FORCE: (
        "telerobot.Force",
        _obj(t=_num, seq={"type": "integer"}, sensor_time=_num, values=_vec),
    ),
    COMMANDS: (
        "telerobot.Command",
        _obj(
            t=_num,
            source=_str,
            client_id=_str,
            client=_str,
            kind=_str,
            args={"type": "object"},
            accepted=_bool,
            reason=_str,
            code=_str,
            target_joints={"type": ["array", "null"], "items": _num},
            lease_holder={"type": ["string", "null"]},
            role=_str,
            autonomy=_str,
            age_ms={"type": ["number", "null"]},
        ),
    ),
    AUTONOMY: (
        "telerobot.Autonomy",
        _obj(
            t=_num,
            mode=_str,
            policy={"type": ["string", "null"]},
            operator={"type": ["string", "null"]},
            cause=_str,
            rate_hz=_num,
            refused={"type": "integer"},
            interventions={"type": "integer"},
        ),
    ),
    SAFETY: (
        "telerobot.Safety",
        _obj(
            t=_num,
            estop=_bool,
            estop_reason=_str,
            force_limited=_bool,
            halted=_bool,
            lease_holder={"type": ["string", "null"]},
            lease_holder_name={"type": ["string", "null"]},
            lease_note=_str,
            force_limited_arms={"type": "array", "items": _str},
        ),
    ),
    EPISODES: (
        "telerobot.Episode",
        _obj(
            t=_num,
            event=_str,
            episode={"type": "integer"},
            task=_str,
            success={"type": ["boolean", "null"]},
            notes=_str,
        ),
    ),
    # Foxglove's well-known schemas (github.com/foxglove/foxglove-sdk, schemas/jsonschema)
    VIDEO: (
        "foxglove.CompressedVideo",
        _obj(
            timestamp=_time,
            frame_id=_str,
            data={"type": "string", "contentEncoding": "base64"},
            format=_str,
        ),
    ),
    TF: (
        "foxglove.FrameTransforms",
        _obj(
            transforms={
                "type": "array",
                "items": _obj(
                    timestamp=_time,
                    parent_frame_id=_str,
                    child_frame_id=_str,
                    translation=_xyz,
                    rotation=_quat,
                ),
            }
        ),
    ),
    TASKS: (
        "telerobot.Task",
        _obj(
            t=_num,
            id=_str,
            state=_str,
            reason=_str,
            progress=_num,
            s=_num,
            duration=_num,
            speed=_num,
            force_n=_num,
            recorded_n=_num,
            peak_force_n=_num,
            offset=_vec,
            supervisor=_str,
            source=_str,
            arms={"type": "array", "items": _str},
        ),
    ),
    CALIBRATION: ("telerobot.Calibration", {"type": "object"}),
    SETTINGS: ("telerobot.Settings", {"type": "object"}),
    ARMS: (
        "telerobot.Arms",
        _obj(
            t=_num,
            arms={
                "type": "array",
                "items": _obj(
                    name=_str,
                    index={"type": "integer"},
                    model=_str,
                    dof={"type": "integer"},
                    joint_names={"type": "array", "items": _str},
                    mount={"type": "array", "items": _vec},
                ),
            },
        ),
    ),
}

# Fields carried as bytes in Python and as base64 in the file.
BYTES_FIELDS: dict[str, str] = {VIDEO: "data"}


def arm_topic(arm: str, kind: str) -> str:
    """One arm's channel of a multi-arm recording: ``/arms/left/state``, ``/arms/left/force``."""
    return f"{ARM_PREFIX}{arm}/{kind}"


def arm_of(topic: str) -> tuple[str, str] | None:
    """``(arm, kind)`` of an arm's channel (``kind``: ``state`` or ``force``), else None."""
    if not topic.startswith(ARM_PREFIX):
        return None
    arm, _, kind = topic[len(ARM_PREFIX) :].partition("/")
    return (arm, kind) if arm and kind in (ARM_STATE, ARM_FORCE) else None


def schema_of(topic: str) -> tuple[str, dict[str, Any]]:
    """The schema name and JSON Schema of any channel (an arm's as ``/robot/state``'s or
    ``/force``'s, with its ``arm``)."""
    found = CHANNELS.get(topic)
    if found is not None:
        return found
    arm = arm_of(topic)
    if arm is None:
        return f"telerobot.{topic.strip('/')}", {}
    name, schema = CHANNELS[ROBOT_STATE if arm[1] == ARM_STATE else FORCE]
    return name, {**schema, "properties": {**schema["properties"], "arm": _str}}
