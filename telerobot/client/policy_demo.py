"""``telerobot policy demo``: a policy to try supervised autonomy with in a minute, on the
simulation, with nothing else installed (docs/policy-demo.md).

**The policy** is scripted, not learned: it reaches for random targets near where the
arm was when it started, one after the other (``ReachPolicy``). Each target is a joint
pose drawn within ``reach_rad`` of the start pose whose tool lies inside the arm's
workspace box (``GET /api/v1/safety``) and not below where the tool started (the table),
found with the arm's forward kinematics from its description (``GET /api/v1/robot/model``;
``ArmChain``: a few lines of numpy). It holds each target for a moment, then the next.
No torch, no LeRobot.

**It drives as a learned policy does**, through the client LeRobot's robot plugin uses
(``TelerobotArm`` with ``policy=True``, ``telerobot.client.lerobot.arm``): it joins the
priority channel with a *policy token* and HELLO's POLICY flag, takes control and waits,
PAUSED, until a person lets it drive. Every action passes the server's checks, and the
supervision: a person pauses it (P on the page), takes over (T, the dead-man, a master's
clutch, ``POST /api/v1/lease``), corrects, and hands back (H, letting go,
``DELETE /api/v1/lease``).

**What the command does for you** (``run``): without ``--token`` it issues itself a
policy token with the operator token (``TELEROBOT_OPERATOR_TOKEN`` or the one
``telerobot serve`` keeps on this machine) and revokes it when it stops; unless told to
``wait``, it then lets itself drive once, as the person who started it
(``POST /api/v1/autonomy/resume``). After that only a person on the page (or over REST)
pauses, takes over, hands back or resumes it. It says what happens, once per change:
each target reached, the supervision's mode and why, and the first refusal of each kind
while a mode lasts (not each refused action). Ctrl+C stops it: control is given back and
the token it issued revoked.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import re
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np

from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm
from telerobot.client.lerobot.parts import ArmPart
from telerobot.client.master.link import Reply
from telerobot.drivers.base import FloatArray
from telerobot.protocol import messages as m

POLICY_TOKEN_PREFIX = "tpol_"  # every policy token starts so (the server's PREFIX)
NAME = "policy demo"  # what the page shows as the policy's name
RATE_HZ = 30.0  # actions a second, as lerobot-rollout sends them
REACH_RAD = 0.35  # a target's joints at most this far from the start pose (20°)
SPEED_RAD_S = 0.45  # per joint: a gentle pace to watch (the server allows 1 rad/s)
REACHED_RAD = 0.02  # every joint this near its target: reached
HOLD_S = 0.6  # at a target before the next
WORKSPACE_MARGIN_M = 0.03  # a target's tool this far inside the workspace box
BELOW_START_M = 0.02  # nor lower than this under where the tool started (the table)
DRAWS = 500  # tries at a target that passes those checks before holding the start pose
TIMEOUT_SLACK_S = 6.0  # a target not reached within 3 × its way at the speed + this: the next
HTTP_TIMEOUT_S = 10.0
QUIET_LOGGERS = ("telerobot.client.master.joints", "telerobot.client.lerobot")
SO_FAR = re.compile(r" \(\d+ (?:refused )?so far\)")  # the server's running count in a refusal
NUMBER = re.compile(r"\d+(?:\.\d+)?")  # refusals that differ only in numbers are one kind

Say = Callable[[str], None]


class DemoError(Exception):
    """Why the demo cannot run or stopped, in one line."""


# ------------------------------------------------------------ the operator's REST calls
def _base(url: str) -> str:
    return url if url.endswith("/") else url + "/"


def _detail(r: httpx.Response) -> str:
    try:
        return str(r.json().get("detail") or r.reason_phrase)
    except (ValueError, AttributeError):
        return r.reason_phrase


def _operator_call(url: str, operator_token: str, method: str, path: str, **kw: Any) -> Any:
    headers = {"Authorization": f"Bearer {operator_token}", "X-Telerobot-Client": "telerobot"}
    try:
        r = httpx.request(method, _base(url) + "api/v1/" + path, headers=headers,
                          timeout=HTTP_TIMEOUT_S, verify=False, **kw)  # fmt: skip
    except httpx.HTTPError as exc:
        raise DemoError(f"cannot reach {_base(url)}: {exc}") from None
    if r.is_error:
        raise DemoError(f"{method} /api/v1/{path}: {_detail(r)}")
    return r.json()


def issue_policy_token(url: str, operator_token: str, name: str = NAME) -> tuple[str, str]:
    """A new policy token, issued with the operator token: its id and its secret."""
    body = _operator_call(url, operator_token, "POST", "policy-tokens", json={"name": name})
    return str(body["id"]), str(body["token"])


def revoke_policy_token(url: str, operator_token: str, ident: str) -> None:
    _operator_call(url, operator_token, "DELETE", f"policy-tokens/{ident}")


def let_it_drive(url: str, operator_token: str) -> None:
    """A person lets the policy drive (``POST /api/v1/autonomy/resume``)."""
    _operator_call(url, operator_token, "POST", "autonomy/resume")


def server_arms(url: str) -> list[str]:
    """The server's arms' names (``GET /api/v1/robot/arms``); a one-line DemoError when
    no server answers there."""
    try:
        r = httpx.get(_base(url) + "api/v1/robot/arms", timeout=HTTP_TIMEOUT_S, verify=False)
        r.raise_for_status()
        return [str(a["name"]) for a in r.json()]
    except httpx.ConnectError:
        raise DemoError(
            f"no Telerobot server at {_base(url)}: start one (telerobot serve) or name it"
            " with --url (or TELEROBOT_URL)"
        ) from None
    except (httpx.HTTPError, ValueError, KeyError, TypeError) as exc:
        raise DemoError(f"{_base(url)} is not a Telerobot server that answers: {exc}") from None


def _public(url: str, path: str, params: dict[str, str]) -> Any:
    try:
        r = httpx.get(_base(url) + "api/v1/" + path, params=params, timeout=HTTP_TIMEOUT_S,
                      verify=False)  # fmt: skip
        r.raise_for_status()
        return r.json()
    except (httpx.HTTPError, ValueError) as exc:
        raise DemoError(f"cannot read {path} from {_base(url)}: {exc}") from None


# ------------------------------------------------------------ the policy
def _rotation(axis: FloatArray, q: float) -> FloatArray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + math.sin(q) * k + (1.0 - math.cos(q)) * (k @ k)
    return t


@dataclass(frozen=True)
class ArmChain:
    """An arm's forward kinematics from its description (``GET /api/v1/robot/model``):
    each joint's origin in its parent's frame, then its rotation about its axis; the
    flange and the tool after them. Where the tool is in the arm's base frame."""

    origins: tuple[FloatArray, ...]
    axes: tuple[FloatArray, ...]
    parents: tuple[int, ...]
    flange_parent: int
    flange: FloatArray  # the flange in its parent joint's frame, then the tool

    @classmethod
    def from_described(cls, model: dict[str, Any]) -> ArmChain:
        joints = model["joints"]
        flange = model["flange"]
        tip = np.asarray(flange["origin"], float) @ np.asarray(model["tool"], float)
        return cls(
            tuple(np.asarray(j["origin"], float) for j in joints),
            tuple(np.asarray(j["axis"], float) for j in joints),
            tuple(int(j["parent"]) for j in joints),
            int(flange["parent"]),
            tip,
        )

    def tool_position(self, q: FloatArray | Sequence[float]) -> FloatArray:
        """The tool's position (m, the arm's base frame) at joints ``q`` (rad)."""
        frames: list[FloatArray] = []
        for i, origin in enumerate(self.origins):
            parent = self.parents[i]
            above: FloatArray = np.eye(4) if parent < 0 else frames[parent]
            frames.append(np.matmul(np.matmul(above, origin), _rotation(self.axes[i], float(q[i]))))
        tool: FloatArray = np.matmul(frames[self.flange_parent], self.flange)[:3, 3]
        return tool


