"""A LeRobot policy driving a Telerobot server through the robot plugin, supervised: the
policy part of bench.rollout, run in LeRobot's own venv (Python 3.12, torch).

    <lerobot venv>/bin/python -m bench.rollout_policy --url URL --token TOKEN [--json]
        [--policy DIR] [--seconds 20] [--episodes 20] [--width 320 --height 240]
    <lerobot venv>/bin/python -m bench.rollout_policy --train DIR [--demos 30] [--steps 3000]

- Without ``--policy``: a small ACT built from the robot's own features, untrained (the
  plumbing is measured, not the skill), saved and loaded back the way ``lerobot-rollout``
  loads one (``PreTrainedConfig.from_pretrained``, ``make_pre_post_processors``).
- ``obs_to_action_ms`` ``{"p50", "p99"}``: at 30 Hz, each step's observation (its frame's
  capture time, the server's clock) → the server applying the first increment toward the
  action computed from it (the plugin's ACK times). ACT computes a chunk of actions at
  once and hands one out per step: most steps take a queued action, one in
  ``n_action_steps`` runs the network (``chunk_ms``).
- With ``--policy``, the reach task (``reach.py``): ``success_rate`` ``{"unsupervised",
  "supervised"}`` over ``--episodes`` each, and ``interventions_per_episode`` (a scripted
  supervisor takes over when the policy stops getting closer, drives part of the way and
  hands back).
- ``--train DIR``: records ``--demos`` scripted demonstrations of the reach task through
  a server it starts, exports them (the LeRobot export), trains a small ACT on the CPU
  with ``lerobot-train`` and leaves the policy in ``DIR/pretrained_model``.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from bench.common import p50_p99

REPO = Path(__file__).resolve().parents[1]
FPS = 30.0
SUCCESS_M = 0.015  # the tool this near the goal at the episode's end: a success
EPISODE_S = 8.0
START_SPREAD_RAD = 0.35  # each start: home + this much at most on the first three joints
# The trained policy's cameras: small, so it trains on a CPU (a training step took 1.8 s
# with a 320×240 pair here); rolled out, the plugin resizes the server's frames to it.
TRAIN_SIZE = (160, 120)  # (the least video the server makes: 120 rows)


# ------------------------------------------------------------ the policy
class Policy:
    """A LeRobot policy and its processors, loaded from ``path`` as lerobot-rollout
    loads one, stepping from a robot observation to a robot action."""

    def __init__(self, path: Path, robot: Any) -> None:
        import torch
        from lerobot.configs import PreTrainedConfig
        from lerobot.policies import get_policy_class, make_pre_post_processors
        from lerobot.utils.feature_utils import combine_feature_dicts, hw_to_dataset_features

        torch.set_num_threads(2)
        self.torch = torch
        cfg = PreTrainedConfig.from_pretrained(str(path))
        cfg.pretrained_path = str(path)
        self.policy = get_policy_class(cfg.type).from_pretrained(str(path), config=cfg)
        self.policy.to("cpu").eval()
        self.pre, self.post = make_pre_post_processors(
            cfg,
            pretrained_path=str(path),
            preprocessor_overrides={"device_processor": {"device": "cpu"}},
        )
        self.features = combine_feature_dicts(
            hw_to_dataset_features(robot.action_features, "action"),
            hw_to_dataset_features(policy_observation_features(robot), "observation"),
        )
        self.robot_type = robot.robot_type
        self.inputs = dict(cfg.input_features)
        self.arm = robot.arm
        self.chunk_ms: list[float] = []

    def reset(self) -> None:
        self.policy.reset()
        self.pre.reset()
        self.post.reset()

    def __call__(self, observation: dict[str, Any]) -> dict[str, float]:
        from lerobot.policies.utils import make_robot_action, prepare_observation_for_inference
        from lerobot.utils.feature_utils import build_dataset_frame

        if "observation.tool_pose" in self.inputs or "observation.force" in self.inputs:
            frame = self._export_frame(observation)  # a policy trained on an export
        else:
            frame = build_dataset_frame(self.features, observation, prefix="observation")
        queued = len(getattr(self.policy, "_action_queue", ()) or ())
        started = time.perf_counter()
        with self.torch.inference_mode():
            batch = prepare_observation_for_inference(
                frame, self.torch.device("cpu"), "", self.robot_type
            )
            action = self.post(self.policy.select_action(self.pre(batch)))
        if queued == 0:
            self.chunk_ms.append((time.perf_counter() - started) * 1000)
        return {k: float(v) for k, v in make_robot_action(action, self.features).items()}

    def _export_frame(self, observation: dict[str, Any]) -> dict[str, Any]:
        """The inputs of a policy trained on Telerobot's LeRobot export: the joints as
        ``observation.state``, the force and the tool's pose as features of their own
        (the export's columns), the cameras."""
        joints = [k for k in observation if k.endswith(".pos")]
        frame: dict[str, Any] = {}
        for key in self.inputs:
            if key == "observation.state":
                frame[key] = np.array([observation[k] for k in joints], np.float32)
            elif key == "observation.force":
                forces = ("fx", "fy", "fz", "tx", "ty", "tz")
                frame[key] = np.array([observation[f"force.{n}"] for n in forces], np.float32)
            elif key == "observation.tool_pose":
                t = self.arm.last_capture_time or self.arm._server_now()
                frame[key] = self.arm.tool_pose_at(t).astype(np.float32)
            elif key.startswith("observation.images."):
                frame[key] = observation[key.removeprefix("observation.images.")]
        return frame


def policy_observation_features(robot: Any) -> dict[str, Any]:
    """What the policy sees: the joints (``.pos``) and the cameras, as lerobot-rollout
    passes them (it leaves out other floats, the forces among them)."""
    return {
        k: v
        for k, v in robot.observation_features.items()
        if not (v is float and not k.endswith(".pos"))
    }


def build_untrained(path: Path, robot: Any, around: dict[str, Any] | None = None) -> Path:
    """A small ACT for this robot's features, untrained, no downloaded weights. With
    ``around`` (an observation), its normalisation is centred there (1° spread), so its
    untrained actions stay near that pose rather than near every joint's zero."""
    from lerobot.configs import FeatureType
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.utils.feature_utils import (
        combine_feature_dicts,
        dataset_to_policy_features,
        hw_to_dataset_features,
    )

    features = dataset_to_policy_features(
        combine_feature_dicts(
            hw_to_dataset_features(robot.action_features, "action"),
            hw_to_dataset_features(policy_observation_features(robot), "observation"),
        )
    )
    cfg = ACTConfig(
        input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
        output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        device="cpu",
        pretrained_backbone_weights=None,
        **SMALL_ACT,
    )
    stats = None
    if around is not None:
        pos = np.array([float(around[k]) for k in robot.action_features], np.float32)
        spread = {"mean": pos, "std": np.ones_like(pos)}
        stats = {"observation.state": spread, "action": spread}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    ACTPolicy(cfg).save_pretrained(str(path))
    pre.save_pretrained(str(path))
    post.save_pretrained(str(path))
    return path


SMALL_ACT: dict[str, Any] = {
    "dim_model": 128,
    "n_heads": 4,
    "dim_feedforward": 512,
    "n_encoder_layers": 2,
    "n_decoder_layers": 1,
    "n_vae_encoder_layers": 2,
    "latent_dim": 16,
    "chunk_size": 30,
    "n_action_steps": 15,
}


def make_robot(url: str, token: str, width: int, height: int, name: str = "act-policy") -> Any:
    """The robot plugin as a policy: ``token`` is the operator's, which issues the policy
    a policy token of its own (a policy never joins with the operator token). It takes
    control paused: a person lets it drive (a resume, or an operator's move handed back)."""
    from lerobot_robot_telerobot.config_telerobot import TelerobotConfig
    from lerobot_robot_telerobot.telerobot import Telerobot

    from bench.policy_stub import issue_policy_token

    secret = issue_policy_token(url, token, name)
    config = TelerobotConfig(url=url, token=token, client_name=name, camera_width=width,
                             camera_height=height, fps=FPS, policy=True,
                             policy_token=secret)  # fmt: skip
    return Telerobot(config)


# ------------------------------------------------------------ the loop
def run_loop(
    robot: Any, policy: Policy, seconds: float, stop: threading.Event | None = None
) -> list[tuple[float, float]]:
    """Steps at FPS for ``seconds``: (frame capture time, action sent) per step, both on
    the server's clock."""
    steps: list[tuple[float, float]] = []
    arm = robot.arm
    period = 1.0 / FPS
    t0 = time.perf_counter()
    next_step = t0
    while time.perf_counter() - t0 < seconds and not (stop and stop.is_set()):
        observation = robot.get_observation()
        capture = arm.last_capture_time
        action = policy(observation)
        sent = arm._server_now()
        robot.send_action(action)
        if capture is not None and arm.mirror is not None and arm.mirror.has_control:
            steps.append((capture, sent))
        next_step += period
        time.sleep(max(0.0, next_step - time.perf_counter()))
    return steps


def obs_to_action(robot: Any, steps: list[tuple[float, float]]) -> list[float]:
    """Each step's capture → the first increment the server applied after it was sent."""
    applied = np.array(list(robot.arm.mirror.applied_at))
    out = []
    for capture, sent in steps:
        later = applied[applied > sent]
        if len(later) and later[0] - sent < 0.2:
            out.append((later[0] - capture) * 1000)
    return out


# ------------------------------------------------------------ the reach task
class Reach:
    """The task: bring the tool from a varied start to just above the block (3 cm over
    its top's centre) within EPISODE_S. The goal's joints are found once by a REST move."""

    def __init__(self, url: str, token: str) -> None:
        from telerobot.client import Telerobot

        self.url, self.token = url, token
        self.http = httpx.Client(base_url=url + "api/v1/", timeout=30)
        block = next(b for b in self.http.get("workcell").json()["boxes"] if b["name"] == "block")
        self.goal = np.array(block["centre"]) + [0.0, 0.0, block["size"][2] / 2 + 0.03]
        # (made before anything else moves the arm: it starts at home)
        with Telerobot(url, token, name="reach-setup") as arm:
            self.home = np.array(arm.state()["joints"])
            arm.move_cartesian(self.goal.tolist())  # (keeping the tool's orientation)
            self.goal_joints = np.array(arm.state()["joints"])
        self.place(self.home, name="reach-setup")
        self.rng = np.random.default_rng(11)

    def start(self) -> np.ndarray:
        """A start pose the task can be done from: the straight joint path from it to the
        goal (the demonstrations' path) touches nothing (tried once by a REST move)."""
        from telerobot.client.rest import TelerobotError

        while True:
            q = self.home.copy()
            q[:3] += self.rng.uniform(-START_SPREAD_RAD, START_SPREAD_RAD, 3)
            try:
                self.place(q, name="reach-start")
                self.place(self.goal_joints, name="reach-start")
            except TelerobotError:
                continue
            if self.distance() < SUCCESS_M / 3:
                return q

    def tool(self) -> np.ndarray:
        return np.array(self.http.get("robot/state").json()["position"])

    def distance(self) -> float:
        return float(np.linalg.norm(self.tool() - self.goal))

    def place(self, q: np.ndarray, name: str = "reset") -> None:
        """Move the arm to ``q`` as an operator (from a policy: a takeover, handed back);
        pressed into something (the force limit), it first backs away upward."""
        from telerobot.client import Telerobot

        with Telerobot(self.url, self.token, name=name) as arm:
            for _ in range(3):  # (one relative move may go 20 mm at most)
                if not self.http.get("safety").json()["force_limited"]:
                    break
                arm.move_cartesian([0.0, 0.0, 0.015], relative=True)
            arm.move_joints(q.tolist())


def evaluate(
    robot: Any, policy: Policy, reach: Reach, episodes: int, supervised: bool
) -> dict[str, Any]:
    """``episodes`` of the task; with ``supervised``, a scripted supervisor corrects a
    policy that stopped getting closer (it drives 70 % of the way, then hands back)."""
    from telerobot.client.rest import TelerobotError

    successes, interventions, finals = 0, [], []
    for _ in range(episodes):
        reach.place(reach.start())
        policy.reset()
        stop = threading.Event()
        driver = threading.Thread(target=run_loop, args=(robot, policy, EPISODE_S, stop))
        driver.start()
        t0 = time.monotonic()
        best, best_at, corrections = math.inf, t0, 0
        while driver.is_alive():
            d = reach.distance()
            now = time.monotonic()
            if d < best - 0.005:
                best, best_at = d, now
            if supervised and d > SUCCESS_M and now - best_at > 1.5 and now - t0 > 2.0:
                q = np.array(reach.http.get("robot/state").json()["joints"])
                try:
                    reach.place(q + 0.7 * (reach.goal_joints - q), name="supervisor")
                except TelerobotError as exc:  # said, and the episode goes on
                    print(f"the supervisor's correction failed: {exc}", file=sys.stderr)
                corrections += 1
                best, best_at = reach.distance(), time.monotonic()
            time.sleep(0.1)
        stop.set()
        driver.join(EPISODE_S + 5)
        final = reach.distance()  # where the policy left the tool: held at the goal?
        finals.append(final)
        successes += final < SUCCESS_M
        interventions.append(corrections)
    return {
        "success_rate": successes / episodes,
        "interventions": interventions,
        "final_mm": [round(f * 1000, 1) for f in finals],
    }


# ------------------------------------------------------------ training
def train(out: Path, demos: int, steps: int, width: int, height: int) -> Path:
    """Demonstrations of the reach task through a server started here, exported, and a
    small ACT trained on them with lerobot-train: ``out/pretrained_model``."""
    from bench.common import serve_for_bench
    from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm

    try:
        import accelerate  # noqa: F401  (lerobot-train needs it; make test's venv has none)
    except ImportError:
        sys.exit(
            f"lerobot-train needs LeRobot's training extra: {sys.executable} -m pip install "
            "'lerobot[dataset,feetech,training]==0.6.1'"
        )

    token = "bench-rollout-train-0123456789abcdef"
    env = {"TELEROBOT_OPERATOR_TOKEN": token, "TELEROBOT_VIDEO": "true",
           "TELEROBOT_SIM_STARTS_AT_HOME": "true", "TELEROBOT_VIDEO_FPS": str(int(FPS)),
           "TELEROBOT_VIDEO_WIDTH": str(width), "TELEROBOT_VIDEO_HEIGHT": str(height)}  # fmt: skip
    exe = REPO / ".venv/bin/telerobot"
    dataset = out / "demos"
    with serve_for_bench(env=env, ready=True, exe=exe) as (_, url):
        reach = Reach(url, token)
        http = httpx.Client(
            base_url=url + "api/v1/", headers={"Authorization": f"Bearer {token}"}, timeout=600
        )
        http.post("recordings", json={"name": "reach-demos"}).raise_for_status()
        for i in range(demos):
            q0 = reach.start()
            reach.place(q0)
            http.post("recordings/active/episodes", json={"task": "reach above the block"})
            arm = TelerobotArm(ArmOptions(url, token, name="demonstrator", cameras=False))
            arm.connect()
            try:
                units = arm.units
                assert units is not None
                move_s = 2.5
                t0 = time.perf_counter()
                while (t := time.perf_counter() - t0) < move_s + 1.0:
                    s = min(t / move_s, 1.0)
                    s = s * s * (3 - 2 * s)  # smooth start and stop
                    q = q0 + s * (reach.goal_joints - q0)
                    arm.send(
                        dict(zip(units.feature_names, units.to_lerobot(q).tolist(), strict=True))
                    )
                    time.sleep(1 / FPS)
            finally:
                arm.disconnect()
            http.post(
                "recordings/active/episodes/end", json={"success": reach.distance() < SUCCESS_M}
            )
            print(
                f"demonstration {i + 1}/{demos}: {reach.distance() * 1000:.1f} mm from the goal",
                flush=True,
            )
        file = http.post("recordings/active/stop").json()["file"]
        made = http.post(f"recordings/{file}/export/lerobot", json={}).json()
        shutil.copytree(made["path"], dataset)
    print(f"exported {made['frames']} rows to {dataset}", flush=True)
    run = out / "train"
    if run.exists():
        shutil.rmtree(run)
    cmd = [str(Path(sys.executable).parent / "lerobot-train"), "--dataset.repo_id=telerobot/reach",
           f"--dataset.root={dataset}", "--dataset.video_backend=pyav", "--policy.type=act",
           "--policy.device=cpu", "--policy.push_to_hub=false",
           "--policy.pretrained_backbone_weights=null",
           *(f"--policy.{k}={v}" for k, v in SMALL_ACT.items()),
           f"--steps={steps}", "--batch_size=8", "--num_workers=0", "--save_freq=100000",
           "--log_freq=100", f"--output_dir={run}", "--wandb.enable=false"]  # fmt: skip
    print(" ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, env={**__import__("os").environ, "HF_HUB_OFFLINE": "1"})
    last = run / "checkpoints" / "last" / "pretrained_model"
    return last


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url")
    p.add_argument("--token")
    p.add_argument("--json", action="store_true")
    p.add_argument("--policy", type=Path)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--width", type=int, default=640, help="of each camera, as the policy sees it")
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--train", type=Path, help="record, export and train into this folder")
    p.add_argument("--demos", type=int, default=30)
    p.add_argument("--steps", type=int, default=3000)
    args = p.parse_args()
    if args.train:
        path = train(args.train, args.demos, args.steps, TRAIN_SIZE[0], TRAIN_SIZE[1])
        print(json.dumps({"policy": str(path)}))
        return
    if args.policy:  # its cameras' size, as it was trained
        features = json.loads((args.policy / "config.json").read_text())["input_features"]
        args.height, args.width = features["observation.images.left"]["shape"][1:]
    out: dict[str, Any] = {"camera": f"{args.width}x{args.height} each, {FPS:g} fps"}
    robot = make_robot(args.url, args.token, args.width, args.height)
    with tempfile.TemporaryDirectory() as tmp:
        robot.connect()
        path = args.policy or build_untrained(
            Path(tmp) / "untrained", robot, robot.get_observation()
        )
        try:
            policy = Policy(path, robot)
            reach = Reach(args.url, args.token) if args.policy else None
            if reach is not None:  # the trained policy at its task
                reach.place(reach.start())
            policy.reset()
            steps = run_loop(robot, policy, args.seconds)
            out["obs_to_action_ms"] = p50_p99(obs_to_action(robot, steps))
            out["chunk_ms"] = p50_p99(policy.chunk_ms)
            out["steps"] = len(steps)
            out["policy"] = "trained: " + str(args.policy) if args.policy else "ACT, untrained"
            if reach is not None:
                free = evaluate(robot, policy, reach, args.episodes, supervised=False)
                helped = evaluate(robot, policy, reach, args.episodes, supervised=True)
                out["success_rate"] = {"unsupervised": free["success_rate"],
                                       "supervised": helped["success_rate"]}  # fmt: skip
                out["interventions_per_episode"] = round(float(np.mean(helped["interventions"])), 2)
                out["final_distance_mm"] = {
                    "unsupervised": float(np.median(free["final_mm"])),
                    "supervised": float(np.median(helped["final_mm"])),
                }
                out["success_within_mm"] = SUCCESS_M * 1000
                out["episode_s"] = EPISODE_S
            else:
                out["success_rate"] = None
                out["interventions_per_episode"] = None
        finally:
            robot.disconnect()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
