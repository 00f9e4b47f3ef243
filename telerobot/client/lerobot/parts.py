"""The server's arms as the LeRobot robot sees them: one ``ArmPart`` per arm, each with
its joints' units, its LeRobot keys and, once connected, its joint mirror and the
STATEs it has had (``describe_arms``).

A one-arm server is LeRobot's robot of that arm (an SO-101: ``so_follower``, keys
``shoulder_pan.pos`` …). A server with more arms is one robot of all of them, as
LeRobot's bimanual robots are: each arm's keys prefixed with its name
(``left_shoulder_pan.pos`` … ``right_gripper.pos``), two SO-101s named left and right
in ``bi_so_follower``'s order (left first) whatever the server's; the same rule as
Telerobot's export of a two-arm recording (``units.column_order``)."""

from __future__ import annotations

import collections
import threading
from typing import Any

import httpx
import numpy as np

from telerobot.client.lerobot.units import FloatArray, JointUnits, column_order, dataset_robot_type
from telerobot.client.master.joints import JointMirror

POSE_FIELDS = ("x", "y", "z", "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22")
STATES_KEPT = 250  # 5 s of STATEs at 50 Hz: a frame's capture time is within them


class Targets:
    """The joint "leader" an arm's mirror follows: the newest target sent, or before
    any, where the arm is (so it holds still)."""

    name = "lerobot"

    def __init__(self, part: ArmPart) -> None:
        self.joint_names = part.units.names
        self._part = part
        self.target: FloatArray | None = None

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def read(self) -> FloatArray:
        if self.target is not None:
            return self.target
        here = self._part.newest_joints()
        return np.zeros(len(self.joint_names)) if here is None else here


class ArmPart:
    """One of the server's arms: ``name`` (what REST's ``?arm=`` takes), its LeRobot
    keys' ``prefix`` ("" on a one-arm server) and ``units``; connected, its ``mirror``,
    its ``targets`` and the STATEs it had."""

    def __init__(self, name: str, prefix: str, units: JointUnits, several: bool) -> None:
        self.name = name
        self.prefix = prefix
        self.units = units
        # What a JointMirror's ``arm`` takes: its name where the server drives several,
        # 0 ("the only arm") where it drives one.
        self.wire: int | str = name if several else 0
        self.query = {"arm": name} if several else {}
        self.mirror: JointMirror | None = None
        self.targets = Targets(self)
        self.said_clipped: set[str] = set()
        self._lock = threading.Lock()
        self._states: collections.deque[tuple[float, FloatArray]] = collections.deque(
            maxlen=STATES_KEPT
        )
        self._poses: collections.deque[FloatArray] = collections.deque(maxlen=STATES_KEPT)

    @property
    def keys(self) -> list[str]:
        """Its joints' LeRobot keys: ``shoulder_pan.pos`` …, ``left_shoulder_pan.pos`` …"""
        return [self.prefix + k for k in self.units.feature_names]

    def on_state(self, fields: dict[str, Any]) -> None:
        mirror = self.mirror
        if mirror is not None and mirror.arm and int(fields.get("arm", mirror.arm)) != mirror.arm:
            return  # another arm's
        with self._lock:
            self._states.append((float(fields["server_time"]), np.array(fields["joints"], float)))
            self._poses.append(np.array([fields[k] for k in POSE_FIELDS], float))

    @property
    def has_state(self) -> bool:
        with self._lock:
            return bool(self._states)

    def newest_joints(self) -> FloatArray | None:
        with self._lock:
            return self._states[-1][1].copy() if self._states else None

    def state_at(self, t: float) -> tuple[float, FloatArray]:
        """The STATE sampled nearest to ``t`` (server clock): its time and joints."""
        with self._lock:
            states = list(self._states)
        times = np.array([s[0] for s in states])
        return states[int(np.argmin(np.abs(times - t)))]

    def tool_pose_at(self, t: float) -> FloatArray:
        """The tool's pose in the STATE sampled nearest to ``t``: position (m), then the
        row-major rotation, in the arm's base frame."""
        with self._lock:
            times = np.array([s[0] for s in self._states])
            poses = list(self._poses)
        return poses[int(np.argmin(np.abs(times - t)))].copy()


def robot_type(parts: list[ArmPart]) -> str:
    """The dataset's ``robot_type``: ``so_follower``, ``bi_so_follower``, … (units.py)."""
    return dataset_robot_type([(p.name, p.units.model) for p in parts])


def describe_arms(url: str) -> list[ArmPart]:
    """The server's arms (``GET /api/v1/robot/arms``, each one's ``/robot/model``), in
    their columns' order."""
    base = url if url.endswith("/") else url + "/"
    with httpx.Client(base_url=base, timeout=10, verify=False) as http:
        arms = read_json(http, base, "api/v1/robot/arms", {}, "its arms")
        try:
            names = [(str(a["name"]), str(a["model"])) for a in arms]
        except (TypeError, KeyError) as exc:
            raise ConnectionError(f"{base} listed its arms not understood: {exc}") from None
        if not names:
            raise ConnectionError(f"{base} drives no arm")
        several = len(names) > 1
        parts = []
        for i in column_order(names):
            name = names[i][0]
            query = {"arm": name} if several else {}
            described = read_json(http, base, "api/v1/robot/model", query, "its arm")
            try:
                units = JointUnits.from_described(described)
            except (ValueError, KeyError, TypeError) as exc:
                raise ConnectionError(
                    f"{base} described its arm {name} in a way not understood: {exc}"
                ) from None
            parts.append(ArmPart(name, f"{name}_" if several else "", units, several))
    return parts


def read_json(http: httpx.Client, base: str, path: str, params: dict[str, str], what: str) -> Any:
    """``GET path`` (relative to ``http``'s base URL, ``base``): its JSON. Any failure is a
    ConnectionError that says what was asked and, of a refusal, what the server said
    (its problem detail: a two-arm server's names its arms), never only a status line."""
    try:
        r = http.get(path, params=params)
    except httpx.HTTPError as exc:
        raise ConnectionError(f"cannot ask {base} for {what}: {exc}") from None
    if r.status_code != 200:
        raise ConnectionError(f"cannot ask {base} for {what} ({r.status_code}): {detail(r)}")
    try:
        return r.json()
    except ValueError as exc:
        raise ConnectionError(f"{base} answered {path} with no JSON: {exc}") from None


def detail(r: httpx.Response) -> str:
    """What the server said of a refusal (its problem detail), else its status line."""
    try:
        said = r.json().get("detail")
    except (ValueError, AttributeError):
        return r.reason_phrase
    if isinstance(said, list):  # a request's fields refused (FastAPI's 422): each one's
        return "; ".join(str(e.get("msg", e)) if isinstance(e, dict) else str(e) for e in said)
    return str(said or r.reason_phrase)