@dataclass
class ReachTargets:
    """One arm's targets: joint poses (rad) within ``reach_rad`` of ``start`` whose tool
    is inside the workspace box (less a margin) and not below where it started."""

    chain: ArmChain
    start: FloatArray
    limits: FloatArray  # (joints, 2), rad
    workspace: tuple[FloatArray, FloatArray]
    rng: np.random.Generator
    reach_rad: float = REACH_RAD
    grippers: tuple[int, ...] = ()  # joints that open and close (any value in range)

    def __post_init__(self) -> None:
        self.start_tool = self.chain.tool_position(self.start)

    def fits(self, q: FloatArray) -> bool:
        p = self.chain.tool_position(q)
        lo, hi = self.workspace
        inside = bool(np.all(p >= lo + WORKSPACE_MARGIN_M) and np.all(p <= hi - WORKSPACE_MARGIN_M))
        return inside and p[2] >= self.start_tool[2] - BELOW_START_M

    def draw(self) -> FloatArray:
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        for _ in range(DRAWS):
            q = self.start + self.rng.uniform(-self.reach_rad, self.reach_rad, len(self.start))
            for g in self.grippers:
                q[g] = self.rng.uniform(lo[g], hi[g])
            q = np.clip(q, lo, hi)
            if self.fits(q):
                return q
        return self.start.copy()


