"""Kinematics of a robot model: FK, Jacobian, IK timings and the IK's accuracy over
random poses within the joint limits.

    python -m bench.kinematics [--json] [--model puma560|so101] [--poses 10000]

Every model: ``fk_us``, ``jacobian_us``, ``ik_us`` (medians of the mean per call),
``ik_success_rate`` and ``ik_max_residual_m`` / ``ik_max_residual_rad`` over
``--poses`` random joint vectors within the limits: each one's tool pose is solved
warm-started from joints ``--warm-rad`` away (normal, per joint; 0.02 rad is one
50 Hz command at 1 rad/s, a teleoperated arm's next pose), and the joints found are
put through FK again to measure the residual. ``ik_cold_success_rate`` starts from the
model's home pose instead (an absolute move across the workspace).

The PUMA 560's IK is its closed form (``ik_us`` is the nearest-configuration call);
it also prints the all-eight-solutions figures (``ik_all_us``, ``roundtrip_max_err``,
``nearest_recovers_start``) measured from the start. Other models use the numeric IK
from their URDF (``telerobot.drivers.robot.models.numeric``).

``--arms 2`` (issue 33): the kinematics a server of two such arms builds, one instance
per arm (``make_kinematics`` over each arm's settings: each its own Pinocchio data; an
arm's mount in the workcell is not in them, its poses are in its own base frame), timed
beside a one-arm server's, round-robin: ``per_arm`` (``fk_us``, ``jacobian_us``,
``ik_us`` per arm and for the one arm), ``per_arm_ratio_max`` (the largest of an arm's
over the one arm's) and ``arms_share_kinematics`` (whether any two arms share an
instance or its data: False).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import pinocchio as pin

from bench.common import emit, machine, parser, time_per_call_us
from telerobot.drivers.base import TelerobotError
from telerobot.drivers.robot.kinematics import ArmKinematics, PinocchioKinematics, tool_transform
from telerobot.drivers.robot.models import DEFAULT_MODEL, RobotModel, load_model, model_names


def residual(kin: ArmKinematics, q: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """Position (m) and orientation (rad) error of FK(q) against ``T``."""
    R = kin.fk(q)
    pos = float(np.linalg.norm(R[:3, 3] - T[:3, 3]))
    return pos, float(np.linalg.norm(pin.log3(R[:3, :3].T @ T[:3, :3])))


def accuracy(
    model: RobotModel, kin: ArmKinematics, poses: int, warm_rad: float, seed: int = 1
) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    lo, hi = model.qlim[:, 0], model.qlim[:, 1]
    home = model.pose(model.home_pose)
    ok = cold_ok = 0
    worst_m = worst_rad = 0.0
    for _ in range(poses):
        q = rng.uniform(lo, hi)
        T = kin.fk(q).copy()
        start = np.clip(q + rng.normal(0.0, warm_rad, len(q)), lo, hi)
        try:
            found = kin.ik(T, start)
        except TelerobotError:
            continue
        pos, rot = residual(kin, found, T)
        worst_m, worst_rad = max(worst_m, pos), max(worst_rad, rot)
        ok += pos <= 1e-6 and rot <= 1e-5 and kin.within_limits(found)
    cold_poses = max(1, poses // 10)
    for _ in range(cold_poses):
        q = rng.uniform(lo, hi)
        T = kin.fk(q).copy()
        try:
            found = kin.ik(T, home)
        except TelerobotError:
            continue
        pos, rot = residual(kin, found, T)
        cold_ok += pos <= 1e-6 and rot <= 1e-5
    return {
        "ik_success_rate": ok / poses,
        "ik_max_residual_m": worst_m,
        "ik_max_residual_rad": worst_rad,
        "ik_cold_success_rate": cold_ok / cold_poses,
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--model", default=DEFAULT_MODEL, choices=model_names())
    p.add_argument("--poses", type=int, default=10_000)
    p.add_argument("--warm-rad", type=float, default=0.02)
    p.add_argument("--arms", type=int, default=1, help="2: each arm's kinematics (issue 33)")
    args = p.parse_args()
    model = load_model(args.model)
    kin = model.kinematics(tool_transform(model.default_tool_length))
    rng = np.random.default_rng(7)
    q = model.pose(model.home_pose)
    T = kin.fk(q).copy()
    start = q + rng.normal(0.0, args.warm_rad, len(q))
    figures: dict[str, Any] = {
        "model": model.name,
        "dof": model.dof,
        "fk_us": time_per_call_us(lambda: kin.fk(q), calls=20_000),
        "jacobian_us": time_per_call_us(lambda: kin.jacobian(q), calls=20_000),
        "ik_us": time_per_call_us(lambda: kin.ik(T, start), calls=2_000),
    }
    figures.update(accuracy(model, kin, args.poses, args.warm_rad))
    all_solutions = getattr(kin, "ik_all", None)
    if all_solutions is not None:  # the PUMA's closed form: the figures kept from the start
        from telerobot.drivers.robot.puma560.kinematics import Puma560Kinematics

        assert isinstance(kin, Puma560Kinematics)
        figures["ik_all_us"] = time_per_call_us(lambda: kin.ik_all(T), calls=5_000)
        worst, recovered = roundtrip(kin, args.poses)
        figures["roundtrip_max_err"] = worst
        figures["nearest_recovers_start"] = recovered
    if args.arms > 1:
        figures.update(per_arm(model, args.arms, T, start, q))
    figures["warm_rad"] = args.warm_rad
    figures["poses"] = args.poses
    figures["machine"] = machine()
    emit(figures, args.json)


def per_arm(
    model: RobotModel, arms: int, T: np.ndarray, start: np.ndarray, q: np.ndarray
) -> dict[str, Any]:
    """The kinematics a server of ``arms`` such arms makes (one per arm) and a one-arm
    server's, each timed as above, taking turns (three rounds, medians)."""
    from bench.common import arm_names
    from telerobot.server.devices import make_kinematics
    from telerobot.server.settings import Settings

    spec = ",".join(f"{name}={model.name}:sim" for name in arm_names(arms))
    kins = {name: make_kinematics(own) for name, own in Settings(arms=spec).arm_settings()}
    kins["one_arm"] = make_kinematics(Settings(robot_model=model.name))
    # What could be shared: the instance, and Pinocchio's data (scratch of every call).
    parts = [id(kin) for kin in kins.values()]
    parts += [id(kin._data) for kin in kins.values() if isinstance(kin, PinocchioKinematics)]
    shared = len(set(parts)) < len(parts)
    calls = {"fk_us": 20_000, "jacobian_us": 20_000, "ik_us": 2_000}
    samples: dict[str, dict[str, list[float]]] = {n: {k: [] for k in calls} for n in kins}
    for _ in range(3):
        for name, kin in kins.items():
            for key, fn in (
                ("fk_us", functools.partial(kin.fk, q)),
                ("jacobian_us", functools.partial(kin.jacobian, q)),
                ("ik_us", functools.partial(kin.ik, T, start)),
            ):
                samples[name][key].append(time_per_call_us(fn, calls=calls[key], repeats=3))
    times = {n: {k: float(np.median(v)) for k, v in by.items()} for n, by in samples.items()}
    one = times["one_arm"]
    return {
        "per_arm": times,
        "per_arm_ratio_max": max(
            t[k] / one[k] for n, t in times.items() if n != "one_arm" for k in calls
        ),
        "arms_share_kinematics": shared,
    }


def roundtrip(kin: Any, poses: int, seed: int = 1) -> tuple[float, float]:
    """PUMA: worst pose error over every reachable solution of every pose, and the
    share of poses where the nearest-configuration IK returns the joints it started from."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    recovered = 0
    for _ in range(poses):
        q = rng.uniform(kin.qlim[:, 0], kin.qlim[:, 1])
        T = kin.fk(q).copy()
        sols = kin.ik_all(T, q)
        for qq in sols.q[sols.reachable]:
            worst = max(worst, float(np.abs(kin.fk(qq) - T).max()))
        recovered += bool(np.abs(kin.ik(T, q) - q).max() < 1e-6)
    return worst, recovered / poses


if __name__ == "__main__":
    main()
