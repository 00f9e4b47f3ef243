"""Where an absolute move's full IK runs (issue 50): the event loop's worst stall while
the SO-101's numeric solver works, inline on the loop, on a thread (what the server
does: ``ArmGuard.off_loop``) and in a process (a pool of one, the model built there).

    python -m bench.solver_thread [--json] [--solves 40]

A 1 ms ticker on the loop stands for every other client's commands, the e-stop and
the forces' hand-over: ``loop_stall_ms`` {"p50", "max"} of its gaps per placement, and
``solve_ms`` {"p50", "p99"} (the caller's wait for one answer) beside them.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any

import numpy as np

from bench.common import emit, machine, p50_p99, parser
from telerobot.drivers.robot.kinematics import tool_transform
from telerobot.drivers.robot.models.so101 import MODEL as SO101

_process_model: Any = None


def _model() -> Any:
    return SO101.kinematics(tool_transform(0.0))


def _solve_in_process(T: np.ndarray, seed: np.ndarray) -> np.ndarray:
    global _process_model
    if _process_model is None:
        _process_model = _model()
    return np.asarray(_process_model.ik(T, seed))


def targets(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Absolute poses a few centimetres from random reachable poses (seeded)."""
    rng = np.random.default_rng(50)
    model = _model()
    lo, hi = model.qlim[:, 0], model.qlim[:, 1]
    out = []
    for _ in range(n):
        q = lo + (hi - lo) * (0.3 + 0.4 * rng.random(len(lo)))
        T = model.fk(q).copy()
        T[:3, 3] += rng.normal(0, 0.02, 3)
        out.append((T, q))
    return out


async def measure(
    solve: Callable[[np.ndarray, np.ndarray], Any], work: list[Any]
) -> dict[str, Any]:
    gaps: list[float] = []
    done = False

    async def ticker() -> None:
        last = time.perf_counter()
        while not done:
            await asyncio.sleep(0.001)
            now = time.perf_counter()
            gaps.append((now - last) * 1000)
            last = now

    tick = asyncio.create_task(ticker())
    await asyncio.sleep(0.05)
    waits = []
    for T, seed in work:
        t0 = time.perf_counter()
        with contextlib.suppress(Exception):  # an unreachable pose costs its time too
            await solve(T, seed)
        waits.append((time.perf_counter() - t0) * 1000)
    done = True
    await tick
    return {"loop_stall_ms": {"p50": float(np.median(gaps)), "max": float(max(gaps))},
            "solve_ms": p50_p99(waits)}  # fmt: skip


async def run(solves: int) -> dict[str, Any]:
    work = targets(solves)
    model = _model()

    async def inline(T: np.ndarray, seed: np.ndarray) -> Any:
        return model.ik(T, seed)

    threaded = copy.deepcopy(model)
    pool = ThreadPoolExecutor(1)

    async def on_thread(T: np.ndarray, seed: np.ndarray) -> Any:
        return await asyncio.get_running_loop().run_in_executor(pool, threaded.ik, T, seed)

    procs = ProcessPoolExecutor(1)
    await asyncio.get_running_loop().run_in_executor(procs, _solve_in_process, *work[0])

    async def in_process(T: np.ndarray, seed: np.ndarray) -> Any:
        return await asyncio.get_running_loop().run_in_executor(procs, _solve_in_process, T, seed)

    figures = {
        "inline": await measure(inline, work),
        "thread": await measure(on_thread, work),
        "process": await measure(in_process, work),
    }
    pool.shutdown()
    procs.shutdown()
    return figures


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--solves", type=int, default=40)
    args = p.parse_args()
    figures = asyncio.run(run(args.solves))
    emit({"machine": machine(), "solves": args.solves, **figures}, args.json)


if __name__ == "__main__":
    main()
