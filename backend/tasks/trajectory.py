"""A taught motion as a tool trajectory: from a recording's ``/robot/state`` (tool
position and rotation, ``t``) and ``/force`` samples of an episode or a time segment
to a time-parameterised tool path with the force that was felt along it.

Pure: no I/O but ``from_recording``, which reads a recording as far as it is valid
(``telerobot.server.recording.salvage``: a torn file or one cut short gives what it holds;
docs/recording.md). Times are the server's monotonic ``t`` of the recording, shifted
so the trajectory starts at 0.

**Bounded.** A recording can last hours and anyone may ask for a preview, so the
messages are taken as a stream and only the task's span is kept, compactly: its robot
states (at most ``MAX_STATES``, in time order; one out of order is skipped) and its
forces already turned to the base frame and summed per resampling interval (one
running sum per interval, never the samples). Reading stops once the span is over,
a span longer than ``MAX_SAMPLES`` intervals is refused as soon as it is seen, and
``deadline`` (a ``time.monotonic()`` instant) ends a read that takes too long.

**The arm it was taught on.** A recording says which arm model made it (its first
message, ``/settings``: ``robot_model``). A task repeats the recorded tool path, which
only that arm model can follow: asked for another model's (``robot_model``), the read
stops at that message with ``AnotherArm`` (422). A recording without ``/settings``
(a foreign file) is read as it is.

**Two arms or more.** A multi-arm recording (its ``/settings`` name the arms) has each
arm's states and forces on ``/arms/<name>/state`` and ``/arms/<name>/force``;
``read_paths`` gives each arm's path by name (one arm's is named "arm"), all on one
time grid over the span every arm was recorded in. Asked for a server's arms
(``arm_models``: name → model), a recording with an arm the server has none of the name
for is refused at its ``/settings`` with ``OtherArms`` (422), one whose arm was another
model with ``AnotherArm``, naming the arm.

Forces are kept in the **base frame** (the recording has them in the sensor frame,
whose axes are the tool's: each is turned with the tool rotation recorded nearest to
it), averaged over each resampling interval so the sensor's noise does not become
the task's reference.
"""

from __future__ import annotations

import math
import time
from array import array
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, InvalidCommand
from telerobot.server.recording.arms import arm_channel, recorded_arms
from telerobot.server.recording.schemas import (
    ARM_STATE,
    FORCE,
    ROBOT_STATE,
    SETTINGS,
    SINGLE_ARM,
)

DEFAULT_DT_S = 0.02  # resampled every 20 ms (the state rate)
MAX_SAMPLES = 30_000  # 10 minutes at 50 Hz: a task is a taught motion, not a shift's work
MAX_STATES = 2 * MAX_SAMPLES  # robot states kept from a span (100 Hz over the longest task)
# Forces seen before the span's first state (its first interval takes those within
# dt/2 before it): a recording with forces and no states keeps no more than these.
MAX_EARLY_FORCES = 5_000
LOOKBACK = 256  # messages looked back at when an episode's start event comes
READ_LIMIT_S = 30.0  # reading a task's source takes at most this long
CHECK_EVERY = 256  # messages between two looks at the deadline
TOPICS = (SETTINGS, ROBOT_STATE, FORCE, "/episodes")  # and each arm's (a multi-arm recording's)
MAX_ARMS = 16  # arms read from one recording (a server drives at most 8)


def read_topic(topic: str) -> bool:
    """Whether a task's read takes this channel's messages."""
    return topic in TOPICS or arm_channel(topic) is not None


class AnotherArm(InvalidCommand):
    """The recording was made with another arm model than the one asked for."""

    code = "another_arm"


class OtherArms(InvalidCommand):
    """The recording's arms are not this server's (by name): one arm's on a multi-arm
    server, two arms' on a one-arm server, or arms it has no arm of the name for."""

    code = "other_arms"


def another_arm_text(source: str, recorded: str, wanted: str) -> str:
    return (
        f"{source} was recorded with another arm model ({recorded}) than this server's "
        f"({wanted}): a task repeats the recorded tool path, which only the arm model that "
        "made it can follow"
    )


@dataclass(frozen=True)
class StateSample:
    """One ``/robot/state``: ``t`` (s), tool ``position`` (3,) m and ``rotation`` (3, 3)."""

    t: float
    position: FloatArray
    rotation: FloatArray


