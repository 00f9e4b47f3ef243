"""A Telerobot server's arm as LeRobot sees a robot: its joints in LeRobot's units
(``units``), its 6-axis force, its two cameras (``cameras``), and joint targets sent
through the server like any other input's. Used by the ``lerobot_robot_telerobot`` plugin
(``integrations/lerobot/robot``); it needs no LeRobot itself.

- **Reading the arm.** Its model (joint names and limits) comes from the server
  (``GET /api/v1/robot/model``), so the PUMA, the SO-101 and any URDF arm work alike.
  A server with two arms is one robot of both, as LeRobot's bimanual robots are
  (``parts``: each arm's keys prefixed with its name, ``bi_so_follower``'s for two
  SO-101s named left and right); one link, one lease, one mirror per arm.
- **Commands** go over the priority channel as a named client holding the lease, by
  the joint mirror (``telerobot.client.master.joints``) the SO-101's leader arm uses:
  each ``send`` sets the target, which the mirror approaches at ``max_speed_rad_s`` a
  joint, 100 times a second; the server's limits, lease, dead-man and e-stop apply to
  every increment, and its replies keep the mirror's record its target exactly (a
  scaled or refused increment is taken back). A target outside the arm's limits is
  clipped to them, said once per joint in the log and counted (``clipped``).
- **Refusals** (a paused policy's: every increment, 100 a second) and actions not sent
  (someone else holds control) are said once a reason, with what the supervisor can
  do, and once commands are applied again with how many were refused meanwhile
  (``refusals``).
- **The token** is held as a ``SecretStr``: no repr, log line or error shows it.
- **Observation.** The newest frame (waiting up to 1.5 frame periods for a new one),
  and the STATE the server sampled nearest to that frame's capture time (the skew is
  kept in ``last_skew_s``); the force is the newest sample. Without cameras, the
  newest STATE.
- **Disconnecting** lets the arm reach its last target first (at most ``SETTLE_S``),
  then gives the lease back.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any, cast

import httpx
import numpy as np
from pydantic import SecretStr

from telerobot.client.lerobot.cameras import CAMERAS, StereoFrame, StereoReceiver, wait_s
from telerobot.client.lerobot.parts import ArmPart, describe_arms, read_json, robot_type
from telerobot.client.lerobot.refusals import Refusals, supervision_of, what_to_do
from telerobot.client.lerobot.units import FloatArray
from telerobot.client.master.joints import JointMirror, JointMirrors, MirrorSettings
from telerobot.client.master.link import PriorityLink, open_link
from telerobot.client.tokens import bearer, secret
from telerobot.drivers.base import ForceSample, JointLeader, TelerobotError
from telerobot.protocol import messages as m

log = logging.getLogger(__name__)

FORCE_NAMES = ("fx", "fy", "fz", "tx", "ty", "tz")
SETTLE_S = 5.0  # disconnecting waits at most this for the arm to reach its last target
SETTLED_RAD = 0.01
CONNECT_S = 10.0
REANCHOR_RAD = 0.02
TAKE_BACK_S = 1.0  # a free lease is asked for again at most this often
# An action after this long without one starts a new run (a replay, a rollout): if it is
# farther than APPROACH_RAD from the arm, the arm goes there before send returns.
IDLE_S = 1.0
APPROACH_RAD = 0.05
# At connect new frames are counted for this long: below RATE_KEPT of ``fps`` the rate
# that can be kept is said.
RATE_PROBE_S = 1.0
RATE_KEPT = 0.9


@dataclass
class ArmOptions:
    url: str
    # The operator token, or a policy's (policy=True); a str is held as a SecretStr, so
    # no repr, log line or error shows it.
    token: SecretStr | str
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

    def __post_init__(self) -> None:
        self.token = secret(self.token)


class TelerobotArm:
    def __init__(self, options: ArmOptions) -> None:
        self.options = options
        self.parts: list[ArmPart] = []  # the server's arms, in their columns' order
        self.link: PriorityLink | None = None
        self.mirrors: JointMirrors | None = None
        self.receiver: StereoReceiver | None = None
        self._forces: dict[int, ForceSample] = {}  # the newest sample of each arm (wire index)
        self._frame_seq = -1
        self.clipped = 0  # targets that had a joint outside the limits
        self.last_skew_s: float | None = None  # state time − frame capture time (the largest)
        self.last_capture_time: float | None = None  # the newest observation's frame (server clock)
        self.repeated_frames = 0
        self.video_rate_hz: float | None = None  # new frames a second, counted at connect
        self.refusals = Refusals(options.name, self._explain)
        self._asked_back = -math.inf  # when the free lease was last asked for (monotonic)
        self._last_sent = -math.inf  # when the last action was sent (monotonic)

    # ------------------------------------------------------------ connecting
    @property
    def connected(self) -> bool:
        return self.mirrors is not None

    @property
    def has_control(self) -> bool:
        return self.mirrors is not None and self.mirrors.has_control

    @property
    def only(self) -> ArmPart:
        """The server's one arm (a caller written for one: the benches, the tests)."""
        if len(self.parts) != 1:
            names = ", ".join(p.name for p in self.parts) or "none yet: connect first"
            raise ValueError(f"the server drives {len(self.parts)} arms ({names}): see parts")
        return self.parts[0]

    @property
    def keys(self) -> list[str]:
        """Every arm's joint keys, in order: the robot's action and state."""
        return [k for p in self.parts for k in p.keys]

    def connect(self) -> None:
        o = self.options
        base = o.url if o.url.endswith("/") else o.url + "/"
        self.parts = describe_arms(o.url)
        try:
            token = secret(o.token).get_secret_value()
            link = open_link(o.url, token, datagrams=False, name=o.name, policy=o.policy)
        except TelerobotError as exc:  # no priority channel, or the token refused
            raise ConnectionError(str(exc)) from None
        if not link.operator:
            link.close()
            raise PermissionError(
                f"{base} took the token as an observer's: commands need the operator token"
            )
        self.link = link
        settings = MirrorSettings(
            rate_hz=o.rate_hz,
            max_speed_rad_s=o.max_speed_rad_s,
            align=False,
            straight=True,
            # No leader to align, but an arm that came to rest this far from the record
            # (stopped by a pause, an e-stop, a takeover) is followed again from where
            # it is, not from the record: the policy resumes from the arm's pose.
            align_rad=REANCHOR_RAD,
        ).check()
        for part in self.parts:
            # (Targets is a JointLeader but for from_options: it is built here, not from a port.)
            leader = cast(JointLeader, part.targets)
            part.mirror = JointMirror(leader, link, part.units.names, settings, arm=part.wire)
            part.mirror.on_increment_reply = self.refusals.on_reply
        self.mirrors = JointMirrors([cast(JointMirror, p.mirror) for p in self.parts])
        self.mirrors.on_other_refusal = self.refusals.on_reply
        mirrors_state = link.on_state

        def on_state(fields: dict[str, Any]) -> None:
            for part in self.parts:
                part.on_state(fields)
            if mirrors_state is not None:
                mirrors_state(fields)

        link.on_state = on_state
        link.on_arm_force = self._on_force
        for _ in range(5):  # the clock offset, to date the frames' arrival and unwrap timecodes
            link.ping()
        self.mirrors.start(take_control=True, take_over=o.take_over)
        deadline = time.monotonic() + CONNECT_S
        while not (self.mirrors.has_control and all(p.has_state for p in self.parts)):
            if time.monotonic() > deadline or link.closed_reason:
                said = [p.mirror.last_error for p in self.parts if p.mirror is not None]
                said += [self.mirrors.last_error, link.closed_reason]
                why = next((s for s in said if s), "no reply")
                self.disconnect(settle=False)
                raise ConnectionError(f"{base} did not give control to {o.name!r}: {why}")
            time.sleep(0.02)
        if o.cameras:
            self.receiver = StereoReceiver(
                o.url, secret(o.token), (o.width, o.height), self._server_now
            )
            try:
                self.receiver.start()
            except ConnectionError:
                self.disconnect(settle=False)
                raise
            self._say_the_rate(self.receiver)

    def _say_the_rate(self, receiver: StereoReceiver) -> None:
        """The rate new frames come at, over RATE_PROBE_S, and if it is below the rate
        the robot is read at (``fps``: lerobot-record's), the rate it can keep, said once
        at connect: past it LeRobot's frames repeat (``repeated_frames``) and a dataset's
        fps would claim pictures it does not have. The server's cameras may be slower,
        or this machine's decoder."""
        first = receiver.received
        time.sleep(RATE_PROBE_S)
        self.video_rate_hz = (receiver.received - first) / RATE_PROBE_S
        can = min(self.video_rate_hz, receiver.server_fps or math.inf)
        if can < self.options.fps * RATE_KEPT:
            log.warning(
                "new frames come at %.1f a second here (the server's cameras: %s), fewer than"
                " the %g the robot is read at: its frames will repeat. Record at"
                " --dataset.fps=%d or less, or give the server's video more (docs/lerobot.md)",
                can, f"{receiver.server_fps:g} fps" if receiver.server_fps else "not said",
                self.options.fps, max(1, math.floor(can)),
            )  # fmt: skip

    def _server_now(self) -> float:
        link = self.link
        return time.monotonic() + (link.offset if link is not None else 0.0)

    def disconnect(self, settle: bool = True) -> None:
        mirrors, link, receiver = self.mirrors, self.link, self.receiver
        if settle and mirrors is not None:
            self._until_at(SETTLE_S)  # a replay's last pose reached before the lease goes
        if receiver is not None:
            receiver.stop()
        if mirrors is not None:
            mirrors.stop()
        if link is not None:
            link.close()
        self.mirrors = self.link = self.receiver = None
        for part in self.parts:
            part.mirror = None

    def _approach(self) -> None:
        """Wait while the arms go to their targets if one is more than APPROACH_RAD
        away: as long as the way takes at the arm's speed, twice, plus SETTLE_S at most."""
        way = max((self._way(p) for p in self.parts), default=0.0)
        if way < APPROACH_RAD:
            return
        log.info("%s goes to its first target (%.2f rad away) first", self.options.name, way)
        self._until_at(2 * way / self.options.max_speed_rad_s + SETTLE_S)

    @staticmethod
    def _way(part: ArmPart) -> float:
        here, target = part.newest_joints(), part.targets.target
        return 0.0 if here is None or target is None else float(np.abs(here - target).max())

    def _until_at(self, within_s: float) -> None:
        """Wait until every arm is within SETTLED_RAD of its target, ``within_s`` at most,
        and only while this client holds control (else they are not going there)."""
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline and self.has_control:
            if all(self._way(p) < SETTLED_RAD for p in self.parts):
                return
            time.sleep(0.02)

    # ------------------------------------------------------------ from the link
    def _on_force(self, arm: int, sample: ForceSample, _received: float) -> None:
        self._forces[arm] = sample

    @property
    def force(self) -> dict[str, float]:
        """The newest force sample of each arm (N, N·m; zeros before the first), keys
        prefixed as the joints' (``fx`` …, ``left_fx`` …), for a caller that wants it
        beside the observation (it is not a LeRobot feature: see ``observation_features``)."""
        out: dict[str, float] = {}
        for part in self.parts:
            if len(self.parts) == 1:  # (its samples' arm byte: whatever the server numbers it)
                sample = next(iter(self._forces.values()), None)
            else:
                sample = self._forces.get(part.mirror.arm if part.mirror is not None else -1)
            values = sample.values if sample is not None else (0.0,) * 6
            out |= {part.prefix + n: float(v) for n, v in zip(FORCE_NAMES, values, strict=True)}
        return out

    def tool_pose_at(self, t: float) -> FloatArray:
        """Each arm's tool pose in the STATE sampled nearest to ``t`` (server clock), one
        after the other: position (m) then the row-major rotation, each in its arm's base
        frame, as the export's ``observation.tool_pose``."""
        return np.concatenate([p.tool_pose_at(t) for p in self.parts])

    # ------------------------------------------------------------ LeRobot's calls
    def _need(self) -> JointMirrors:
        if not self.parts or self.mirrors is None:
            raise ConnectionError("the Telerobot arm is not connected: call connect() first")
        link = self.link
        if link is not None and link.closed_reason:
            raise ConnectionError(f"the server closed the priority channel: {link.closed_reason}")
        return self.mirrors

    def observation(self) -> dict[str, Any]:
        self._need()
        frame: StereoFrame | None = None
        if self.receiver is not None:
            if not self.receiver.alive:
                raise ConnectionError(f"the video ended: {self.receiver.error or 'closed'}")
            # The newest frame there is, as LeRobot's own robots read their cameras
            # (``read_latest``): waiting for a newer one (up to 1.5 frame periods) cost
            # lerobot-record its rate on a busy machine. Only the first is waited for.
            frame = self.receiver.latest() or self.receiver.newer_than(-1, wait_s(self.options.fps))
        out: dict[str, Any] = {}
        skews = []
        for part in self.parts:
            if frame is not None:
                t_state, joints = part.state_at(frame.capture_time)
                skews.append(t_state - frame.capture_time)
            else:
                newest = part.newest_joints()
                assert newest is not None  # connect() waited for a STATE of each
                joints = newest
            values = part.units.to_lerobot(joints)
            out |= dict(zip(part.keys, map(float, values), strict=True))
        if frame is not None:
            if frame.seq == self._frame_seq:
                self.repeated_frames += 1
            self._frame_seq = frame.seq
            self.last_capture_time = frame.capture_time
            self.last_skew_s = max(skews, key=abs)
            out["left"], out["right"] = frame.left, frame.right
        return out

    def _take_back_if_free(self, mirror: JointMirrors) -> None:
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

    def _explain(self, refused: str | None) -> str:
        """The line said of this client's commands not applied (``refused``: the server's
        words; None: not in control): a policy's with what its supervisor can do in the
        state the server says it is in."""
        o = self.options
        if not o.policy:
            if refused is None:
                return f"{o.name} does not hold control: its actions are not sent"
            return f"the server refused {o.name}'s commands: {refused}"
        try:
            autonomy, estop = supervision_of(o.url, bearer(secret(o.token)))
        except ConnectionError as exc:
            autonomy, estop = {}, False
            log.info("the supervision's state is not known: %s", exc)
        return what_to_do(o.name, autonomy, estop, refused)

    def send(self, action: dict[str, Any]) -> dict[str, float]:
        """The target in LeRobot's units (every joint's ``.pos``, each arm's prefixed on a
        server with more); returns the target as applied (clipped to the limits), in the
        same units."""
        mirrors = self._need()
        keys = self.keys
        missing = [k for k in keys if k not in action]
        if missing:
            raise ValueError(f"the action has no {', '.join(missing)} (the arm's joints: "
                             f"{', '.join(keys)})")  # fmt: skip
        each = [np.array([float(action[k]) for k in part.keys]) for part in self.parts]
        values = np.concatenate(each)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"the action is not finite: {values.tolist()}")
        targets = []
        for part, mine in zip(self.parts, each, strict=True):
            q, moved = part.units.clip(part.units.from_lerobot(mine))
            if moved:
                self.clipped += 1
                for name in set(moved) - part.said_clipped:
                    log.warning("a target of %s%s beyond its limits was clipped to them",
                                part.prefix, name)  # fmt: skip
                part.said_clipped |= set(moved)
            targets.append(q)
        if not mirrors.has_control:
            # Someone else drives (the operator took over, LeRobot's teleoperator being the
            # Telerobot one): the server applies their commands; sending this one too would
            # apply it twice. What was applied is the server's target. Once they let go,
            # the lease is taken back.
            self._take_back_if_free(mirrors)
            self.refusals.withheld()
            return server_target(self.options, self.parts)
        self.refusals.say()
        first = (
            any(p.targets.target is None for p in self.parts)
            or time.monotonic() - self._last_sent > IDLE_S
        )
        for part, q in zip(self.parts, targets, strict=True):
            part.targets.target = q
        self._last_sent = time.monotonic()
        if first:
            # The first action (of a replay, a rollout) may be far from where the arm is:
            # it is reached first, at the arm's speed, before the caller's clock runs on
            # (lerobot-replay times each frame after the last returns); else the frames
            # after it are targets the arm is still far behind.
            self._approach()
        out: dict[str, float] = {}
        for part, q in zip(self.parts, targets, strict=True):
            out |= dict(zip(part.keys, map(float, part.units.to_lerobot(q)), strict=True))
        return out