class ReachPolicy:
    """The policy: an observation (each moving arm's joints, rad) in, the targets out;
    a target held until every arm is at its own, then ``HOLD_S`` more, then the next."""

    def __init__(self, arms: dict[str, ReachTargets]) -> None:
        self.arms = arms
        self.targets = {name: t.draw() for name, t in arms.items()}
        self.number = 1  # of the current target
        self.reached_at: float | None = None

    def reached(self, joints: dict[str, FloatArray]) -> bool:
        return all(
            float(np.abs(joints[name] - target).max()) < REACHED_RAD
            for name, target in self.targets.items()
        )

    def next(self) -> None:
        self.targets = {name: t.draw() for name, t in self.arms.items()}
        self.number += 1
        self.reached_at = None

    def tool_targets(self) -> dict[str, FloatArray]:
        return {n: self.arms[n].chain.tool_position(q) for n, q in self.targets.items()}


# ------------------------------------------------------------ what it says
@dataclass
class Narrator:
    """Says each change once: the supervision's mode (from the server's AUTONOMY events)
    and, while a mode lasts, each kind of refusal the first time (a paused policy has
    every action refused alike; the count in the server's words is left out)."""

    say: Say
    mode: str = ""
    refusals_said: dict[str, str] = field(default_factory=dict)  # kind → as said
    refused: int = 0  # actions refused in all (ERROR replies)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()

    def on_reply(self, reply: Reply) -> None:
        if reply.name == "EVENT" and int(reply.fields.get("kind", -1)) == m.EventKind.AUTONOMY:
            with contextlib.suppress(ValueError, TypeError, KeyError):
                said = json.loads(reply.text)
                self.mode_is(str(said["mode"]), str(said.get("cause") or ""))
        elif reply.name == "ERROR":
            why = SO_FAR.sub("", reply.text)
            kind = NUMBER.sub("#", why)
            with self._lock:
                self.refused += 1
                new = kind not in self.refusals_said
                self.refusals_said[kind] = why
            if new:
                self.say(f"refused: {why}")

    def mode_is(self, mode: str, cause: str) -> None:
        with self._lock:
            if mode == self.mode:
                return
            self.mode = mode
            self.refusals_said.clear()
        self.say(describe_mode(mode, cause))


def describe_mode(mode: str, cause: str) -> str:
    why = f" ({cause})" if cause else ""
    match mode:
        case "autonomous":
            return f"AUTONOMOUS{why}: the policy drives"
        case "paused":
            return (
                f"PAUSED{why}: it holds still until a person lets it drive (P on the page,"
                " or POST /api/v1/autonomy/resume)"
            )
        case "correcting":
            return (
                f"CORRECTING{why}: a person drives; the policy drives again when they hand"
                " back (H on the page, or DELETE /api/v1/lease)"
            )
        case _:
            return f"{mode.upper()}{why}"


# ------------------------------------------------------------ running it
@dataclass
class DemoOptions:
    url: str
    policy_token: str | None = field(default=None, repr=False)  # None: issue one
    operator_token: str | None = field(default=None, repr=False)  # to issue one, to say go
    arms: list[str] = field(default_factory=list)  # the arms it moves (none named: all)
    wait: bool = False  # True: a person lets it drive (P on the page), not the command
    seed: int | None = None
    reach_rad: float = REACH_RAD
    speed_rad_s: float = SPEED_RAD_S
    targets: int = 0  # stop after this many reached (0: until Ctrl+C)


def _fmt(p: FloatArray) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in p) + ") m"


def _chosen_arms(url: str, wanted: list[str]) -> list[str]:
    names = server_arms(url)
    unknown = [a for a in wanted if a not in names]
    if unknown:
        raise DemoError(
            f"the server has no arm {unknown[0]!r}: it drives {', '.join(names)} (--arm NAME)"
        )
    return list(dict.fromkeys(wanted)) or names


