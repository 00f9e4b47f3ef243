"""Repeating a taught push with and without compliance.

On the simulation, in virtual time (a ManualClock; the force sensor sampled every
millisecond, the DecisionServer's dead-man and force limit running as in the server):

1. teach: the operator pushes the tool (pointing down, at mid-block height) along +x
   into the block's face nearest the arm at 10 mm/s until the sensor reads ~20 N,
   holds it 0.5 s and backs off to where it started; the states (50 Hz) and forces
   (1 kHz) are the "recording";
2. the block is moved 5 mm toward the arm (−x), and the motion is repeated by a
   TaskRunner twice from the same start: with compliance along x (K 500 N/m) and
   position only. The unexpected-contact margin is off in both runs, so what stops
   the position-only run is the DecisionServer's force limit (60 N).

Figures: ``replay_force_n`` = {"compliance": {peak, mean, limit_tripped},
"position_only": {...}, "taught_n": the peak taught force}. ``peak`` is over every
sensor sample of the repeat; ``mean`` over the task's control periods where the
recording or the repeat had contact (> 2 N). The cell and the push are
harness/sim_cell.py's.

    python -m bench.task_replay [--json]
"""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np

from bench.common import emit, parser
from harness.sim_cell import COMPLIANCE, replay_moved_block
from telerobot.server.tasks.runner import Task


def figures(task: Task, peak: float) -> dict[str, Any]:
    """``peak`` from every sensor sample (1 kHz), ``mean`` from the task's periods."""
    contact = [p.force_n for p in task.trace if max(p.recorded_n, p.force_n) > 2.0]
    return {
        "peak": round(peak, 2),
        "mean": round(float(np.mean(contact)), 2) if contact else 0.0,
        "limit_tripped": task.reason.startswith("force limit"),
        "state": str(task.state),
        "reason": task.reason,
    }


async def _measure() -> dict[str, Any]:
    compliant, taught, compliant_peak = await replay_moved_block(COMPLIANCE)
    rigid, _, rigid_peak = await replay_moved_block(None)
    return {
        "replay_force_n": {
            "compliance": figures(compliant, compliant_peak),
            "position_only": figures(rigid, rigid_peak),
            "taught_n": round(taught, 2),
        }
    }


def measure() -> dict[str, Any]:
    return asyncio.run(_measure())


def main() -> None:
    args = parser(__doc__ or "").parse_args()
    result = measure()
    r = result["replay_force_n"]
    print(f"taught push: {r['taught_n']} N; block moved 5 mm toward the arm, repeated:")
    for name in ("compliance", "position_only"):
        f = r[name]
        print(
            f"  {name:<14} peak {f['peak']:6.1f} N  mean {f['mean']:6.1f} N  "
            f"force limit tripped: {f['limit_tripped']}  ({f['state']}: {f['reason'] or 'ok'})"
        )
    emit(result, args.json)


if __name__ == "__main__":
    main()