def _nobody_holds(mirror: JointMirrors) -> bool:
    return not mirror.flags & m.StateFlags.SOMEONE_HAS_CONTROL


def server_target(options: ArmOptions, parts: list[ArmPart]) -> dict[str, float]:
    """The arms' targets on the server now (``GET /api/v1/robot/state``), LeRobot's units."""
    base = options.url if options.url.endswith("/") else options.url + "/"
    out: dict[str, float] = {}
    headers = bearer(secret(options.token))
    with httpx.Client(base_url=base, headers=headers, timeout=10, verify=False) as http:
        for part in parts:
            what = f"{part.name}'s target"
            state = read_json(http, base, "api/v1/robot/state", part.query, what)
            try:
                values = part.units.to_lerobot(state["target_joints"])
            except (ValueError, KeyError, TypeError) as exc:
                raise ConnectionError(f"{base} gave {what} not understood: {exc}") from None
            out |= dict(zip(part.keys, map(float, values), strict=True))
    return out


def observation_features(joint_keys: list[str], options: ArmOptions) -> dict[str, Any]:
    """The joints and the cameras, as LeRobot's own robot of the same arms reports them
    (the SO-101's ``so_follower``, two SO-101s' ``bi_so_follower``: each arm's keys
    prefixed, the cameras a top-level pair, unprefixed). Nothing else: ``lerobot-record``
    puts every number a robot reports into ``observation.state`` (LeRobot 0.6.1's
    ``aggregate_pipeline_dataset_features``), and forces there made a 12-value state no
    SO-101 policy or tool takes. The forces are in the session's recording and in
    Telerobot's export, as ``observation.force`` (docs/lerobot.md)."""
    out: dict[str, Any] = {k: float for k in joint_keys}
    if options.cameras:
        for cam in CAMERAS:
            out[cam] = (options.height, options.width, 3)
    return out


__all__ = [
    "ArmOptions",
    "ArmPart",
    "TelerobotArm",
    "TelerobotError",
    "describe_arms",
    "observation_features",
    "robot_type",
]