class PolicyDemo:
    """The demo's session: connected by ``start``, run by ``step`` at ``RATE_HZ``
    (``run_demo`` does both and stops it), ended by ``stop``."""

    def __init__(self, options: DemoOptions, say: Say = print) -> None:
        self.options = options
        self.say = say
        self.narrator = Narrator(say)
        self.robot: TelerobotArm | None = None
        self.policy: ReachPolicy | None = None
        self.issued: str | None = None  # the id of the policy token it issued itself
        self.moving: list[str] = []
        self.reached = 0
        self._driving_s = 0.0  # time AUTONOMOUS toward the current target
        self._last_step: float | None = None
        # The arms it does not move are held where they were when it last took control
        # (not at each new reading: a real arm's noise would be chased).
        self._held: dict[str, FloatArray] = {}

    # ---------------------------------------------------------------- start, stop
    def start(self) -> None:
        o = self.options
        self.moving = _chosen_arms(o.url, o.arms)
        token = o.policy_token
        if token is None:
            if not o.operator_token:
                raise DemoError(
                    "no operator token to issue a policy token with: pass --token"
                    " POLICY_TOKEN (telerobot policy-token new NAME), set"
                    " TELEROBOT_OPERATOR_TOKEN, or run it where `telerobot serve` keeps it"
                )
            self.issued, token = issue_policy_token(o.url, o.operator_token)
            self.say(f"issued itself a policy token ({self.issued}, revoked when it stops)")
        elif not token.startswith(POLICY_TOKEN_PREFIX):
            raise DemoError(
                f"--token takes a policy token (they start with {POLICY_TOKEN_PREFIX}:"
                " telerobot policy-token new NAME), not the operator token; leave it out"
                " and the demo issues itself one"
            )
        # The client says refusals and approaches in its own log lines (a LeRobot user's
        # only view of them); here the narrator says each change once, in its words.
        for name in QUIET_LOGGERS:
            logging.getLogger(name).setLevel(logging.ERROR)
        robot = TelerobotArm(
            ArmOptions(
                url=o.url,
                token=token,
                name=NAME,
                cameras=False,
                policy=True,
                max_speed_rad_s=o.speed_rad_s,
            )
        )
        try:
            robot.connect()
        except (ConnectionError, PermissionError) as exc:
            raise DemoError(str(exc)) from None
        self.robot = robot
        link = robot.link
        assert link is not None
        mirrors_reply = link.on_reply

        def on_reply(reply: Reply) -> None:
            self.narrator.on_reply(reply)
            if mirrors_reply is not None:
                mirrors_reply(reply)

        link.on_reply = on_reply
        self.policy = self._make_policy(robot.parts)
        where = ", ".join(self.moving)
        self.say(
            f"joined {_base(o.url)} as the policy {NAME!r} and holds control; moving"
            f" {where}; first target at {self._tool_targets()}"
        )
        said = _public(o.url, "autonomy", {})
        self.narrator.mode_is(str(said.get("mode", link.autonomy)), str(said.get("cause") or ""))
        if o.wait or not o.operator_token:
            self.say("waiting for a person to let it drive: P on the page")
        else:
            let_it_drive(o.url, o.operator_token)

    def _make_policy(self, parts: list[ArmPart]) -> ReachPolicy:
        o = self.options
        rng = np.random.default_rng(o.seed)
        arms: dict[str, ReachTargets] = {}
        for part in parts:
            if part.name not in self.moving:
                continue
            query = part.query
            model = _public(o.url, "robot/model", query)
            safety = _public(o.url, "safety", query)
            box = (
                np.array(safety["workspace_min"], float),
                np.array(safety["workspace_max"], float),
            )
            here = part.newest_joints()
            assert here is not None  # connect waited for every arm's STATE
            arms[part.name] = ReachTargets(
                ArmChain.from_described(model),
                here,
                np.array(part.units.limits, float),
                box,
                rng,
                reach_rad=o.reach_rad,
                grippers=tuple(i for i, n in enumerate(part.units.names) if n == "gripper"),
            )
        return ReachPolicy(arms)

    def _tool_targets(self) -> str:
        assert self.policy is not None
        tools = self.policy.tool_targets()
        if len(tools) == 1:
            return _fmt(next(iter(tools.values())))
        return ", ".join(f"{n} {_fmt(p)}" for n, p in tools.items())

    def stop(self) -> None:
        """Control given back, the token it issued revoked (whatever of it can be)."""
        robot, self.robot = self.robot, None
        if robot is not None:
            with contextlib.suppress(Exception):  # (the server may be gone)
                robot.disconnect(settle=False)
        o = self.options
        if self.issued is not None and o.operator_token:
            with contextlib.suppress(DemoError):
                revoke_policy_token(o.url, o.operator_token, self.issued)
            self.issued = None

    # ---------------------------------------------------------------- one step
    def step(self) -> None:
        """One action: the policy's targets for the arms it moves, the others held where
        they are. Says a target reached, or given up."""
        robot, policy = self.robot, self.policy
        assert robot is not None and policy is not None
        now = time.monotonic()
        dt = 0.0 if self._last_step is None else now - self._last_step
        self._last_step = now
        joints: dict[str, FloatArray] = {}
        for part in robot.parts:
            q = part.newest_joints()
            assert q is not None
            joints[part.name] = q
        if self.narrator.mode == "autonomous":
            self._driving_s += dt
        if policy.reached(joints):
            if policy.reached_at is None:
                policy.reached_at = now
                self.reached += 1
                self.say(
                    f"target {policy.number} reached: {self._tool_targets()}"
                    f" ({self._driving_s:.1f} s driving)"
                )
            elif now - policy.reached_at >= HOLD_S:
                self._next_target()
        elif self._driving_s > self._allowed_s(joints):
            self.say(
                f"target {policy.number} not reached in {self._driving_s:.0f} s driving"
                f" ({self._last_refusal()}): the next one"
            )
            self._next_target()
        if not robot.has_control:
            self._held.clear()
            return  # a person drives (or nobody): nothing to send
        if not self._held:
            self._held = {n: q for n, q in joints.items() if n not in policy.targets}
        action: dict[str, float] = {}
        for part in robot.parts:
            q = policy.targets.get(part.name, self._held.get(part.name, joints[part.name]))
            values = part.units.to_lerobot(q)
            action |= dict(zip(part.keys, map(float, values), strict=True))
        try:
            robot.send(action)
        except ConnectionError as exc:
            raise DemoError(str(exc)) from None

    def _allowed_s(self, joints: dict[str, FloatArray]) -> float:
        assert self.policy is not None
        way = max(float(np.abs(joints[n] - t).max()) for n, t in self.policy.targets.items())
        return 3.0 * way / self.options.speed_rad_s + TIMEOUT_SLACK_S

    def _last_refusal(self) -> str:
        said = list(self.narrator.refusals_said.values())
        return f"refused: {said[-1]}" if said else "too slow"

    def _next_target(self) -> None:
        assert self.policy is not None
        self.policy.next()
        self._driving_s = 0.0
        self.say(f"target {self.policy.number}: {self._tool_targets()}")

    def check_link(self) -> None:
        robot = self.robot
        link = robot.link if robot is not None else None
        if link is None or link.closed_reason:
            why = link.closed_reason if link is not None else "not connected"
            raise DemoError(f"the server closed the priority channel: {why}")


def run_demo(options: DemoOptions, say: Say = print) -> int:
    """Connect, drive until Ctrl+C (or ``options.targets`` reached), stop. A DemoError
    is the caller's to say (one line); Ctrl+C is the way to stop."""
    demo = PolicyDemo(options, say)
    try:
        demo.start()
        period = 1.0 / RATE_HZ
        next_at = time.monotonic()
        while not options.targets or demo.reached < options.targets:
            demo.check_link()
            demo.step()
            next_at += period
            time.sleep(max(0.0, next_at - time.monotonic()))
            next_at = max(next_at, time.monotonic() - period)
    finally:
        with _uninterrupted():
            demo.stop()
    return 0


@contextlib.contextmanager
def _uninterrupted() -> Iterator[None]:
    """A second Ctrl+C while stopping waits: control given back and the token revoked
    either way (in the main thread, where signals are handled; elsewhere as it is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in held}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


__all__ = [
    "ArmChain",
    "DemoError",
    "DemoOptions",
    "PolicyDemo",
    "ReachPolicy",
    "ReachTargets",
    "issue_policy_token",
    "run_demo",
]
