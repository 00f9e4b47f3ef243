"""A Telerobot server's arm as LeRobot sees a robot: its joints in LeRobot's units
(``units``), its 6-axis force, its two cameras (``cameras``), and joint targets sent
through the server like any other input's. Used by the ``lerobot_robot_telerobot`` plugin
(``integrations/lerobot/robot``); it needs no LeRobot itself.

- **Reading the arm.** Its model (joint names and limits) comes from the server
  (``GET /api/v1/robot/model``), so the PUMA, the SO-101 and any URDF arm work alike.
- **Commands** go over the priority channel as a named client holding the lease, by
  the joint mirror (``telerobot.client.master.joints``) the SO-101's leader arm uses:
  each ``send`` sets the target, which the mirror approaches at ``max_speed_rad_s`` a
  joint, 100 times a second; the server's limits, lease, dead-man and e-stop apply to
  every increment, and its replies keep the mirror's record its target exactly (a
  scaled or refused increment is taken back). A target outside the arm's limits is
  clipped to them, said once per joint in the log and counted (``clipped``).
- **Observation.** The newest frame (waiting up to 1.5 frame periods for a new one),
  and the STATE the server sampled nearest to that frame's capture time (the skew is
  kept in ``last_skew_s``); the force is the newest sample. Without cameras, the
  newest STATE.
- **Disconnecting** lets the arm reach its last target first (at most ``SETTLE_S``),
  then gives the lease back.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, cast

import httpx
import numpy as np

from telerobot.client.lerobot.cameras import CAMERAS, StereoFrame, StereoReceiver, wait_s
from telerobot.client.lerobot.units import FloatArray, JointUnits
from telerobot.client.master.joints import JointMirror, MirrorSettings
from telerobot.client.master.link import PriorityLink, open_link
from telerobot.drivers.base import ForceSample, JointLeader, TelerobotError
from telerobot.protocol import messages as m

log = logging.getLogger(__name__)

FORCE_NAMES = ("fx", "fy", "fz", "tx", "ty", "tz")
SETTLE_S = 5.0  # disconnecting waits at most this for the arm to reach its last target
SETTLED_RAD = 0.01
POSE_FIELDS = ("x", "y", "z", "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22")
STATES_KEPT = 250  # 5 s of STATEs at 50 Hz: the frame's capture time is within them
CONNECT_S = 10.0
REANCHOR_RAD = 0.02
TAKE_BACK_S = 1.0  # a free lease is asked for again at most this often
# An action after this long without one starts a new run (a replay, a rollout): if it is
# farther than APPROACH_RAD from the arm, the arm goes there before send returns.
IDLE_S = 1.0
APPROACH_RAD = 0.05


@dataclass
class ArmOptions:
    url: str
    token: str = field(repr=False)  # the operator token, or a policy's (policy=True)
    name: str = "lerobot"
    cameras: bool = True
    width: int = 640  # of one camera: frames of another size are resized to it
    height: int = 480
    fps: float = 30.0
    max_speed_rad_s: float = 0.95  # per joint; the server's joint limit is 1 rad/s
    rate_hz: float = 100.0
    take_over: bool = False
    # A learned policy drives (lerobot-rollout, lerobot-eval): the server supervises it
    # (docs/protocol.md, Supervised autonomy): an operator takes over at will, and its
    # actions are refused while paused or corrected (send returns the server's target).
    policy: bool = False


class _Targets:
    """The joint "leader" the mirror follows: the newest target sent, or before any,
    where the arm is (so it holds still)."""

    name = "lerobot"

    def __init__(self, names: tuple[str, ...], where: Any) -> None:
        self.joint_names = names
        self._where = where
        self.target: FloatArray | None = None

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def read(self) -> FloatArray:
        if self.target is not None:
            return self.target
        here = self._where()
        return np.zeros(len(self.joint_names)) if here is None else here


class TelerobotArm:
    def __init__(self, options: ArmOptions) -> None:
        self.options = options
        self.units: JointUnits | None = None
        self.link: PriorityLink | None = None
        self.mirror: JointMirror | None = None
        self.receiver: StereoReceiver | None = None
        self._targets: _Targets | None = None
        self._lock = threading.Lock()
        self._states: collections.deque[tuple[float, FloatArray]] = collections.deque(
            maxlen=STATES_KEPT
        )
        self._poses: collections.deque[FloatArray] = collections.deque(maxlen=STATES_KEPT)
        self._force: ForceSample | None = None
        self._frame_seq = -1
        self.clipped = 0  # targets that had a joint outside the limits
        self._said_clipped: set[str] = set()
        self.last_skew_s: float | None = None  # state time − frame capture time
        self.last_capture_time: float | None = None  # the newest observation's frame (server clock)
        self.repeated_frames = 0
        self._said_not_in_control = False
        self._asked_back = -math.inf  # when the free lease was last asked for (monotonic)
        self._last_sent = -math.inf  # when the last action was sent (monotonic)

    # ------------------------------------------------------------ connecting
    @property
    def connected(self) -> bool:
        return self.mirror is not None

    def connect(self) -> None:
        o = self.options
        base = o.url if o.url.endswith("/") else o.url + "/"
        self.units = describe_arm(o.url)
        try:
            link = open_link(o.url, o.token, datagrams=False, name=o.name, policy=o.policy)
        except TelerobotError as exc:  # no priority channel, or the token refused
            raise ConnectionError(str(exc)) from None
        if not link.operator:
            link.close()
            raise PermissionError(
                f"{base} took the token as an observer's: commands need the operator token"
            )
        self.link = link
        self._targets = _Targets(self.units.names, self._newest_joints)
        settings = MirrorSettings(
            rate_hz=o.rate_hz,
            max_speed_rad_s=o.max_speed_rad_s,
            align=False,
            straight=True,
            # No leader to align, but an arm that came to rest this far from the record
            # (stopped by a pause, an e-stop, a takeover) is followed again from where
            # it is, not from the record: the policy resumes from the arm's pose.
            align_rad=REANCHOR_RAD,
        )
        # (_Targets is a JointLeader but for from_options: it is built here, not from a port.)
        leader = cast(JointLeader, self._targets)
        self.mirror = JointMirror(leader, link, self.units.names, settings.check())
        mirror_state = link.on_state

        def on_state(fields: dict[str, Any]) -> None:
            self._on_state(fields)
            if mirror_state is not None:
                mirror_state(fields)

        link.on_state = on_state
        link.on_force = self._on_force
        for _ in range(5):  # the clock offset, to date the frames' arrival and unwrap timecodes
            link.ping()
        self.mirror.start(take_control=True, take_over=o.take_over)
        deadline = time.monotonic() + CONNECT_S
        while not (self.mirror.has_control and self._states):
            if time.monotonic() > deadline or link.closed_reason:
                why = self.mirror.last_error or link.closed_reason or "no reply"
                self.disconnect(settle=False)
                raise ConnectionError(f"{base} did not give control to {o.name!r}: {why}")
            time.sleep(0.02)
        if o.cameras:
            self.receiver = StereoReceiver(o.url, o.token, (o.width, o.height), self._server_now)
            try:
                self.receiver.start()
            except ConnectionError:
                self.disconnect(settle=False)
                raise

    def _server_now(self) -> float:
        link = self.link
        return time.monotonic() + (link.offset if link is not None else 0.0)

    def disconnect(self, settle: bool = True) -> None:
        mirror, link, receiver = self.mirror, self.link, self.receiver
        if settle and mirror is not None and self._targets is not None:
            self._settle(mirror, self._targets.target)
        if receiver is not None:
            receiver.stop()
        if mirror is not None:
            mirror.stop()
        if link is not None:
            link.close()
        self.mirror = self.link = self.receiver = None

    def _approach(self, mirror: JointMirror, target: FloatArray) -> None:
        """Wait while the arm goes to ``target`` if it is more than APPROACH_RAD away: as
        long as the way takes at the arm's speed, twice, plus SETTLE_S at most."""
        here = self._newest_joints()
        if here is None:
            return
        way = float(np.abs(here - target).max())
        if way < APPROACH_RAD:
            return
        log.info("%s goes to its first target (%.2f rad away) first", self.options.name, way)
        self._until_at(mirror, target, 2 * way / self.options.max_speed_rad_s + SETTLE_S)

    def _settle(self, mirror: JointMirror, target: FloatArray | None) -> None:
        """Let the arm reach the last target before the lease goes (a replay's last
        pose), for at most SETTLE_S."""
        if target is not None:
            self._until_at(mirror, target, SETTLE_S)

    def _until_at(self, mirror: JointMirror, target: FloatArray, within_s: float) -> None:
        """Wait until the arm is within SETTLED_RAD of ``target``, ``within_s`` at most,
        and only while this client holds control (else it is not going there)."""
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline and mirror.has_control:
            here = self._newest_joints()
            if here is not None and np.abs(here - target).max() < SETTLED_RAD:
                return
            time.sleep(0.02)

    # ------------------------------------------------------------ from the link
    def _on_state(self, fields: dict[str, Any]) -> None:
        with self._lock:
            self._states.append((float(fields["server_time"]), np.array(fields["joints"], float)))
            self._poses.append(np.array([fields[k] for k in POSE_FIELDS], float))

    def _on_force(self, sample: ForceSample, _received: float) -> None:
        self._force = sample

    @property
    def force(self) -> dict[str, float]:
        """The newest force sample (N, N·m; zeros before the first), for a caller that
        wants it beside the observation (it is not a LeRobot feature: see
        ``observation_features``)."""
        values = self._force.values if self._force is not None else (0.0,) * 6
        return {n: float(v) for n, v in zip(FORCE_NAMES, values, strict=True)}

    def _newest_joints(self) -> FloatArray | None:
        with self._lock:
            return self._states[-1][1].copy() if self._states else None

    def tool_pose_at(self, t: float) -> FloatArray:
        """The tool's pose in the STATE sampled nearest to ``t`` (server clock): position
        (m) then the row-major rotation, base frame, as the export's
        ``observation.tool_pose``."""
        with self._lock:
            times = np.array([s[0] for s in self._states])
            poses = list(self._poses)
        return poses[int(np.argmin(np.abs(times - t)))].copy()

    def _state_at(self, t: float) -> tuple[float, FloatArray]:
        with self._lock:
            states = list(self._states)
        times = np.array([s[0] for s in states])
        i = int(np.argmin(np.abs(times - t)))
        return states[i]

    # ------------------------------------------------------------ LeRobot's calls
    def _need(self) -> tuple[JointUnits, JointMirror, _Targets]:
        if self.units is None or self.mirror is None or self._targets is None:
            raise ConnectionError("the Telerobot arm is not connected: call connect() first")
        link = self.link
        if link is not None and link.closed_reason:
            raise ConnectionError(f"the server closed the priority channel: {link.closed_reason}")
        return self.units, self.mirror, self._targets

    def observation(self) -> dict[str, Any]:
        units, _, _ = self._need()
        frame: StereoFrame | None = None
        if self.receiver is not None:
            if not self.receiver.alive:
                raise ConnectionError(f"the video ended: {self.receiver.error or 'closed'}")
            # The newest frame there is, as LeRobot's own robots read their cameras
            # (``read_latest``): waiting for a newer one (up to 1.5 frame periods) cost
            # lerobot-record its rate on a busy machine. Only the first is waited for.
            frame = self.receiver.latest() or self.receiver.newer_than(-1, wait_s(self.options.fps))
        if frame is not None:
            if frame.seq == self._frame_seq:
                self.repeated_frames += 1
            self._frame_seq = frame.seq
            self.last_capture_time = frame.capture_time
            t_state, joints = self._state_at(frame.capture_time)
            self.last_skew_s = t_state - frame.capture_time
        else:
            newest = self._newest_joints()
            assert newest is not None  # connect() waited for a STATE
            joints = newest
        values = units.to_lerobot(joints)
        out: dict[str, Any] = dict(zip(units.feature_names, map(float, values), strict=True))
        if frame is not None:
            out["left"], out["right"] = frame.left, frame.right
        return out

    def _take_back_if_free(self, mirror: JointMirror) -> None:
        """The robot held the lease until an operator took over; once they let it go (the
        lease free), take it back, as a supervised policy is handed back: the recording
        goes on being driven by LeRobot's actions. Never from someone holding it, and
        never a policy's (the server hands control back to a policy: docs/lerobot.md).
        Asked at most once every TAKE_BACK_S."""
        if self.options.policy or not _nobody_holds(mirror):
            return
        now = time.monotonic()
        if now - self._asked_back < TAKE_BACK_S:
            return
        self._asked_back = now
        log.info("%s takes control back: nobody holds it", self.options.name)
        mirror.link.lease(m.LeaseAction.TAKE)

    def send(self, action: dict[str, Any]) -> dict[str, float]:
        """The target in LeRobot's units (every joint's ``.pos``); returns the target as
        applied (clipped to the limits), in the same units."""
        units, mirror, targets = self._need()
        missing = [k for k in units.feature_names if k not in action]
        if missing:
            raise ValueError(f"the action has no {', '.join(missing)} (the arm's joints: "
                             f"{', '.join(units.feature_names)})")  # fmt: skip
        values = np.array([float(action[k]) for k in units.feature_names])
        if not np.all(np.isfinite(values)):
            raise ValueError(f"the action is not finite: {values.tolist()}")
        q, moved = units.clip(units.from_lerobot(values))
        if moved:
            self.clipped += 1
            for name in set(moved) - self._said_clipped:
                log.warning("a target of %s beyond its limits was clipped to them", name)
            self._said_clipped |= set(moved)
        if not mirror.has_control:
            # Someone else drives (the operator took over, LeRobot's teleoperator being the
            # Telerobot one): the server applies their commands; sending this one too would
            # apply it twice. What was applied is the server's target. Once they let go,
            # the lease is taken back.
            self._take_back_if_free(mirror)
            if not self._said_not_in_control:
                log.info("%s does not hold control: its actions are not sent", self.options.name)
                self._said_not_in_control = True
            return server_target(self.options, units)
        self._said_not_in_control = False
        first = targets.target is None or time.monotonic() - self._last_sent > IDLE_S
        targets.target = q
        self._last_sent = time.monotonic()
        if first:
            # The first action (of a replay, a rollout) may be far from where the arm is:
            # it is reached first, at the arm's speed, before the caller's clock runs on
            # (lerobot-replay times each frame after the last returns); else the frames
            # after it are targets the arm is still far behind.
            self._approach(mirror, q)
        applied = units.to_lerobot(q)
        return {k: float(v) for k, v in zip(units.feature_names, applied, strict=True)}


