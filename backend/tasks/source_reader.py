"""Reading tasks' sources (recordings) for the API: off the event loop, one read at a
time, each bounded in time and memory (``Trajectory.from_recording``); previews cached;
a budget per address for clients without the operator token.

Anyone may preview a task (the page's ghost of the path before it runs), and a preview
reads the recording: about a second of CPU per minute recorded. Reads in threads, many
at once, held the interpreter the event loop needs for the e-stop and the operator's
commands (tokenless preview loops grew the server from 322 to 502 MB and had
operator commands dropped as stale). So:

- **One read at a time**, in one worker process of its own (started on the first
  read, ``spawn``: the server's threads are not copied): the read never holds the
  interpreter the event loop runs in. In a thread it did, in slices of up to tens of
  milliseconds (decompressing, decoding), and the e-stop waited behind them (30 ms
  under tokenless preview loops, bench.abuse's task_preview). Its memory is the
  worker's, not the server's. A client without the token that finds it busy gets 429 at
  once (nothing queues for it); the operator's reads wait their turn, ``MAX_QUEUED`` at
  most.
- **Previews are cached** by (file, size, modification time, episode, segment): asking
  again costs a lookup. ``CACHE_SIZE`` previews of at most ``PREVIEW_POINTS`` points.
- **Only this server's arms' recordings** (``arm_models``: each arm's name and model):
  a recording made with another arm model, or with arms this server has none of the name
  for, is refused as soon as its first message says so (``AnotherArm``, ``OtherArms``,
  422): its tool path is another arm's. A multi-arm recording gives each arm's path.
- **A budget per address** (a token bucket, as /ws has): an answer from the cache costs
  1, a read ``READ_COST``, refilled at ``RATE_PER_S`` up to ``BURST``; past it, 429 saying
  when to come back. The operator token skips the budget, not the one-at-a-time rule.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand, TelerobotError
from telerobot.server.realtime.ratelimit import TokenBucket
from telerobot.server.recording.readjobs import JOB_NICE
from telerobot.server.recording.schemas import SINGLE_ARM
from telerobot.server.tasks.trajectory import READ_LIMIT_S, Trajectory, read_recording
from telerobot.tuning import yield_cpu

PREVIEW_POINTS = 400
CACHE_SIZE = 64
RATE_PER_S = 2.0
BURST = 20.0
READ_COST = 10.0  # a read is ten looks at the cache: one every 5 s, after a burst of two
MAX_ADDRESSES = 1024  # addresses with a budget; the one heard from longest ago goes first
# Every tokenless address together gets this many times one address's budget: a budget
# per address alone grows with the addresses a client has (six loopback ones in a probe).
ALL_ADDRESSES_SHARE = 2.0
ORPHAN_CHECK_S = 0.5  # how often the reader's process looks whether the server is gone
MAX_QUEUED = 4  # the operator's reads waiting for the reader, at most


def _behind_control() -> None:
    """The reader's process waits behind control, forces and live video, as the
    recordings' read jobs do: at the same priority as the server, a read took turns
    with the event loop on a 2-core machine and the e-stop waited out its slices.
    And it ends with the server: a server that stopped (``close`` does not wait) or was
    killed left its reader behind for good, ~100 MB each time."""
    yield_cpu(JOB_NICE)
    threading.Thread(target=_exit_with, args=(os.getppid(),), daemon=True).start()


def _exit_with(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(ORPHAN_CHECK_S)
    os._exit(0)


class ReadFailed(TelerobotError):
    """The reader's process ended without an answer."""

    code = "task_source_read_failed"
    http_status = 503


class TooManyPreviews(TelerobotError):
    """This address has used its budget of reads, or the reader is busy."""

    code = "too_many_previews"
    http_status = 429


