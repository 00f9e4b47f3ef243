"""An emulated Unimation controller that speaks the TRINC exchange
(docs/val-protocol.md) on a pseudo-terminal or a TCP port and moves a simulated arm.

``ValControllerEmulator`` is the protocol logic, fed lines with the time they
arrive; ``EmulatorLink`` runs it on a real pty or socket in its own thread, so the
driver under test goes through real file descriptors. ``fault`` lets tests make the
controller go silent or garble a reply.

A move follows the controller's synchronised trapezoid (``SyncMove``), so where the
arm is at any instant is known. ``ABORT`` during a move stops it as the controller's
drives do: every joint decelerates together, the slowest at the arm's stop
deceleration (``StopRamp``), and the monitor prompt comes when the arm is at rest.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from telerobot.drivers.base import FloatArray
from telerobot.drivers.emulator_link import EmulatorLink as BaseLink
from telerobot.drivers.robot.motion import PUMA_AMAX, PUMA_STOP_DECEL, PUMA_VMAX, StopRamp, SyncMove
from telerobot.drivers.robot.puma560 import val_protocol as vp
from telerobot.drivers.robot.puma560.kinematics import NAMED_POSES, QLIM_DEG

log = logging.getLogger(__name__)

Fault = Literal["mute", "garble"] | None


@dataclass(frozen=True)
class _Move:
    """A MOVE under way: started at ``start`` (emulator clock), ends at ``deadline``."""

    start: float
    deadline: float
    seq: int
    target_deg: list[float]
    profile: SyncMove  # radians, in unscaled time


@dataclass(frozen=True)
class _Stop:
    """An aborted MOVE decelerating to rest: at rest at ``deadline``."""

    start: float
    deadline: float
    ramp: StopRamp  # radians, in unscaled time


class ValControllerEmulator:
    def __init__(
        self,
        start_deg: list[float] | None = None,
        *,
        time_scale: float = 1.0,
        vmax: np.ndarray = PUMA_VMAX,
        amax: np.ndarray = PUMA_AMAX,
        stop_decel: np.ndarray = PUMA_STOP_DECEL,
    ) -> None:
        self.joints_deg = (
            list(np.degrees(NAMED_POSES["qz"])) if start_deg is None else list(start_deg)
        )
        self.time_scale = time_scale
        self.vmax, self.amax, self.stop_decel = vmax, amax, stop_decel
        self.mode: Literal["monitor", "edit", "program"] = "monitor"
        self.program: list[str] = []
        self.loaded: dict[str, list[str]] = {}
        self.fault: Fault = None
        self.moves = 0
        self.aborted = 0  # moves stopped by ABORT
        self._pending: _Move | None = None
        self._stopping: _Stop | None = None
        self._queued: deque[str] = deque()

    # ---------------------------------------------------------- where the arm is
    def state_at(self, now: float) -> tuple[FloatArray, FloatArray]:
        """Joint angles (rad) and velocities (rad/s) at ``now``, mid-move or mid-stop."""
        ts = self.time_scale
        if self._pending is not None:
            q, v = self._pending.profile.at((now - self._pending.start) / ts)
            return q, v / ts
        if self._stopping is not None:
            ql, vl = self._stopping.ramp.at((now - self._stopping.start) / ts)
            return np.array(ql), np.array(vl) / ts
        return np.radians(self.joints_deg), np.zeros(6)

    # ---------------------------------------------------------- lines in, lines out
    def receive(self, line: str, now: float) -> list[str]:
        line = line.rstrip()  # leading blanks are kept: they are program text in the editor
        if line.strip().upper() == "ABORT" and self._stopping is None:
            # A monitor command: it works even while the program is inside MOVE.
            self.mode = "monitor"
            self._queued.clear()
            if self._pending is not None:
                self._abort(now)
                return []  # the prompt comes when the arm is at rest
            return self._out([vp.PROMPT])
        if self._pending is not None or self._stopping is not None:
            self._queued.append(line)  # inside MOVE, or stopping: the line waits
            return []
        return self._out(self._handle(line, now))

    def _abort(self, now: float) -> None:
        """Stop the move under way as the drives do: decelerate to rest at the limit."""
        assert self._pending is not None
        move, self._pending = self._pending, None
        q, v = move.profile.at((now - move.start) / self.time_scale)
        ramp = StopRamp(q, v, self.stop_decel)
        self._stopping = _Stop(now, now + ramp.duration * self.time_scale, ramp)
        self.aborted += 1

    def poll(self, now: float) -> list[str]:
        """Lines due by ``now``: a move's DONE, or the prompt once an aborted move is at
        rest, then any lines that waited for it."""
        out: list[str] = []
        if self._pending is not None and now >= self._pending.deadline:
            move, self._pending = self._pending, None
            self.joints_deg = move.target_deg
            self.moves += 1
            out += self._out([vp.done_line(move.seq, move.target_deg)])
        elif self._stopping is not None and now >= self._stopping.deadline:
            stop, self._stopping = self._stopping, None
            self.joints_deg = [round(math.degrees(a), 4) for a in stop.ramp.end]
            out += self._out([vp.PROMPT])
        else:
            return out
        while self._queued and self._pending is None and self._stopping is None:
            out += self.receive(self._queued.popleft(), now)
        return out

    def next_deadline(self) -> float | None:
        if self._pending is not None:
            return self._pending.deadline
        return None if self._stopping is None else self._stopping.deadline

    def _out(self, lines: list[str]) -> list[str]:
        if self.fault == "mute":
            return []
        if self.fault == "garble" and lines:
            self.fault = None
            return ["\x13#?~ POS 1.0 x", *lines[1:]]
        return lines

    def _handle(self, line: str, now: float) -> list[str]:
        if self.mode == "edit":
            if line.upper() == "E":
                self.loaded[self._editing] = list(self.program)
                self.mode = "monitor"
                return [vp.PROMPT]
            self.program.append(line)
            return [f"{len(self.program) + 1}."]
        if self.mode == "program":
            return self._program_line(line.strip(), now)
        return self._monitor_line(line.strip())

    def _monitor_line(self, line: str) -> list[str]:
        words = line.upper().split()
        if not words:
            return [vp.PROMPT]
        if words[0] == "EDIT" and len(words) == 2:
            self.mode, self._editing, self.program = "edit", words[1], []
            return ["1."]
        if words[0] in ("EXECUTE", "EX") and len(words) == 2:
            if words[1] not in self.loaded:
                return [f"ERR program {words[1]} is not loaded", vp.PROMPT]
            self.mode = "program"
            return [vp.READY_BANNER]
        if words[0] == "WHERE":
            return [vp.position_line(self.joints_deg), vp.PROMPT]
        return [f"ERR unknown command {words[0]}", vp.PROMPT]

    def _program_line(self, line: str, now: float) -> list[str]:
        if line.upper() == "W":
            return [vp.position_line(self.joints_deg)]
        if line.upper() == "Q":
            self.mode = "monitor"
            return [vp.END_BANNER, vp.PROMPT]
        try:
            seq, delta = vp.parse_increment(line)
        except vp.ProtocolError:
            return [f"ERR bad input {line[:40]!r}"]
        target = [round(j + d, 4) for j, d in zip(self.joints_deg, delta, strict=True)]
        for i, (lo, hi) in enumerate(QLIM_DEG):
            if not lo - 1e-6 <= target[i] <= hi + 1e-6:
                return [vp.nak_line(seq, f"joint {i + 1} limit")]
        profile = SyncMove(np.radians(self.joints_deg), np.radians(target), self.vmax, self.amax)
        duration = self.time_scale * profile.duration
        self._pending = _Move(now, now + duration, seq, target, profile)
        return [vp.ack_line(seq, duration)]


class EmulatorLink(BaseLink):
    """Runs a VAL controller emulator on a pseudo-terminal or a TCP port
    (``telerobot.drivers.emulator_link``): lines in, the controller's lines out, and what it
    says by itself when a move ends."""

    thread_name = "val-emulator"

    def __init__(
        self, emulator: ValControllerEmulator, clock: Callable[[], float] = time.monotonic
    ) -> None:
        super().__init__(clock)
        self.emulator = emulator
        self._buffer = b""

    @classmethod
    def on_pty(cls, emulator: ValControllerEmulator) -> EmulatorLink:
        return cls(emulator)._open_pty()

    @classmethod
    def on_tcp(
        cls, emulator: ValControllerEmulator, host: str = "127.0.0.1", port: int = 0
    ) -> EmulatorLink:
        return cls(emulator)._open_tcp(host, port)

    def _connected(self) -> None:
        self._buffer = b""

    def _wait_s(self) -> float:
        deadline = self.emulator.next_deadline()
        return 0.05 if deadline is None else min(0.05, max(0.0, deadline - self.clock()))

    def _tick(self) -> bytes:
        return _lines(self.emulator.poll(self.clock()))

    def _received(self, data: bytes) -> bytes:
        # A line ends with CR, LF or CR LF; an empty line asks for a prompt.
        self._buffer += data.replace(b"\r\n", b"\r").replace(b"\n", b"\r")
        *lines, self._buffer = self._buffer.split(b"\r")
        return b"".join(
            _lines(self.emulator.receive(raw.decode("latin-1"), self.clock())) for raw in lines
        )


def _lines(lines: list[str]) -> bytes:
    return b"".join(line.encode("latin-1") + b"\r\n" for line in lines)
