"""The joint mirror (``telerobot master --device so101-leader``): a leader arm drives
the follower joint for joint, the way SO-101 owners teleoperate, through the server.

It runs beside the leader and talks to the server over the priority channel, as the
Cartesian master bridge does, so the follower moves only through the same lease,
limits and dead-man as every other input.

- **Aligning first.** The follower does not jump to the leader: until every leader
  joint is within ``align_rad`` of the follower's (its STATE joints), nothing moves and
  the status says which joint is how far off. Then it follows.
- **Following.** Every command period it sends the joint increment that brings its
  own record of the commanded joints toward the leader's, each joint at most
  ``max_speed_rad_s`` × period: a quick hand is followed at that speed rather than
  refused. The server may still scale one down (its joint speed limit over the time
  since the previous command, which jitter shortens): its ACK says the share applied
  (``scale``) and the record takes back the rest, so it stays the server's target
  exactly; a refused one (ERROR) is taken back whole.
- **The dead-man** is the server's: if this bridge stops sending, the arm stops. A
  leader has no clutch; letting go of it leaves the follower where the leader rests.
- **Two leaders** (a server driving two arms, docs/arms.md): one ``JointMirror`` per
  arm, each naming its arm (``arm``: the wire's index) in every increment and taking
  only that arm's STATE and status events, aligned and following on its own;
  ``JointMirrors`` runs them over one link (one client, one lease) in one loop. A
  leader that fails stops them all: the server's dead-man then stops both arms.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from telerobot.client.master.link import PriorityLink, Reply
from telerobot.drivers.base import (
    DeviceError,
    FloatArray,
    InvalidCommand,
    JointLeader,
    RobotStatus,
    TelerobotError,
)
from telerobot.drivers.threads import WorkerThread
from telerobot.protocol import messages as m

log = logging.getLogger(__name__)

STATUSES = list(RobotStatus)  # STATE's status is an index in this order
READY = STATUSES.index(RobotStatus.READY)

# Increments awaiting their reply at most (a second's worth at 1 kHz): past it the
# replies are lost, the record is not the server's, and the mirror aligns again.
MAX_IN_FLIGHT = 1000


@dataclass
class MirrorSettings:
    rate_hz: float = 100.0  # leader reads and commands per second
    align_rad: float = 0.15  # every joint this near the follower's before it follows
    max_speed_rad_s: float = 0.9  # per joint: under the server's joint speed limit
    heartbeat_s: float = 0.05
    # False: follow from wherever the arm is, at ``max_speed_rad_s`` (the LeRobot robot
    # plugin: a policy's or a replay's targets, which no hand brings near the arm first).
    align: bool = True
    # True: a step toward a far target keeps its direction (every joint scaled by the
    # slowest's share), so a replayed path is followed, not bent where one joint is capped.
    straight: bool = False

    def check(self) -> MirrorSettings:
        for name in ("rate_hz", "align_rad", "max_speed_rad_s", "heartbeat_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InvalidCommand(f"{name} must be a positive number, not {v}")
        if self.rate_hz > 1000:
            raise InvalidCommand("rate_hz must be at most 1000")
        return self


class JointMirror:
    def __init__(
        self,
        leader: JointLeader,
        link: PriorityLink,
        follower_joints: tuple[str, ...],
        settings: MirrorSettings | None = None,
        *,
        arm: int | str = 0,
        time_source: Callable[[], float] = time.monotonic,
    ) -> None:
        """``arm``: the server's arm it drives, by index or name (0: the only arm)."""
        if tuple(leader.joint_names) != tuple(follower_joints):
            raise InvalidCommand(
                f"the leader's joints {list(leader.joint_names)} are not the arm's "
                f"{list(follower_joints)}: a joint-for-joint mirror needs the same arm"
            )
        # Its arm as the link knows it (0: the only arm, whose count WELCOME says).
        self.arm = 0 if arm == 0 else link.arm_index(arm)
        self.arm_name = link.arm(self.arm).name if self.arm else ""
        joint_count = link.arm(self.arm).joints if self.arm else link.joint_count
        if joint_count != len(follower_joints):
            raise InvalidCommand(
                f"the server's arm{f' {self.arm_name}' if self.arm else ''} has"
                f" {joint_count} joints, its model names {len(follower_joints)}"
            )
        # A server with two arms or more starts each status event with its arm's name
        # ("left: ERROR: …"): this mirror keeps its own arm's, not the others'.
        self._said_prefix = f"{self.arm_name}: " if self.arm and len(link.arms) > 1 else ""
        self.leader = leader
        self.link = link
        self.names = tuple(follower_joints)
        self.settings = (settings or MirrorSettings()).check()
        self._now = time_source
        self._lock = threading.Lock()
        self._follower: FloatArray | None = None  # the newest STATE joints
        self._at_rest = False  # the newest STATE said READY (not moving)
        self.arm_status: RobotStatus | None = None  # the newest STATE's
        # What the server last said of the arm's status (an EVENT STATUS: "ERROR: why"),
        # or what the command line read at start (GET /api/v1/robot/state).
        self.arm_message: str | None = None
        self.flags = 0
        self._commanded: FloatArray | None = None  # None: aligning
        # Our JOINT_INCs awaiting their reply (seq → increment), and what the replies
        # took back from the record since the last cycle.
        self._sent: dict[int, FloatArray] = {}
        self._taken_back = np.zeros(len(follower_joints))
        self._last_heartbeat = -math.inf
        self._worker = WorkerThread(self._run, "joint-mirror")
        self.status = "waiting for the arm's state"
        self.commands_sent = 0
        self.scaled = 0  # increments the server applied in part
        self.refused = 0
        self.last_error: str | None = None
        self._said: str | None = None  # the refusal last logged
        # Set: every reply to its increments (ACK, ERROR) is handed here, and the mirror
        # logs no refusal itself: its runner says them (the LeRobot robot, once a reason
        # with what the supervisor can do: telerobot/client/lerobot/refusals.py).
        self.on_increment_reply: Callable[[Reply], None] | None = None
        # When the server applied each increment (ACK's server_time), newest last: when
        # a new target first moved the arm (bench.rollout's observation → action).
        self.applied_at: collections.deque[float] = collections.deque(maxlen=10_000)
        link.on_state = self._on_state
        link.on_reply = self._on_reply

    # ------------------------------------------------------------ from the link's thread
    def _on_state(self, fields: dict[str, Any]) -> None:
        if self.arm and int(fields.get("arm", self.arm)) != self.arm:
            return  # another arm's
        status = int(fields["status"])
        with self._lock:
            self._follower = np.array(fields["joints"], dtype=float)
            self._at_rest = status == READY
            self.flags = int(fields["flags"])
        self.arm_status = STATUSES[status] if 0 <= status < len(STATUSES) else None

    def _on_reply(self, reply: Reply) -> None:
        if reply.name == "EVENT" and int(reply.fields["kind"]) == m.EventKind.STATUS:
            if reply.text.startswith(self._said_prefix):
                self.arm_message = reply.text[len(self._said_prefix) :]
            return
        seq = int(reply.fields.get("seq", -1))
        with self._lock:
            dq = self._sent.pop(seq, None)
            if dq is not None and reply.name == "ERROR":
                self._taken_back += dq
                self.refused += 1
            elif dq is not None and reply.name == "ACK" and float(reply.fields["scale"]) < 1.0:
                self._taken_back += dq * (1.0 - float(reply.fields["scale"]))
                self.scaled += 1
            if dq is not None and reply.name == "ACK":
                self.applied_at.append(float(reply.fields["server_time"]))
        hand_to = self.on_increment_reply
        if hand_to is not None and reply.name in ("ACK", "ERROR"):
            hand_to(reply)
        if reply.name == "ERROR":
            # Said once until an increment is applied again: a policy held still by its
            # supervisor has each of its 100 increments a second refused alike.
            if reply.text != self._said and hand_to is None:
                log.warning("server: %s", reply.text)
            self.last_error = self._said = reply.text
        elif reply.name == "ACK":
            self._said = None

    def owns(self, seq: int) -> bool:
        """Whether ``seq`` is one of this mirror's increments awaiting its reply."""
        with self._lock:
            return seq in self._sent

    def _forget(self) -> None:
        """Not following: the record, the increments in flight and their replies go."""
        self._commanded = None
        with self._lock:
            self._sent.clear()
            self._taken_back = np.zeros_like(self._taken_back)

    @property
    def has_control(self) -> bool:
        return bool(self.flags & m.StateFlags.YOU_HAVE_CONTROL)

    @property
    def following(self) -> bool:
        return self._commanded is not None

    # ------------------------------------------------------------ one cycle
    def step(
        self, leader: FloatArray, follower: FloatArray | None, at_rest: bool = True
    ) -> FloatArray | None:
        """The increment to send for these joints (None: nothing to send), and the
        status said. Pure but for the mirror's own record: tests call it directly.
        It starts following only from an arm at rest: the server adds increments to
        its target, which is where the arm reports it is only once it has stopped."""
        if follower is None:
            self.status = "waiting for the arm's state"
            return None
        with self._lock:
            taken_back, self._taken_back = self._taken_back, np.zeros_like(self._taken_back)
            in_flight = sum(self._sent.values(), np.zeros_like(taken_back))
        if self._commanded is not None:
            self._commanded = self._commanded - taken_back  # what the server did not apply
            # At rest, the arm is at the server's target: the record but the increments
            # still on their way (a loaded server answers late; they are not a stop).
            expected = self._commanded - in_flight
            if at_rest and np.abs(follower - expected).max() > self.settings.align_rad:
                # The arm came to rest away from the record: the server stopped it (a
                # dead-man, an e-stop, a limit). Align again from where it is.
                self._forget()
        if self._commanded is None and not at_rest:
            self.status = self._waiting_for()
            return None
        if self._commanded is None:
            off = np.abs(leader - follower)
            worst = int(np.argmax(off))
            if self.settings.align and off[worst] > self.settings.align_rad:
                self.status = (
                    f"align the leader: {self.names[worst]} is "
                    f"{math.degrees(float(leader[worst] - follower[worst])):+.0f}° from the arm's"
                )
                return None
            self._commanded = follower.copy()
        cap = self.settings.max_speed_rad_s / self.settings.rate_hz
        want = leader - self._commanded
        if self.settings.straight:
            largest = float(np.abs(want).max())
            dq = want * (cap / largest) if largest > cap else want
        else:
            dq = np.clip(want, -cap, cap)
        self._commanded = self._commanded + dq
        lag = np.abs(leader - self._commanded)
        worst = int(np.argmax(lag))
        self.status = (
            f"following (lag {math.degrees(float(lag[worst])):.1f}° at {self.names[worst]})"
        )
        return dq if np.any(np.abs(dq) > 1e-9) else None

    def _waiting_for(self) -> str:
        """Why the mirror waits for an arm that is not READY, in words: an arm in ERROR
        or not initialised does not come to rest by itself."""
        status = self.arm_status
        if status is None or status is RobotStatus.MOVING:
            return "waiting for the arm to come to rest"
        said = self.arm_message or ""
        why = said.split(": ", 1)[1] if said.startswith(f"{status.value}: ") else ""
        if status is RobotStatus.WAITING:
            return "waiting for the arm to finish initialising"
        # Initialising needs the lease this mirror holds: it is given back first.
        todo = (
            "it needs initialising: stop the leader, press Home on the page (or POST "
            "/api/v1/robot/initialize), then start the leader again"
        )
        if status is RobotStatus.ERROR:
            return f"the arm is in ERROR{f' ({why})' if why else ''}: {todo}"
        state = "connected, not initialised" if status is RobotStatus.CONNECTED else "not connected"
        return f"the arm is {state}: {todo}"

    def tick(self) -> None:
        now = self._now()
        leader = np.asarray(self.leader.read(), dtype=float)
        with self._lock:
            follower = None if self._follower is None else self._follower.copy()
            at_rest = self._at_rest
        if not self.has_control:
            if self._commanded is not None:
                self._forget()  # taken away: align again when it comes back
            self.status = "waiting for control" if follower is not None else self.status
            dq = None
        else:
            dq = self.step(leader, follower, at_rest)
        if dq is not None:
            seq = self.link.next_seq()
            with self._lock:  # recorded before the reply can come back
                self._sent[seq] = dq
                lost = len(self._sent) > MAX_IN_FLIGHT
            if lost:  # replies lost: the record is not the server's, align again
                self._forget()
            else:
                # Sent outside the lock: the link's reader needs it to hand replies over.
                self.link.joints(dq.tolist(), seq, arm=self.arm)
            self.commands_sent += 1
            self._last_heartbeat = now
        elif now - self._last_heartbeat >= self.settings.heartbeat_s:
            self.link.heartbeat()
            self._last_heartbeat = now

    # ------------------------------------------------------------ running
    def start(self, take_control: bool = True, take_over: bool = False) -> None:
        self.leader.open()
        if take_control:
            self.link.lease(m.LeaseAction.TAKE_OVER if take_over else m.LeaseAction.TAKE)
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()
        self.leader.close()
        if self.has_control:
            with contextlib.suppress(OSError):
                self.link.lease(m.LeaseAction.RELEASE)

    def _run(self) -> None:
        _run_mirrors([self], self._worker.stopping)