def _nobody_holds(mirror: JointMirror) -> bool:
    return not mirror.flags & m.StateFlags.SOMEONE_HAS_CONTROL


def describe_arm(url: str) -> JointUnits:
    """The server's arm (``GET /api/v1/robot/model``): its joints and their units."""
    base = url if url.endswith("/") else url + "/"
    try:
        r = httpx.get(base + "api/v1/robot/model", timeout=10, verify=False)
    except httpx.HTTPError as exc:
        raise ConnectionError(f"cannot ask {base} for its arm: {exc}") from None
    if r.status_code != 200:
        # E.g. a server with two arms or more, which names them: the plugin drives one
        # arm (LeRobot's so_follower); both arms' demonstrations are `telerobot export lerobot`
        # (bi_so_follower-shaped, docs/lerobot.md).
        detail = _detail(r)
        raise ConnectionError(
            f"cannot ask {base} for its arm ({r.status_code}): {detail}; the Telerobot robot"
            " drives a server with one arm (a two-arm session's LeRobot dataset is"
            " `telerobot export lerobot`)"
        )
    try:
        return JointUnits.from_described(r.json())
    except (ValueError, KeyError) as exc:
        raise ConnectionError(f"{base} described its arm in a way not understood: {exc}") from None


def _detail(r: httpx.Response) -> str:
    """What the server said of a refusal (its problem detail), else its status line."""
    try:
        return str(r.json().get("detail") or r.reason_phrase)
    except ValueError:
        return r.reason_phrase


