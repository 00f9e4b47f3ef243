"""The LeRobot robot plugin's calls against ``telerobot serve`` (the simulated SO-101 with
its stereo video), as ``lerobot-record`` and ``lerobot-rollout`` make them at their fps:
``get_observation`` with both cameras at the configured size, then ``send_action``.

    python -m bench.lerobot [--json] [--seconds 20] [--fps 30] [--width 640 --height 480]
                            [--busy-core] [--record-seconds 30]

Figures, each ``{"p50": …, "p99": …}`` in ms: ``get_observation_ms`` (the newest frame,
not waited for, as LeRobot's own robots ``read_latest``),
``send_action_ms``, and ``frame_state_skew_ms``: |the state's sample time − the
frame's capture time| (both the server's clock: the simulated cameras date their
frames with a timecode), which should be under half a frame. Also ``steps``,
``repeated_frames`` (a step that found no new frame) and ``capture_source``.
It runs ``telerobot.client.lerobot.arm`` directly, which the plugin only wraps: no
LeRobot (nor torch) is needed for those.

``record_loop_hz`` ``{"p50", "min", "mean"}``: LeRobot's own ``lerobot-record`` (from its
venv, ``LEROBOT_VENV``, else ``make test``'s) with the plugin and its teleoperator, one
episode of ``--record-seconds``, both cameras at the size given, at ``--fps``: each loop
iteration that overran its period LeRobot says at what rate ("Record loop is running
slower (X Hz)"), the others kept the rate; ``mean`` is the frames the dataset got over
the episode's length. ``--record-seconds 0`` skips it.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import busy_core, emit, machine, parser
from harness.servers import serve_for_bench

TOKEN = "bench-lerobot-token-0123456789abcdef"


def _p(values_s: list[float]) -> dict[str, float]:
    v = np.array(values_s) * 1000.0
    return {
        "p50": round(float(np.percentile(v, 50)), 3),
        "p99": round(float(np.percentile(v, 99)), 3),
    }


def measure(seconds: float, fps: float, width: int, height: int) -> dict[str, Any]:
    from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm

    env = {"TELEROBOT_OPERATOR_TOKEN": TOKEN, "TELEROBOT_VIDEO": "true",
           "TELEROBOT_SIM_STARTS_AT_HOME": "true"}  # fmt: skip
    with serve_for_bench("--model", "so101", env=env, ready=True) as (_, base):
        options = ArmOptions(url=base, token=TOKEN, name="bench", width=width, height=height,
                             fps=fps)  # fmt: skip
        arm = TelerobotArm(options)
        arm.connect()
        try:
            units = arm.only.units
            assert units is not None
            start = arm.observation()
            home = np.array([start[k] for k in units.feature_names])
            obs_s, act_s, skew_s = [], [], []
            period = 1.0 / fps
            t0 = time.perf_counter()
            next_step = t0
            steps = 0
            while time.perf_counter() - t0 < seconds:
                a = time.perf_counter()
                arm.observation()
                b = time.perf_counter()
                if arm.last_skew_s is not None:
                    skew_s.append(abs(arm.last_skew_s))
                t = b - t0
                target = home.copy()
                target[0] += 15.0 * math.sin(2 * math.pi * t / 6)  # shoulder_pan, degrees
                arm.send(dict(zip(units.feature_names, target.tolist(), strict=True)))
                act_s.append(time.perf_counter() - b)
                obs_s.append(b - a)
                steps += 1
                next_step += period
                time.sleep(max(0.0, next_step - time.perf_counter()))
            receiver = arm.receiver
            source = receiver.latest().capture_source if receiver and receiver.latest() else None
        finally:
            arm.disconnect()
    return {
        "get_observation_ms": _p(obs_s),
        "send_action_ms": _p(act_s),
        "frame_state_skew_ms": _p(skew_s),
        "half_frame_ms": round(500.0 / fps, 3),
        "steps": steps,
        "repeated_frames": arm.repeated_frames,
        "capture_source": source,
        "camera": f"{width}x{height} each, {fps:g} fps",
    }


LEROBOT_VENV = Path(os.environ.get("LEROBOT_VENV", Path.home() / ".cache/telerobot/lerobot-0.6.1"))
SLOWER = re.compile(r"Record loop is running slower \(([\d.]+) Hz\)")


def record_loop(seconds: float, fps: float, width: int, height: int) -> dict[str, Any]:
    """``lerobot-record`` through the plugins for one episode: its loop's rate."""
    env = {"TELEROBOT_OPERATOR_TOKEN": TOKEN, "TELEROBOT_VIDEO": "true",
           "TELEROBOT_SIM_STARTS_AT_HOME": "true"}  # fmt: skip
    with (
        serve_for_bench("--model", "so101", env=env, ready=True) as (_, base),
        tempfile.TemporaryDirectory() as home,
    ):
        args = [
            str(LEROBOT_VENV / "bin" / "lerobot-record"),
            "--robot.type=telerobot", f"--robot.camera_width={width}",
            f"--robot.camera_height={height}", f"--robot.fps={fps:g}",
            "--teleop.type=telerobot", "--dataset.repo_id=bench/record-loop",
            f"--dataset.root={home}/ds", "--dataset.single_task=hold",
            "--dataset.num_episodes=1", f"--dataset.episode_time_s={seconds:g}",
            "--dataset.reset_time_s=0", f"--dataset.fps={fps:g}",
            "--dataset.push_to_hub=false", "--play_sounds=false",
        ]  # fmt: skip
        # The plugins are installed in LeRobot's venv (make lerobot-test); Telerobot's
        # client, which they import, comes from this checkout (as in its tests).
        run_env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]),
                   "TELEROBOT_URL": base, "TELEROBOT_OPERATOR_TOKEN": TOKEN,
                   "HF_HOME": f"{home}/hf", "HF_LEROBOT_HOME": f"{home}/lerobot",
                   "HF_HUB_OFFLINE": "1"}  # fmt: skip
        out = subprocess.run(
            args, stdin=subprocess.DEVNULL, capture_output=True, text=True,
            timeout=seconds + 300, env=run_env,
        )  # fmt: skip
        said = out.stdout + out.stderr
        if out.returncode != 0:
            raise RuntimeError(f"lerobot-record exited with {out.returncode}:\n{said[-3000:]}")
        info = json.loads((Path(home) / "ds" / "meta" / "info.json").read_text())
    frames = int(info["total_frames"])
    slow = [float(v) for v in SLOWER.findall(said)]
    rates = np.array(slow + [fps] * max(0, frames - len(slow)))
    return {
        "p50": round(float(np.percentile(rates, 50)), 2) if len(rates) else None,
        "min": round(float(rates.min()), 2) if len(rates) else None,
        "mean": round(frames / seconds, 2),
        "frames": frames,
        "slow_iterations": len(slow),
        "seconds": seconds,
    }


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--busy-core", action="store_true", help="one core kept busy (stress-ng)")
    p.add_argument("--record-seconds", type=float, default=30.0,
                   help="lerobot-record's episode for record_loop_hz (0: none)")  # fmt: skip
    args = p.parse_args()
    with busy_core(args.busy_core):
        figures = measure(args.seconds, args.fps, args.width, args.height)
        if args.record_seconds > 0:
            figures["record_loop_hz"] = record_loop(
                args.record_seconds, args.fps, args.width, args.height
            )
    emit({**figures, "busy_core": args.busy_core, "machine": machine()}, args.json)


if __name__ == "__main__":
    main()
