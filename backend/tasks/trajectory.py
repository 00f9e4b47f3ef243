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

DEFAULT_DT_S = 0.02  # resampled every 20 ms (the state rate)
MAX_SAMPLES = 30_000  # 10 minutes at 50 Hz: a task is a taught motion, not a shift's work
MAX_STATES = 2 * MAX_SAMPLES  # robot states kept from a span (100 Hz over the longest task)
# Forces seen before the span's first state (its first interval takes those within
# dt/2 before it): a recording with forces and no states keeps no more than these.
MAX_EARLY_FORCES = 5_000
LOOKBACK = 256  # messages looked back at when an episode's start event comes
READ_LIMIT_S = 30.0  # reading a task's source takes at most this long
CHECK_EVERY = 256  # messages between two looks at the deadline
TOPICS = ("/settings", "/robot/state", "/force", "/episodes")


class AnotherArm(InvalidCommand):
    """The recording was made with another arm model than the one asked for."""

    code = "another_arm"


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
        span = _Span(episode, segment, dt, robot_model, source)
        for n, (topic, m) in enumerate(messages):
            if span.add(topic, m):
                break
            if deadline is not None and n % CHECK_EVERY == 0 and time.monotonic() > deadline:
                raise InvalidCommand(
                    "reading the recording took too long (its span is not over after "
                    f"{n} messages): choose an earlier episode or a shorter recording"
                )
        return span.trajectory(source)

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
        from telerobot.server.recording.salvage import SalvageReader

        what = path.name + (f" episode {episode}" if episode is not None else "")
        if segment is not None:
            what += f" [{segment[0]:g}, {segment[1]:g}] s"
        reader = SalvageReader(path)
        messages = ((topic, payload) for topic, _log_time, payload in reader.messages(TOPICS))
        deadline = time.monotonic() + time_limit_s
        try:
            return cls.from_messages(
                messages,
                episode=episode,
                segment=segment,
                dt=dt,
                source=what,
                deadline=deadline,
                robot_model=robot_model,
            )
        except InvalidCommand as exc:
            if reader.stopped and not isinstance(exc, AnotherArm):  # say why so little was read
                raise InvalidCommand(f"{exc} (the file is cut short: {reader.stopped})") from exc
            raise

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
    ts: FloatArray, P: FloatArray, R: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The grid every ``dt`` from ``ts[0]`` (``ts`` sorted), with the positions and
    rotations interpolated at each."""
    start, span = float(ts[0]), float(ts[-1] - ts[0])
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


class _Span:
    """The task's span of a stream of recording messages, kept compactly as it comes
    (``Trajectory.from_messages``). ``add`` says when nothing later can be in the span."""

    SLACK_S = 0.5  # read this far past the span's end: threads log a little out of order

    def __init__(
        self,
        episode: int | None,
        segment: tuple[float, float] | None,
        dt: float,
        robot_model: str | None = None,
        source: str = "",
    ) -> None:
        if not (math.isfinite(dt) and 0.001 <= dt <= 1.0):
            raise InvalidCommand(f"dt must be 1 ms–1 s, got {dt!r}")
        if segment is not None and not (
            math.isfinite(segment[0]) and math.isfinite(segment[1]) and segment[0] < segment[1]
        ):
            raise InvalidCommand(f"a segment is [t0, t1] with t0 < t1, got {segment!r}")
        self.episode, self.segment, self.dt = episode, segment, dt
        self.robot_model, self.source = robot_model, source
        # The span [lo, hi] in the recording's t: lo is None until it is known (an
        # episode's start event not seen yet).
        self.lo: float | None = -math.inf if episode is None and segment is None else None
        self.hi = math.inf
        self.marks = 0  # the episode's start/end events seen
        self.any_state = False
        self.states = np.empty((1024, 13))  # t, position (3), rotation (9): kept, in order
        self.n = 0
        self.early: deque[tuple[float, float, float, float]] = deque(maxlen=MAX_EARLY_FORCES)
        # Until an episode's start event, the last few messages: one logged just before
        # the event (at its very instant, or by another thread) may still be in the span.
        self.recent: deque[tuple[str, Mapping[str, Any]]] = deque(maxlen=LOOKBACK)
        self.rotation: tuple[float, ...] = ()  # of the last state kept (row-major)
        # Per resampling interval: the base-frame forces' sums and counts.
        self.fx, self.fy, self.fz = array("d"), array("d"), array("d")
        self.count = array("l")

    # ------------------------------------------------------------ taking messages
    def add(self, topic: str, m: Mapping[str, Any]) -> bool:
        """Take one message; True once the span is over (nothing later belongs to it)."""
        try:
            if topic == "/robot/state":
                return self._state(m)
            if topic == "/force":
                return self._force(m)
            if topic == "/episodes":
                self._episode(m)
            if topic == "/settings":
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
        recorded = m.get("robot_model") if isinstance(m, Mapping) else None
        if self.robot_model is None or not isinstance(recorded, str) or not recorded:
            return  # any arm asked for, or the recording does not say
        if recorded != self.robot_model:
            raise AnotherArm(
                another_arm_text(self.source or "the recording", recorded[:64], self.robot_model)
            )

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

    def _state(self, m: Mapping[str, Any]) -> bool:
        t = _finite(m["t"])
        if not self.any_state:
            self.any_state = True
            if self.episode is None and self.segment is not None:
                self.lo, self.hi = t + self.segment[0], t + self.segment[1]
        if self.lo is None:
            self.recent.append(("/robot/state", m))
            return False
        if t < self.lo:
            return False
        if t > self.hi:
            return t > self.hi + self.SLACK_S
        if self.n and t <= self.states[self.n - 1, 0]:
            return False  # out of time order (a crafted file): skipped
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
        return False

    def _force(self, m: Mapping[str, Any]) -> bool:
        t = _finite(m["t"])
        values = m["values"]
        f = (float(values[0]), float(values[1]), float(values[2]))
        if not all(math.isfinite(v) for v in f):
            return False  # a bad sample is left out, as the sensor's own would be
        if self.lo is None:
            self.recent.append(("/force", m))
            return False
        if t < self.lo - self.dt:
            return False
        if t > self.hi + self.SLACK_S:
            return True
        if self.n == 0:
            self.early.append((t, *f))
        else:
            self._bin(t, *f)
        return False

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

    # ------------------------------------------------------------ the result
    def trajectory(self, source: str) -> Trajectory:
        if not self.any_state:
            raise InvalidCommand("the recording has no robot states (/robot/state)")
        if self.episode is not None and self.marks == 0:
            raise InvalidCommand(f"the recording has no episode {self.episode}")
        kept = self.states[: self.n]
        kept = kept[kept[:, 0] <= self.hi]
        if len(kept) < 2:
            raise InvalidCommand("a task needs at least two robot states in its time span")
        ts = kept[:, 0].copy()
        P = kept[:, 1:4].copy()
        R = kept[:, 4:13].reshape(-1, 3, 3).copy()
        grid, positions, rotations = _resampled(ts, P, R, self.dt)
        forces = np.zeros((len(grid), 3))
        last = np.zeros(3)
        for i in range(len(grid)):
            if i < len(self.count) and self.count[i] > 0:
                c = self.count[i]
                last = np.array([self.fx[i] / c, self.fy[i] / c, self.fz[i] / c])
            forces[i] = last
        return Trajectory(self.dt, positions, rotations, forces, source)


def _finite(value: Any) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"a time that is not finite ({v})")
    return v