@dataclass(frozen=True)
class PathPreview:
    """A trajectory's positions thinned to at most ``PREVIEW_POINTS`` (ends kept), with
    the recorded force's magnitude at each (arrays: a cached preview is 13 kB)."""

    positions: FloatArray  # (k, 3) m, base frame
    forces_n: FloatArray  # (k,)
    start_rotation: FloatArray  # (3, 3) the tool's at the first pose (for the approach)
    arm: str = SINGLE_ARM  # whose path it is (a multi-arm recording's first arm)

    @classmethod
    def of_paths(cls, paths: Mapping[str, Trajectory]) -> PathPreview:
        """The first arm's path (a multi-arm task's other arms' are not previewed)."""
        arm, traj = next(iter(paths.items()))
        return cls.of(traj, arm=arm)

    @classmethod
    def of(
        cls, traj: Trajectory, max_points: int = PREVIEW_POINTS, *, arm: str = SINGLE_ARM
    ) -> PathPreview:
        step = max(1, -(-len(traj) // max_points))
        idx = list(range(0, len(traj), step))
        if idx[-1] != len(traj) - 1:
            idx.append(len(traj) - 1)
        return cls(
            traj.positions[idx].copy(),
            np.linalg.norm(traj.forces[idx], axis=1),
            traj.rotations[0].copy(),
            arm,
        )


Key = tuple[str, int, int, int | None, tuple[float, float] | None, str | None]


def _key(
    path: Path, episode: int | None, segment: tuple[float, float] | None, onto: str | None = None
) -> Key:
    """What a preview depends on: the file as it is now (one stat), the span, and the
    arm a one-arm recording is repeated on."""
    stat = path.stat()
    return (path.name, stat.st_size, stat.st_mtime_ns, episode, segment, onto)


def onto_arm(name: str, arm_models: Mapping[str, str] | None) -> str:
    """The model of this server's arm ``name``, which a one-arm recording is to be
    repeated on; InvalidCommand naming the server's arms if there is none of that name."""
    models = dict(arm_models or {})
    if name not in models or name == SINGLE_ARM:
        names = ", ".join(n for n in models if n != SINGLE_ARM) or "none: it drives one arm"
        raise InvalidCommand(
            f"this server has no arm {name[:32]!r} to repeat the recording on (its arms: {names})"
        )
    return models[name]


class SourceReader:
    """Reads recordings into trajectories for ``POST /tasks`` and ``/tasks/preview``."""

    def __init__(
        self,
        *,
        clock: Callable[[], float] = time.monotonic,
        time_limit_s: float = READ_LIMIT_S,
        rate_per_s: float = RATE_PER_S,
        burst: float = BURST,
        read_cost: float = READ_COST,
        cache_size: int = CACHE_SIZE,
        robot_model: str | None = None,
        arm_models: Mapping[str, str] | None = None,
    ) -> None:
        self.clock = clock
        # The server's arms, name → model (None: any recording); one arm's: robot_model.
        if arm_models is None and robot_model is not None:
            arm_models = {SINGLE_ARM: robot_model}
        self.arm_models = None if arm_models is None else dict(arm_models)
        self.time_limit_s = time_limit_s
        self.rate_per_s, self.burst, self.read_cost = rate_per_s, burst, read_cost
        self.cache_size = cache_size
        self.reads = 0  # recordings read (for tests and the bench)
        self.refused = 0  # requests answered 429
        self._cache: OrderedDict[Key, PathPreview] = OrderedDict()
        self._budgets: OrderedDict[str, TokenBucket] = OrderedDict()
        self._everyone = TokenBucket(
            ALL_ADDRESSES_SHARE * rate_per_s, ALL_ADDRESSES_SHARE * burst
        )  # every address's reads together
        self._executor: ProcessPoolExecutor | None = None  # started on the first read
        self._closed = False
        self._lock = threading.Lock()
        self._in_flight = 0  # reads submitted and not yet finished (the thread's count)

    # ------------------------------------------------------------ the API's calls
    async def paths(
        self,
        path: Path,
        episode: int | None,
        segment: tuple[float, float] | None,
        *,
        operator: bool,
        address: str,
        onto: str | None = None,
    ) -> dict[str, Trajectory]:
        """Each recorded arm's path (by name; one arm's named "arm") of ``path``'s
        episode or segment, read now; a one-arm recording's named ``onto`` (one of this
        server's arms) when that is given (``onto_arm``)."""
        if not operator:
            self._charge(address, self.read_cost)
        return await self._read(path, episode, segment, operator=operator, onto=onto)

    async def trajectory(
        self,
        path: Path,
        episode: int | None,
        segment: tuple[float, float] | None,
        *,
        operator: bool,
        address: str,
    ) -> Trajectory:
        """The trajectory of a one-arm recording's episode or segment, read now."""
        paths = await self.paths(path, episode, segment, operator=operator, address=address)
        if len(paths) != 1:
            raise InvalidCommand(f"{path.name} was recorded with {len(paths)} arms: read paths")
        return next(iter(paths.values()))

    async def preview(
        self,
        path: Path,
        episode: int | None,
        segment: tuple[float, float] | None,
        *,
        operator: bool,
        address: str,
        onto: str | None = None,
    ) -> PathPreview:
        """The thinned path of ``path``'s episode or segment, from the cache if it has
        been read since the file last changed (``onto``: as for ``paths``)."""
        key = _key(path, episode, segment, onto)
        cached = self._cache.get(key)
        if cached is not None:
            if not operator:
                self._charge(address, 1.0)
            self._cache.move_to_end(key)
            return cached
        if not operator:
            self._charge(address, self.read_cost)
        found = PathPreview.of_paths(
            await self._read(path, episode, segment, operator=operator, onto=onto)
        )
        self._cache[key] = found
        while len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return found

    def close(self) -> None:
        """Server shutdown: a read under way finishes in its process (within its time
        limit); queued ones are dropped."""
        self._closed = True
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)

    # ------------------------------------------------------------ inside
    def _charge(self, address: str, cost: float) -> None:
        bucket = self._budgets.pop(address, None)
        if bucket is None:
            bucket = TokenBucket(self.rate_per_s, self.burst)
        self._budgets[address] = bucket
        while len(self._budgets) > MAX_ADDRESSES:
            self._budgets.popitem(last=False)
        now = self.clock()
        wait = bucket.take(now, cost)
        if wait <= 0 and (wait := self._everyone.take(now, cost)) > 0:
            bucket.tokens += cost  # refused: the address's budget is given back
            self._everyone.tokens += cost
            self.refused += 1
            raise TooManyPreviews(
                f"too many task previews from clients without the operator token right now:"
                f" try again in {wait:.1f} s"
            )
        if wait > 0:
            bucket.tokens += cost  # refused: it costs nothing more
            self.refused += 1
            raise TooManyPreviews(
                f"too many task previews from {address}: try again in {wait:.1f} s (without "
                f"the operator token an address may read a recording every "
                f"{self.read_cost / self.rate_per_s:g} s, and look again at one read "
                f"{self.rate_per_s:g} times a second)"
            )

    async def _read(
        self,
        path: Path,
        episode: int | None,
        segment: tuple[float, float] | None,
        *,
        operator: bool,
        onto: str | None = None,
    ) -> dict[str, Trajectory]:
        arm_models = self.arm_models
        if onto is not None:
            # Read as a one-arm recording of that arm's model; its path named after it.
            arm_models = {SINGLE_ARM: onto_arm(onto, self.arm_models)}
        with self._lock:
            busy = self._in_flight
            if (busy and not operator) or busy >= MAX_QUEUED:
                self.refused += 1
                raise TooManyPreviews(
                    "another recording is being read for a task: try again in a moment"
                    + ("" if operator else " (reads without the operator token do not queue)")
                )
            self._in_flight += 1
        self.reads += 1
        try:
            if self._closed:
                raise RuntimeError("closed")
            if self._executor is None:
                self._executor = ProcessPoolExecutor(
                    max_workers=1,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=_behind_control,
                )
            future = self._executor.submit(
                read_recording,
                path,
                episode=episode,
                segment=segment,
                time_limit_s=self.time_limit_s,
                arm_models=arm_models,
            )
        except RuntimeError:  # shut down
            self._finished(None)
            raise TooManyPreviews("the server is stopping: no recording is read now") from None
        future.add_done_callback(self._finished)  # also when the request is gone
        try:
            paths = await asyncio.wrap_future(future)
            return paths if onto is None else {onto: paths[SINGLE_ARM]}
        except BrokenProcessPool:  # the worker died (killed, out of memory): a new one next
            self._executor = None
            raise ReadFailed(
                f"reading {path.name} for the task stopped its reader process (out of"
                " memory?): the server's log says more"
            ) from None

    def _finished(self, _future: object) -> None:
        with self._lock:
            self._in_flight -= 1