@dataclass(frozen=True)
class ForceReading:
    """One ``/force`` sample: ``t`` (s) and ``values`` (6,) in the sensor frame."""

    t: float
    values: FloatArray


@dataclass(frozen=True)
class Trajectory:
    """Tool poses and recorded contact forces (base frame) every ``dt`` seconds from 0."""

    dt: float
    positions: FloatArray  # (N, 3) m
    rotations: FloatArray  # (N, 3, 3)
    forces: FloatArray  # (N, 3) N, base frame
    source: str = ""  # where it came from (file, episode, segment), for people

    @property
    def duration(self) -> float:
        return self.dt * (len(self.positions) - 1)

    def __len__(self) -> int:
        return len(self.positions)

    # ------------------------------------------------------------ building
    @classmethod
    def from_samples(
        cls,
        states: Sequence[StateSample],
        forces: Sequence[ForceReading],
        *,
        dt: float = DEFAULT_DT_S,
        segment: tuple[float, float] | None = None,
        source: str = "",
    ) -> Trajectory:
        """Resample ``states`` (any order, any rate) every ``dt`` seconds within
        ``segment`` (t0, t1 in the samples' own clock; default: all of them), and the
        forces felt around each instant."""
        if not (math.isfinite(dt) and 0.001 <= dt <= 1.0):
            raise InvalidCommand(f"dt must be 1 ms–1 s, got {dt!r}")
        ordered = sorted(states, key=lambda s: s.t)
        if segment is not None:
            t0, t1 = segment
            if not (math.isfinite(t0) and math.isfinite(t1) and t0 < t1):
                raise InvalidCommand(f"a segment is [t0, t1] with t0 < t1, got {segment!r}")
            ordered = [s for s in ordered if t0 <= s.t <= t1]
        if len(ordered) < 2:
            raise InvalidCommand("a task needs at least two robot states in its time span")
        ts = np.array([s.t for s in ordered])
        P = np.array([np.asarray(s.position, dtype=float) for s in ordered])
        R = np.array([np.asarray(s.rotation, dtype=float).reshape(3, 3) for s in ordered])
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(R))):
            raise InvalidCommand("the recording has a robot state that is not finite")
        grid, positions, rotations = _resampled(ts, P, R, dt)
        base_forces = _forces_in_base(forces, ts, R)
        return cls(dt, positions, rotations, _binned(base_forces, grid, dt), source)

    @classmethod
    def from_messages(
        cls,
        messages: Iterable[tuple[str, Mapping[str, Any]]],
        *,
        episode: int | None = None,
        segment: tuple[float, float] | None = None,
        dt: float = DEFAULT_DT_S,
        source: str = "",
        deadline: float | None = None,
        robot_model: str | None = None,
    ) -> Trajectory:
        """From a recording's messages in log order, as ``(topic, payload)``:
        ``/settings``, ``/robot/state``, ``/force`` and ``/episodes`` (docs/recording.md).
        ``episode`` keeps the span between that episode's start and end events;
        ``segment`` is a span [t0, t1] of the recording's ``t``, relative to its first
        state (or to the episode's start). Bounded in memory and time (the module's
        docstring). ``robot_model``: the arm model it must have been recorded with
        (``AnotherArm`` if ``/settings`` names another; None: any)."""
        paths = read_paths(
            messages,
            episode=episode,
            segment=segment,
            dt=dt,
            source=source,
            deadline=deadline,
            arm_models=None if robot_model is None else {SINGLE_ARM: robot_model},
        )
        return _the_only(paths, source)

    @classmethod
    def from_recording(
        cls,
        path: Path,
        *,
        episode: int | None = None,
        segment: tuple[float, float] | None = None,
        dt: float = DEFAULT_DT_S,
        time_limit_s: float = READ_LIMIT_S,
        robot_model: str | None = None,
    ) -> Trajectory:
        """Read ``path`` as far as it is valid (a torn file gives what it holds; one that
        is not an MCAP is refused: ``NotARecording``); ``robot_model`` as in
        ``from_messages`` (the file's name is what the refusal names)."""
        paths = read_recording(
            path,
            episode=episode,
            segment=segment,
            dt=dt,
            time_limit_s=time_limit_s,
            arm_models=None if robot_model is None else {SINGLE_ARM: robot_model},
        )
        return _the_only(paths, next(iter(paths.values())).source)

    # ------------------------------------------------------------ sampling
    def at(self, s: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, rotation and recorded force (base frame) at trajectory time ``s``
        (clamped to [0, duration]); linear between samples, rotations along the arc."""
        x = min(max(s / self.dt, 0.0), len(self) - 1.0)
        i = min(int(x), len(self) - 2) if len(self) > 1 else 0
        a = x - i
        if len(self) == 1:
            return self.positions[0], self.rotations[0], self.forces[0]
        p = self.positions[i] + a * (self.positions[i + 1] - self.positions[i])
        f = self.forces[i] + a * (self.forces[i + 1] - self.forces[i])
        return p, interpolate_rotation(self.rotations[i], self.rotations[i + 1], a), f

    def peak_force_near(self, s: float, window: float) -> float:
        """The strongest recorded contact force (magnitude, N) within ``window`` seconds
        of trajectory time ``s``: a repeat runs a period or two behind or ahead of the
        recording, so a force edge is judged against its neighbourhood."""
        lo = max(math.floor((s - window) / self.dt), 0)
        hi = min(math.ceil((s + window) / self.dt), len(self) - 1)
        if hi < lo:
            lo = hi = min(max(round(s / self.dt), 0), len(self) - 1)
        return float(np.max(np.linalg.norm(self.forces[lo : hi + 1], axis=1)))

    def lag_behind(
        self, max_speed_m_s: float, max_angular_speed_rad_s: float, speed: float = 1.0
    ) -> tuple[float, float, float]:
        """How far an arm held to these speeds falls behind the path, repeated at
        ``speed`` of the taught pace, at worst: (m, rad, and the path time s where
        it is furthest behind). Zero for a path taught within the limits; a jump in
        the recording (a pose far from the one before it) shows as its length."""
        if len(self) < 2:
            return 0.0, 0.0, 0.0
        step_m = np.linalg.norm(np.diff(self.positions, axis=0), axis=1)
        relative = np.einsum("nji,njk->nik", self.rotations[:-1], self.rotations[1:])
        cos = (np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0
        step_rad = np.arccos(np.clip(cos, -1.0, 1.0))
        # Each interval lasts dt / speed when repeated; the arm covers at most this.
        lag_m = _lag(step_m - max_speed_m_s * self.dt / speed)
        lag_rad = _lag(step_rad - max_angular_speed_rad_s * self.dt / speed)
        at = int(np.argmax(lag_m if lag_m.max() > 0 else lag_rad))  # where it is furthest
        return float(lag_m.max()), float(lag_rad.max()), at * self.dt

    def polyline(self, max_points: int = 400) -> FloatArray:
        """The path's positions, thinned to at most ``max_points`` (ends kept)."""
        n = len(self)
        if n <= max_points:
            return self.positions.copy()
        idx = np.unique(np.linspace(0, n - 1, max_points).round().astype(int))
        result: FloatArray = self.positions[idx]
        return result


def _the_only(paths: dict[str, Trajectory], source: str) -> Trajectory:
    if len(paths) != 1:
        raise OtherArms(
            f"{source or 'the recording'} was recorded with {len(paths)} arms "
            f"({', '.join(paths)}): each arm's path is read with read_paths"
        )
    return next(iter(paths.values()))


def read_paths(
    messages: Iterable[tuple[str, Mapping[str, Any]]],
    *,
    episode: int | None = None,
    segment: tuple[float, float] | None = None,
    dt: float = DEFAULT_DT_S,
    source: str = "",
    deadline: float | None = None,
    arm_models: Mapping[str, str] | None = None,
) -> dict[str, Trajectory]:
    """Each recorded arm's path, by arm name in the recording's order (one arm's named
    "arm"), from a recording's messages in log order, as ``(topic, payload)``:
    ``/settings``, ``/robot/state`` and ``/force`` (or each arm's ``/arms/<name>/state``
    and ``/arms/<name>/force``) and ``/episodes`` (docs/recording.md). ``episode`` keeps
    the span between that episode's start and end events; ``segment`` is a span [t0, t1]
    of the recording's ``t``, relative to its first state (or to the episode's start).
    Several arms' paths are on one grid, over the span all of them were recorded in.
    Bounded in memory and time (the module's docstring). ``arm_models``: the arms (name →
    model) the recording must have been made with, each of its arms by name
    (``OtherArms``, ``AnotherArm`` if not; None: any)."""
    span = _Span(episode, segment, dt, arm_models, source)
    for n, (topic, m) in enumerate(messages):
        if span.add(topic, m):
            break
        if deadline is not None and n % CHECK_EVERY == 0 and time.monotonic() > deadline:
            raise InvalidCommand(
                "reading the recording took too long (its span is not over after "
                f"{n} messages): choose an earlier episode or a shorter recording"
            )
    return span.trajectories(source)


def read_recording(
    path: Path,
    *,
    episode: int | None = None,
    segment: tuple[float, float] | None = None,
    dt: float = DEFAULT_DT_S,
    time_limit_s: float = READ_LIMIT_S,
    arm_models: Mapping[str, str] | None = None,
) -> dict[str, Trajectory]:
    """``read_paths`` of ``path``, read as far as it is valid (a torn file gives what it
    holds; one that is not an MCAP is refused: ``NotARecording``); the file's name is
    what a refusal names."""
    from telerobot.server.recording.salvage import SalvageReader

    what = path.name + (f" episode {episode}" if episode is not None else "")
    if segment is not None:
        what += f" [{segment[0]:g}, {segment[1]:g}] s"
    reader = SalvageReader(path)
    messages = ((topic, payload) for topic, _, payload in reader.messages(keep=read_topic))
    deadline = time.monotonic() + time_limit_s
    try:
        return read_paths(
            messages,
            episode=episode,
            segment=segment,
            dt=dt,
            source=what,
            deadline=deadline,
            arm_models=arm_models,
        )
    except InvalidCommand as exc:
        if reader.stopped and not isinstance(exc, AnotherArm | OtherArms):
            # say why so little was read
            raise InvalidCommand(f"{exc} (the file is cut short: {reader.stopped})") from exc
        raise


def _lag(excess: FloatArray) -> FloatArray:
    """How far behind a follower is after each interval, when each puts it ``excess``
    further behind (negative: it catches up) and it is never ahead: L = max(0, L + x),
    all at once as the running sum less its lowest point so far (from 0)."""
    total = np.cumsum(excess)
    lowest = np.minimum.accumulate(np.minimum(total, 0.0))
    result: FloatArray = total - lowest
    return result


def interpolate_rotation(R0: FloatArray, R1: FloatArray, a: float) -> FloatArray:
    """The rotation ``a`` of the way from ``R0`` to ``R1`` along the shortest arc."""
    if a <= 0.0:
        return R0.copy()
    if a >= 1.0:
        return R1.copy()
    result: FloatArray = R0 @ pin.exp3(a * pin.log3(R0.T @ R1))
    return result


def _forces_in_base(
    forces: Sequence[ForceReading], ts: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Each force's time and its (x, y, z) turned to the base frame with the tool
    rotation recorded nearest before it (the sensor's axes are the tool's)."""
    if not forces:
        return np.zeros(0), np.zeros((0, 3))
    ft = np.array([f.t for f in forces])
    F = np.array([np.asarray(f.values, dtype=float)[:3] for f in forces])
    keep = np.all(np.isfinite(F), axis=1) & np.isfinite(ft)
    ft, F = ft[keep], F[keep]
    k = np.clip(np.searchsorted(ts, ft, side="right") - 1, 0, len(ts) - 1)
    base = np.einsum("nij,nj->ni", R[k], F)
    return ft, base


def _binned(timed: tuple[FloatArray, FloatArray], grid: FloatArray, dt: float) -> FloatArray:
    """The mean force within ±dt/2 of each grid time; where none was taken, the nearest
    earlier mean (or zero before the first)."""
    ft, F = timed
    out = np.zeros((len(grid), 3))
    if len(ft) == 0:
        return out
    order = np.argsort(ft)
    ft, F = ft[order], F[order]
    lo = np.searchsorted(ft, grid - dt / 2, side="left")
    hi = np.searchsorted(ft, grid + dt / 2, side="left")
    csum = np.vstack([np.zeros(3), np.cumsum(F, axis=0)])
    last = np.zeros(3)
    for i in range(len(grid)):
        count = int(hi[i] - lo[i])
        if count > 0:
            last = (csum[hi[i]] - csum[lo[i]]) / count
        out[i] = last
    return out


def _resampled(
    ts: FloatArray,
    P: FloatArray,
    R: FloatArray,
    dt: float,
    within: tuple[float, float] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The grid every ``dt`` from ``ts[0]`` to ``ts[-1]`` (``ts`` sorted), or over
    ``within`` (several arms' common span), with the positions and rotations
    interpolated at each."""
    start, stop = (float(ts[0]), float(ts[-1])) if within is None else within
    span = stop - start
    n = math.floor(span / dt + 1e-9) + 1
    if n > MAX_SAMPLES:
        raise InvalidCommand(
            f"the motion lasts {span:.0f} s: a task may last at most "
            f"{MAX_SAMPLES * dt:.0f} s; choose a segment"
        )
    grid: FloatArray = np.asarray(start + dt * np.arange(n), dtype=np.float64)
    positions = np.column_stack([np.interp(grid, ts, P[:, k]) for k in range(3)])
    rotations = np.empty((n, 3, 3))
    j = 0
    for i, t in enumerate(grid.tolist()):
        while j < len(ts) - 2 and ts[j + 1] <= t:
            j += 1
        span_j = ts[j + 1] - ts[j]
        a = 0.0 if span_j <= 0 else min(max((t - ts[j]) / span_j, 0.0), 1.0)
        rotations[i] = interpolate_rotation(R[j], R[j + 1], a)
    return grid, positions, rotations


class _ArmSpan:
    """One arm's states and forces within the span, kept compactly as they come."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.states = np.empty((1024, 13))  # t, position (3), rotation (9): kept, in order
        self.n = 0
        self.early: deque[tuple[float, float, float, float]] = deque(maxlen=MAX_EARLY_FORCES)
        self.rotation: tuple[float, ...] = ()  # of the last state kept (row-major)
        # Per resampling interval: the base-frame forces' sums and counts.
        self.fx, self.fy, self.fz = array("d"), array("d"), array("d")
        self.count = array("l")

    def state(self, t: float, m: Mapping[str, Any]) -> None:
        """Keep one state within the span."""
        if self.n and t <= self.states[self.n - 1, 0]:
            return  # out of time order (a crafted file): skipped
        p = [float(v) for v in m["position"]]
        r = [float(v) for v in m["rotation"]]
        if len(p) != 3 or len(r) != 9:
            raise ValueError("a position is 3 numbers and a rotation 9")
        if not all(math.isfinite(v) for v in (*p, *r)):
            raise InvalidCommand("the recording has a robot state that is not finite")
        if self.n and (t - self.states[0, 0]) / self.dt + 1e-9 >= MAX_SAMPLES:
            raise InvalidCommand(
                f"the motion lasts more than {MAX_SAMPLES * self.dt:.0f} s, the most a task "
                "may last: choose a segment"
            )
        if self.n >= MAX_STATES:
            raise InvalidCommand(
                f"the recording has more than {MAX_STATES} robot states in the task's span: "
                "choose a shorter segment"
            )
        if self.n == len(self.states):
            self.states = np.concatenate([self.states, np.empty_like(self.states)])
        self.states[self.n] = (t, *p, *r)
        self.n += 1
        self.rotation = tuple(r)
        if self.n == 1:
            for early in self.early:
                self._bin(*early)
            self.early.clear()

    def force(self, t: float, f: tuple[float, float, float]) -> None:
        if self.n == 0:
            self.early.append((t, *f))
        else:
            self._bin(t, *f)

    def _bin(self, t: float, fx: float, fy: float, fz: float) -> None:
        """Add the force (sensor frame) to its interval, turned to the base frame with
        the tool rotation recorded last (the sensor's axes are the tool's)."""
        i = math.floor((t - float(self.states[0, 0])) / self.dt + 0.5)
        if i < 0 or i >= MAX_SAMPLES:
            return
        while len(self.count) <= i:
            self.fx.append(0.0)
            self.fy.append(0.0)
            self.fz.append(0.0)
            self.count.append(0)
        r = self.rotation
        self.fx[i] += r[0] * fx + r[1] * fy + r[2] * fz
        self.fy[i] += r[3] * fx + r[4] * fy + r[5] * fz
        self.fz[i] += r[6] * fx + r[7] * fy + r[8] * fz
        self.count[i] += 1

    def kept(self, hi: float) -> FloatArray:
        kept = self.states[: self.n]
        result: FloatArray = kept[kept[:, 0] <= hi]
        return result

    def trajectory(
        self, kept: FloatArray, source: str, within: tuple[float, float] | None
    ) -> Trajectory:
        """Resampled every ``dt`` (over ``within``: several arms' common span), each
        point with the mean force of its interval (else the one before)."""
        ts = kept[:, 0].copy()
        P = kept[:, 1:4].copy()
        R = kept[:, 4:13].reshape(-1, 3, 3).copy()
        grid, positions, rotations = _resampled(ts, P, R, self.dt, within)
        # The force bins count from this arm's first state; the grid may start later.
        first = round((float(grid[0]) - float(self.states[0, 0])) / self.dt)
        forces = np.zeros((len(grid), 3))
        last = np.zeros(3)
        for i in range(len(grid)):
            k = i + first
            if 0 <= k < len(self.count) and self.count[k] > 0:
                c = self.count[k]
                last = np.array([self.fx[k] / c, self.fy[k] / c, self.fz[k] / c])
            forces[i] = last
        return Trajectory(self.dt, positions, rotations, forces, source)


class _Span:
    """The task's span of a stream of recording messages, kept compactly as it comes
    (``read_paths``): each arm's states and forces (one arm's on ``/robot/state`` and
    ``/force``, named "arm"; a multi-arm recording's on ``/arms/<name>/…``). ``add``
    says when nothing later can be in the span."""

    SLACK_S = 0.5  # read this far past the span's end: threads log a little out of order

    def __init__(
        self,
        episode: int | None,
        segment: tuple[float, float] | None,
        dt: float,
        arm_models: Mapping[str, str] | None = None,
        source: str = "",
    ) -> None:
        if not (math.isfinite(dt) and 0.001 <= dt <= 1.0):
            raise InvalidCommand(f"dt must be 1 ms–1 s, got {dt!r}")
        if segment is not None and not (
            math.isfinite(segment[0]) and math.isfinite(segment[1]) and segment[0] < segment[1]
        ):
            raise InvalidCommand(f"a segment is [t0, t1] with t0 < t1, got {segment!r}")
        self.episode, self.segment, self.dt = episode, segment, dt
        self.arm_models, self.source = arm_models, source
        # The span [lo, hi] in the recording's t: lo is None until it is known (an
        # episode's start event not seen yet).
        self.lo: float | None = -math.inf if episode is None and segment is None else None
        self.hi = math.inf
        self.marks = 0  # the episode's start/end events seen
        self.any_state = False
        self.arms: dict[str, _ArmSpan] = {}  # by name, in the order recorded
        self.named: list[str] = []  # the arms /settings names, in order ([] if none seen)
        # Until an episode's start event, the last few messages: one logged just before
        # the event (at its very instant, or by another thread) may still be in the span.
        self.recent: deque[tuple[str, Mapping[str, Any]]] = deque(maxlen=LOOKBACK)

    # ------------------------------------------------------------ taking messages
    def add(self, topic: str, m: Mapping[str, Any]) -> bool:
        """Take one message; True once the span is over (nothing later belongs to it)."""
        try:
            arm = arm_channel(topic)
            if arm is not None:
                if arm[1] == ARM_STATE:
                    return self._state(topic, arm[0], m)
                return self._force(topic, arm[0], m)
            if topic == "/episodes":
                self._episode(m)
            if topic == SETTINGS:
                self._settings(m)
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, InvalidCommand):
                raise
            raise InvalidCommand(
                f"the recording has a {topic} message that is not as docs/recording.md "
                f"says ({type(exc).__name__}: {str(exc)[:80]})"
            ) from None
        return False

    def _settings(self, m: Mapping[str, Any]) -> None:
        if not isinstance(m, Mapping):
            return
        recorded = recorded_arms(m)
        self.named = [arm.name for arm in recorded]
        if self.arm_models is not None:
            pairs = [(arm.name, arm.model) for arm in recorded]
            check_arms(pairs, self.arm_models, self.source or "the recording")

    def _arm(self, name: str) -> _ArmSpan:
        arm = self.arms.get(name)
        if arm is None:
            if len(self.arms) >= MAX_ARMS:
                raise InvalidCommand(f"the recording has more than {MAX_ARMS} arms")
            arm = self.arms[name] = _ArmSpan(self.dt)
        return arm

    def _episode(self, m: Mapping[str, Any]) -> None:
        if self.episode is None or m.get("event") not in ("start", "end"):
            return
        if int(m["episode"]) != self.episode:
            return
        t = _finite(m["t"])
        self.marks += 1
        if self.marks == 1:
            if self.segment is not None:
                self.lo, self.hi = t + self.segment[0], t + self.segment[1]
            else:
                self.lo = t
            for topic, earlier in self.recent:
                self.add(topic, earlier)
            self.recent.clear()
        elif self.marks == 2 and self.segment is None:
            self.hi = t

    def _state(self, topic: str, name: str, m: Mapping[str, Any]) -> bool:
        t = _finite(m["t"])
        if not self.any_state:
            self.any_state = True
            if self.episode is None and self.segment is not None:
                self.lo, self.hi = t + self.segment[0], t + self.segment[1]
        if self.lo is None:
            self.recent.append((topic, m))
            return False
        if t < self.lo:
            return False
        if t > self.hi:
            return t > self.hi + self.SLACK_S
        self._arm(name).state(t, m)
        return False

    def _force(self, topic: str, name: str, m: Mapping[str, Any]) -> bool:
        t = _finite(m["t"])
        values = m["values"]
        f = (float(values[0]), float(values[1]), float(values[2]))
        if not all(math.isfinite(v) for v in f):
            return False  # a bad sample is left out, as the sensor's own would be
        if self.lo is None:
            self.recent.append((topic, m))
            return False
        if t < self.lo - self.dt:
            return False
        if t > self.hi + self.SLACK_S:
            return True
        self._arm(name).force(t, f)
        return False

    # ------------------------------------------------------------ the result
    def trajectories(self, source: str) -> dict[str, Trajectory]:
        """Each arm's path, in the order the recording names them; several arms' over
        the span they were all recorded in, on one grid (one path clock drives them)."""
        if not self.any_state:
            raise InvalidCommand("the recording has no robot states (/robot/state)")
        if self.episode is not None and self.marks == 0:
            raise InvalidCommand(f"the recording has no episode {self.episode}")
        order = [*self.named, *(n for n in self.arms if n not in self.named)]
        if self.arm_models is not None and not self.named:  # no /settings said the arms
            check_arms([(n, "") for n in order], self.arm_models, self.source or "the recording")
        kept = {name: self._arm(name).kept(self.hi) for name in order}
        for name, states in kept.items():
            if len(states) < 2:
                of = "" if len(kept) == 1 else f" of its arm {name[:32]!r}"
                raise InvalidCommand(f"a task needs at least two robot states{of} in its time span")
        within = None
        if len(kept) > 1:
            within = (
                max(float(s[0, 0]) for s in kept.values()),
                min(float(s[-1, 0]) for s in kept.values()),
            )
            if within[1] - within[0] < self.dt:
                raise InvalidCommand(
                    "the arms' robot states do not overlap in the task's time span"
                )
        return {
            name: self.arms[name].trajectory(states, source, within)
            for name, states in kept.items()
        }


def check_arms(recorded: list[tuple[str, str]], wanted: Mapping[str, str], source: str) -> None:
    """The recording's arms (``(name, model)``, model "" if not said) can be repeated on
    the arms ``wanted`` (name → model: the server's): each recorded arm by the arm of its
    name, of its model; else ``OtherArms`` or ``AnotherArm``, saying why."""
    names = [name for name, _ in recorded]
    if any(name not in wanted for name in names):
        raise OtherArms(other_arms_text(source, names, list(wanted)))
    for name, model in recorded:
        if model and wanted[name] and model != wanted[name]:
            if len(wanted) == 1:
                raise AnotherArm(another_arm_text(source, model[:64], wanted[name]))
            raise AnotherArm(
                f"{source}: its arm {name!r} was recorded as another arm model "
                f"({model[:64]}) than this server's {name!r} ({wanted[name]}): a task "
                "repeats the recorded tool path, which only the arm model that made it can "
                "follow"
            )


def other_arms_text(source: str, recorded: list[str], server: list[str]) -> str:
    def arms(names: list[str]) -> str:
        if names == [SINGLE_ARM]:
            return "one arm"
        return f"{len(names)} arms ({', '.join(n[:32] for n in names[:MAX_ARMS])})"

    if recorded == [SINGLE_ARM] and len(server) > 1:
        return (
            f"{source} was recorded with one arm, and this server drives {arms(server)}:"
            " name the arm to repeat it on (arm: one of"
            f" {', '.join(n[:32] for n in server[:MAX_ARMS])})"
        )
    return (
        f"{source} was recorded with {arms(recorded)}, and this server drives "
        f"{arms(server)}: a task repeats each recorded arm's path on this server's arm of "
        "the same name"
    )


def _finite(value: Any) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"a time that is not finite ({v})")
    return v