def server_target(options: ArmOptions, units: JointUnits) -> dict[str, float]:
    """The arm's target on the server now (``GET /api/v1/robot/state``), LeRobot's units."""
    base = options.url if options.url.endswith("/") else options.url + "/"
    headers = {"Authorization": f"Bearer {options.token}"} if options.token else {}
    try:
        r = httpx.get(base + "api/v1/robot/state", headers=headers, timeout=10, verify=False)
        r.raise_for_status()
        values = units.to_lerobot(r.json()["target_joints"])
    except (httpx.HTTPError, ValueError, KeyError) as exc:
        raise ConnectionError(f"cannot read the arm's target from {base}: {exc}") from None
    return {k: float(v) for k, v in zip(units.feature_names, values, strict=True)}


def observation_features(joint_keys: list[str], options: ArmOptions) -> dict[str, Any]:
    """The joints and the cameras, as LeRobot's own robot of the same arm reports them
    (the SO-101's ``so_follower``). Nothing else: ``lerobot-record`` puts every number a
    robot reports into ``observation.state`` (LeRobot 0.6.1's
    ``aggregate_pipeline_dataset_features``), and forces there made a 12-value state no
    SO-101 policy or tool takes. The forces are in the session's recording and in
    Telerobot's export, as ``observation.force`` (docs/lerobot.md)."""
    out: dict[str, Any] = {k: float for k in joint_keys}
    if options.cameras:
        for cam in CAMERAS:
            out[cam] = (options.height, options.width, 3)
    return out


__all__ = ["ArmOptions", "TelerobotArm", "TelerobotError", "describe_arm", "observation_features"]
