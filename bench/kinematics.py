"""PUMA 560 kinematics: FK, analytic IK (all 8 solutions), Jacobian, and the worst
FK∘IK round-trip error over random poses within the joint limits.

    python -m bench.kinematics [--json] [--poses 10000]
"""

from __future__ import annotations

import numpy as np

from bench.common import emit, machine, parser, time_per_call_us
from drivers.robot.puma560.kinematics import NAMED_POSES, QLIM, Puma560Kinematics, tool_transform


def roundtrip(kin: Puma560Kinematics, poses: int, seed: int = 1) -> tuple[float, float]:
    """Worst pose error over every reachable solution of every pose, and the share of
    poses where the nearest-configuration IK returns the joints it started from."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    recovered = 0
    for _ in range(poses):
        q = rng.uniform(QLIM[:, 0], QLIM[:, 1])
        T = kin.fk(q).copy()
        sols = kin.ik_all(T, q)
        for qq in sols.q[sols.reachable]:
            worst = max(worst, float(np.abs(kin.fk(qq) - T).max()))
        recovered += bool(np.abs(kin.ik(T, q) - q).max() < 1e-6)
    return worst, recovered / poses


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--poses", type=int, default=10_000)
    args = p.parse_args()
    kin = Puma560Kinematics(tool_transform(0.1))
    q = NAMED_POSES["qn"] + 0.1
    T = kin.fk(q).copy()
    figures = {
        "fk_us": time_per_call_us(lambda: kin.fk(q), calls=20_000),
        "ik_us": time_per_call_us(lambda: kin.ik_all(T), calls=5_000),
        "ik_nearest_us": time_per_call_us(lambda: kin.ik(T, q), calls=2_000),
        "jacobian_us": time_per_call_us(lambda: kin.jacobian(q), calls=20_000),
    }
    worst, recovered = roundtrip(kin, args.poses)
    figures["roundtrip_max_err"] = worst
    figures["nearest_recovers_start"] = recovered
    figures["poses"] = args.poses
    figures["machine"] = machine()
    emit(figures, args.json)


if __name__ == "__main__":
    main()
