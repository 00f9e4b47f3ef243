"""A taught motion as a tool trajectory: from a recording's ``/robot/state`` (tool
position and rotation, ``t``) and ``/force`` samples of an episode or a time segment
to a time-parameterised tool path with the force that was felt along it.

Pure: no I/O but ``from_recording``, which reads a recording through
``backend.recording.reader`` (docs/recording.md). Times are the server's monotonic
``t`` of the recording, shifted so the trajectory starts at 0.

Forces are kept in the **base frame** (the recording has them in the sensor frame,
whose axes are the tool's: each is turned with the tool rotation recorded nearest to
it), averaged over each resampling interval so the sensor's noise does not become
the task's reference.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from drivers.base import FloatArray, InvalidCommand

DEFAULT_DT_S = 0.02  # resampled every 20 ms (the state rate)
MAX_SAMPLES = 30_000  # 10 minutes at 50 Hz: a task is a taught motion, not a shift's work


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
    ) -> Trajectory:
        """From a recording's messages in log order, as ``(topic, payload)``:
        ``/robot/state``, ``/force`` and ``/episodes`` (docs/recording.md). ``episode``
        keeps the span between that episode's start and end events; ``segment`` is
        a span [t0, t1] of the recording's ``t``, relative to its first state."""
        states: list[StateSample] = []
        forces: list[ForceReading] = []
        spans: dict[int, list[float]] = {}
        for topic, m in messages:
            if topic == "/robot/state":
                states.append(
                    StateSample(
                        float(m["t"]),
                        np.asarray(m["position"], dtype=float),
                        np.asarray(m["rotation"], dtype=float).reshape(3, 3),
                    )
                )
            elif topic == "/force":
                forces.append(ForceReading(float(m["t"]), np.asarray(m["values"], dtype=float)))
            elif topic == "/episodes" and m.get("event") in ("start", "end"):
                spans.setdefault(int(m["episode"]), []).append(float(m["t"]))
        if not states:
            raise InvalidCommand("the recording has no robot states (/robot/state)")
        window: tuple[float, float] | None = None
        if episode is not None:
            if episode not in spans:
                raise InvalidCommand(f"the recording has no episode {episode}")
            marks = spans[episode]
            end = marks[1] if len(marks) > 1 else max(s.t for s in states)
            window = (marks[0], end)
        if segment is not None:
            first = window[0] if window else min(s.t for s in states)
            window = (first + segment[0], first + segment[1])
        return cls.from_samples(states, forces, dt=dt, segment=window, source=source)

    @classmethod
    def from_recording(
        cls,
        path: Path,
        *,
        episode: int | None = None,
        segment: tuple[float, float] | None = None,
        dt: float = DEFAULT_DT_S,
    ) -> Trajectory:
        """Read ``path`` with ``backend.recording.reader`` (docs/recording.md)."""
        from backend.recording.reader import read

        what = path.name + (f" episode {episode}" if episode is not None else "")
        if segment is not None:
            what += f" [{segment[0]:g}, {segment[1]:g}] s"
        messages = (
            (topic, payload)
            for topic, _log_time, payload in read(path, ["/robot/state", "/force", "/episodes"])
        )
        return cls.from_messages(messages, episode=episode, segment=segment, dt=dt, source=what)

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

    def polyline(self, max_points: int = 400) -> FloatArray:
        """The path's positions, thinned to at most ``max_points`` (ends kept)."""
        n = len(self)
        if n <= max_points:
            return self.positions.copy()
        idx = np.unique(np.linspace(0, n - 1, max_points).round().astype(int))
        result: FloatArray = self.positions[idx]
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