def _run_mirrors(mirrors: Sequence[JointMirror], stop: threading.Event) -> None:
    """Tick every mirror each period (the first's rate) until ``stop``; a leader that
    fails, or the link closing, ends it for all (say so, stop sending: the server's
    dead-man stops the arms)."""
    period = 1.0 / mirrors[0].settings.rate_hz
    next_tick = time.monotonic()
    while not stop.is_set():
        for mirror in mirrors:
            try:
                mirror.tick()
            except TelerobotError as exc:  # the leader failed: say so, stop sending
                whose = f"{mirror.arm_name} leader" if mirror.arm_name else "leader"
                mirror.last_error = str(exc)
                mirror.status = f"leader: {exc}"
                log.error("%s: %s", whose, exc)
                for other in mirrors:
                    if other is not mirror:
                        other.status = f"stopped: the {whose} failed ({exc})"
                return
            except OSError as exc:
                for each in mirrors:
                    each.last_error = f"the priority channel closed: {exc}"
                    each.status = each.last_error
                return
        next_tick += period
        stop.wait(max(0.0, next_tick - time.monotonic()))


class JointMirrors:
    """Leaders mirrored each into its own arm over one link: one client, one lease,
    one loop. It takes the link's callbacks over from the mirrors, handing each STATE
    to its arm's mirror, each reply to the mirror whose increment it answers, and the
    status events to all (each keeps its own arm's)."""

    def __init__(self, mirrors: Sequence[JointMirror]) -> None:
        if not mirrors:
            raise InvalidCommand("no leader to mirror")
        link = mirrors[0].link
        arms = [mirror.arm for mirror in mirrors]
        if any(mirror.link is not link for mirror in mirrors):
            raise InvalidCommand("the leaders' mirrors must share one link")
        if len(set(arms)) != len(arms) or (len(arms) > 1 and 0 in arms):
            raise InvalidCommand(f"one leader per arm, each naming its arm (not {arms})")
        self.mirrors = tuple(mirrors)
        self.link = link
        self.last_error: str | None = None  # a refusal of no mirror's increment (LEASE…)
        self._said: str | None = None
        # Set: such a refusal (a lease's, an increment's forgotten on losing control) is
        # handed here and not logged, as the mirrors' own (``on_increment_reply``).
        self.on_other_refusal: Callable[[Reply], None] | None = None
        # The newest STATE's flags, whichever arm's: the lease's and the e-stop's are the
        # server's, the same in every arm's STATE.
        self.flags = 0
        self._worker = WorkerThread(self._run, "joint-mirror")
        link.on_state = self._on_state
        link.on_reply = self._on_reply

    def _on_state(self, fields: dict[str, Any]) -> None:
        self.flags = int(fields["flags"])
        for mirror in self.mirrors:
            mirror._on_state(fields)  # (each takes its own arm's)

    def _on_reply(self, reply: Reply) -> None:
        if reply.name == "EVENT":
            for mirror in self.mirrors:
                mirror._on_reply(reply)
            return
        seq = int(reply.fields.get("seq", -1))
        for mirror in self.mirrors:
            if mirror.owns(seq):
                mirror._on_reply(reply)
                return
        if reply.name == "ERROR":  # none of the increments: the lease, a heartbeat…
            if self.on_other_refusal is not None:
                self.on_other_refusal(reply)
            elif reply.text != self._said:
                log.warning("server: %s", reply.text)
            self.last_error = self._said = reply.text

    @property
    def has_control(self) -> bool:
        return any(mirror.has_control for mirror in self.mirrors)

    @property
    def commands_sent(self) -> int:
        return sum(mirror.commands_sent for mirror in self.mirrors)

    def start(self, take_control: bool = True, take_over: bool = False) -> None:
        opened: list[JointMirror] = []
        for mirror in self.mirrors:
            try:
                mirror.leader.open()
            except TelerobotError as exc:
                for each in opened:
                    each.leader.close()
                if not mirror.arm_name:
                    raise
                raise DeviceError(f"the {mirror.arm_name} arm's leader: {exc}") from None
            opened.append(mirror)
        if take_control:  # one lease covers every arm
            self.link.lease(m.LeaseAction.TAKE_OVER if take_over else m.LeaseAction.TAKE)
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()
        for mirror in self.mirrors:
            mirror.leader.close()
        if self.has_control:
            with contextlib.suppress(OSError):
                self.link.lease(m.LeaseAction.RELEASE)

    def _run(self) -> None:
        _run_mirrors(self.mirrors, self._worker.stopping)
