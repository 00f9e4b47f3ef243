"""A LeRobot policy driving a Telerobot server through the robot plugin, supervised: the
policy part of bench.rollout, run in LeRobot's own venv (Python 3.12, torch).

    <lerobot venv>/bin/python -m bench.rollout_policy --url URL --token TOKEN [--json]
        [--policy DIR] [--seconds 20] [--episodes 20] [--handovers 10]
        [--width 320 --height 240]
    <lerobot venv>/bin/python -m bench.rollout_policy --train DIR [--demos 30] [--steps 3000]

``TOKEN`` is the operator's: the policy joins with a policy token it issues (a policy
never joins with the operator token) and starts paused; the bench, as the person, lets it
drive (``person_resumes``: the resumes it needed; an operator's move handed back, as every
placement here is, lets it drive too). The last line's keys:

- ``obs_to_action_ms`` ``{"p50", "p99"}``: at 30 Hz, each step's observation (its frame's
  capture time, the server's clock) → the server applying the first increment toward the
  action computed from it (the plugin's ACK times). ACT computes a chunk of actions at
  once and hands one out per step: most steps take a queued action, one in
  ``n_action_steps`` runs the network (``chunk_ms``). Without ``--policy``: a small ACT
  built from the robot's own features, untrained (the plumbing is measured, not the
  skill), saved and loaded back the way ``lerobot-rollout`` loads one
  (``PreTrainedConfig.from_pretrained``, ``make_pre_post_processors``).
- ``handover_jump_mm`` / ``handover_jump_rad``: ``--handovers`` trials of the ACT driving
  (absolute joint targets through the plugin, which re-anchors on the arm when control
  comes back) while an operator takes over over REST 1 s into the trial (POST /lease),
  holds control 0.5 s and hands back (DELETE /lease): the worst tool and joint step
  between two consecutive STATEs (50 Hz) within 0.5 s after each takeover and each
  hand-back (``handover_jump_mm_by_kind``). ``steady_step_mm`` / ``steady_step_rad``:
  the largest while control stayed put (the ACT's own motion). With ``--policy``, each
  trial starts from a held-out start (mid-reach at the takeover).
- With ``--policy``, the reach task (``Reach``: the tool from a start to 3 cm above the
  block within 8 s; a success if it ends within 15 mm). The demonstrations' starts are
  drawn from ``TRAINING_SEED`` (``--train`` keeps them in ``starts.json`` beside the
  policy; without it they are drawn again), the evaluation's held-out starts from
  ``HELD_OUT_SEED``: ``start_seeds`` ``{"training", "held_out"}``,
  ``held_out_from_training_rad`` ``{"min", "median"}`` (each held-out start's largest
  joint difference to the nearest demonstration start; none is one). ``success_rate``:
  ``held_out`` and ``training_starts`` (unsupervised, ``--episodes`` each, the first
  demonstrations' starts), ``supervised`` (the held-out starts again, a scripted
  supervisor taking over when the policy stopped getting closer for 1.5 s, driving 70 %
  of the rest and handing back). ``supervisor_path_share``: the tool's path driven while
  the supervisor held control / the tool's whole path in the supervised episodes (a
  supervised success is not the policy's alone). ``interventions_per_episode``,
  ``final_distance_mm`` (medians) and ``ended_paused`` (episodes that ended with the
  policy paused: stopped by the force limit, say, with nobody there to let it go on).
- ``--train DIR``: records ``--demos`` scripted demonstrations of the reach task through
  a server it starts, exports them (the LeRobot export), trains a small ACT on the CPU
  with ``lerobot-train`` and leaves the policy in ``DIR/pretrained_model`` with its
  ``starts.json``. On a 2-core machine with other work on it, set ``OMP_NUM_THREADS=1``:
  with another process busy on a core, a step took 4.8–9 s with torch's two threads and
  1.1–1.8 s with one (docs/PERFORMANCE.md, issue 49).
"""

from __future__ import annotations

import argparse
import functools
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
from harness.lerobot_policy import (
    FPS,
    SMALL_ACT,
    build_untrained,
    make_robot,
    policy_observation_features,
)

REPO = Path(__file__).resolve().parents[1]
SUCCESS_M = 0.015  # the tool this near the goal at the episode's end: a success
EPISODE_S = 8.0
START_SPREAD_RAD = 0.35  # each start: home + this much at most on the first three joints
# The trained policy's cameras: small, so it trains on a CPU (a training step took 1.8 s
# with a 320×240 pair here); rolled out, the plugin resizes the server's frames to it.
TRAIN_SIZE = (160, 120)  # (the least video the server makes: 120 rows)
# The start poses' streams: the demonstrations' (training) and the evaluation's held-out
# starts are drawn from different seeds; --train keeps its starts in STARTS_FILE.
TRAINING_SEED = 11
HELD_OUT_SEED = 4904
STARTS_FILE = "starts.json"


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
        if capture is not None and arm.has_control:
            steps.append((capture, sent))
        next_step += period
        time.sleep(max(0.0, next_step - time.perf_counter()))
    return steps


def obs_to_action(robot: Any, steps: list[tuple[float, float]]) -> list[float]:
    """Each step's capture → the first increment the server applied after it was sent."""
    applied = np.array(list(robot.arm.only.mirror.applied_at))
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
        self.http = httpx.Client(
            base_url=url + "api/v1/", headers={"Authorization": f"Bearer {token}"}, timeout=30
        )
        block = next(b for b in self.http.get("workcell").json()["boxes"] if b["name"] == "block")
        self.goal = np.array(block["centre"]) + [0.0, 0.0, block["size"][2] / 2 + 0.03]
        # The model's home pose, wherever the arm is now (bench.rollout's stub and master
        # moved it first): the starts are drawn around it, the goal keeps its orientation.
        model = self.http.get("robot/model").json()
        self.home = np.array(model["named_poses"][model["home_pose"]], float)
        self.place(self.home, name="reach-setup")
        with Telerobot(url, token, name="reach-setup") as arm:
            arm.move_cartesian(self.goal.tolist())  # (keeping the tool's orientation)
            self.goal_joints = np.array(arm.state()["joints"])
        self.place(self.home, name="reach-setup")

    def start(self, rng: np.random.Generator) -> np.ndarray:
        """The next start pose drawn from ``rng`` the task can be done from: the straight
        joint path from it to the goal (the demonstrations' path) touches nothing (tried
        once by a REST move; a draw that fails is skipped)."""
        from telerobot.client.rest import TelerobotError

        while True:
            q = self.home.copy()
            q[:3] += rng.uniform(-START_SPREAD_RAD, START_SPREAD_RAD, 3)
            try:
                self.place(q, name="reach-start")
                self.place(self.goal_joints, name="reach-start")
            except TelerobotError:
                continue
            if self.distance() < SUCCESS_M / 3:
                return q

    def starts(self, seed: int, n: int) -> list[np.ndarray]:
        """The first ``n`` start poses of the stream ``seed`` (as ``start`` draws them)."""
        rng = np.random.default_rng(seed)
        return [self.start(rng) for _ in range(n)]

    def tool(self) -> np.ndarray:
        return np.array(self.http.get("robot/state").json()["position"])

    def distance(self) -> float:
        return float(np.linalg.norm(self.tool() - self.goal))

    def place(self, q: np.ndarray, name: str = "reset") -> None:
        """Move the arm to ``q`` as an operator (from a policy: a takeover, handed back);
        pressed into something (the force limit), it first backs away along the contact's
        force (the server allows only moves that back away)."""
        from telerobot.client import Telerobot

        with Telerobot(self.url, self.token, name=name) as arm:
            for _ in range(4):  # (one relative move may go 20 mm at most)
                if not self.http.get("safety").json()["force_limited"]:
                    break
                arm.move_cartesian((0.015 * self.away()).tolist(), relative=True)
            arm.move_joints(q.tolist())

    def away(self) -> np.ndarray:
        """The direction away from the contact: the force on the tool in the base frame
        (up when there is too little of it to tell)."""
        state = self.http.get("robot/state").json()
        latest = self.http.get("force").json()["latest"]
        f = np.array(state["rotation"]) @ np.array(latest["values"][:3]) if latest else np.zeros(3)
        n = float(np.linalg.norm(f))
        return f / n if n > 1.0 else np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------ people and the tool's path
class Person:
    """The person supervising, over REST with the operator token: lets the policy drive
    (a resume) and takes over and hands back (POST /lease, DELETE /lease)."""

    def __init__(self, url: str, token: str, robot: Any) -> None:
        self.url, self.token = url, token
        self.http = httpx.Client(
            base_url=url + "api/v1/", headers={"Authorization": f"Bearer {token}"}, timeout=30
        )
        self.now = robot.arm._server_now  # the server's clock
        self.resumes = 0  # a person's go other than a hand-back

    def mode(self) -> str:
        return str(self.http.get("autonomy").json()["mode"])

    def let_drive(self) -> None:
        """The policy drives: if nothing handed it back (it joined, or was stopped), a
        person resumes it."""
        from harness.policy_stub import resume_policy

        if self.mode() != "autonomous":
            resume_policy(self.url, self.token)
            self.resumes += 1
        if self.mode() != "autonomous":
            raise RuntimeError(f"the policy does not drive: {self.http.get('autonomy').json()}")

    def take_over(self) -> tuple[str, float]:
        """An operator takes control from the policy: its client id, and when it asked
        (server clock)."""
        asked = self.now()
        r = self.http.post("lease", json={"name": "bench-operator"})
        r.raise_for_status()
        return str(r.json()["client_id"]), asked

    def hand_back(self, client_id: str) -> float:
        """The operator releases: control goes back to the policy, AUTONOMOUS (a hand-back
        is a person's go). When it asked (server clock)."""
        asked = self.now()
        self.http.delete("lease", headers={"X-Client-Id": client_id}).raise_for_status()
        return asked


class Track:
    """Every STATE the policy's link receives: the tool's position and the joints, on the
    server's clock (the plugin's own handler still gets each)."""

    def __init__(self, robot: Any) -> None:
        self._lock = threading.Lock()
        self.t: list[float] = []
        self.p: list[np.ndarray] = []
        self.q: list[np.ndarray] = []
        link = robot.arm.link
        before = link.on_state

        def on_state(fields: dict[str, Any]) -> None:
            with self._lock:
                self.t.append(float(fields["server_time"]))
                self.p.append(np.array([fields["x"], fields["y"], fields["z"]], float))
                self.q.append(np.array(fields["joints"], float))
            if before is not None:
                before(fields)

        link.on_state = on_state

    def _within(self, since: float, until: float) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            t = np.array(self.t)
            keep = (t >= since) & (t <= until)
            p = np.array(self.p)[keep] if keep.any() else np.zeros((0, 3))
            q = np.array(self.q)[keep] if keep.any() else np.zeros((0, 6))
        return p, q

    def largest_steps(self, since: float, until: float) -> tuple[float, float]:
        """The largest tool move (m) and joint move (rad) between two consecutive STATEs
        (50 Hz) within [since, until]."""
        p, q = self._within(since, until)
        if len(p) < 2:
            return 0.0, 0.0
        return (
            float(np.linalg.norm(np.diff(p, axis=0), axis=1).max()),
            float(np.abs(np.diff(q, axis=0)).max()),
        )

    def path_m(self, since: float, until: float) -> float:
        """The length of the tool's path within [since, until]."""
        p, _ = self._within(since, until)
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def hold_still(robot: Any) -> None:
    """The plugin forgets the policy's last target: the arm stays where it is put until
    the policy's next action (an episode starts at its start pose, not on its way back to
    the previous episode's last target)."""
    robot.arm._targets.target = None


# ------------------------------------------------------------ handovers with the ACT
HANDOVER_TRIAL_S = 4.0  # each trial: the policy drives this long
TAKE_AT_S = 1.0  # an operator takes over this long into it (a trained policy: mid-reach)
HOLD_S = 0.5  # holds control this long, then hands back
AFTER_S = 0.5  # a handover's jump: the steps this long after it (as bench.rollout)


def act_handovers(
    robot: Any,
    policy: Policy,
    person: Person,
    track: Track,
    n: int,
    reach: Reach | None,
    starts: list[np.ndarray],
) -> dict[str, Any]:
    """``n`` trials of the ACT driving through the plugin (absolute joint targets) while
    an operator takes over over REST, holds control HOLD_S and hands back: the worst tool
    and joint step between consecutive STATEs within AFTER_S after each takeover and each
    hand-back, against the largest while control stayed put (the policy's own motion).
    With ``reach``, each trial starts from the next of ``starts`` (held out)."""
    after: dict[str, list[tuple[float, float]]] = {"takeover": [], "hand_back": []}
    steady: list[tuple[float, float]] = []
    for i in range(n):
        if reach is not None:
            hold_still(robot)
            reach.place(starts[i % len(starts)])
        person.let_drive()
        policy.reset()
        t0 = person.now()
        driver = threading.Thread(target=run_loop, args=(robot, policy, HANDOVER_TRIAL_S))
        driver.start()
        time.sleep(TAKE_AT_S)
        client, took = person.take_over()
        time.sleep(HOLD_S)
        back = person.hand_back(client)
        driver.join(HANDOVER_TRIAL_S + 30)
        t1 = person.now()
        after["takeover"].append(track.largest_steps(took, took + AFTER_S))
        after["hand_back"].append(track.largest_steps(back, back + AFTER_S))
        steady.append(track.largest_steps(t0, took))
        if back + AFTER_S < t1:
            steady.append(track.largest_steps(back + AFTER_S, t1))
    worst = {k: (max(s[0] for s in v), max(s[1] for s in v)) for k, v in after.items()}
    jump = max(w[0] for w in worst.values()), max(w[1] for w in worst.values())
    still = max(s[0] for s in steady), max(s[1] for s in steady)
    return {
        "handover_jump_mm": round(jump[0] * 1000, 3),
        "handover_jump_rad": round(jump[1], 5),
        "steady_step_mm": round(still[0] * 1000, 3),
        "steady_step_rad": round(still[1], 5),
        "handover_jump_mm_by_kind": {k: round(w[0] * 1000, 3) for k, w in worst.items()},
        "handovers": n,
    }


# ------------------------------------------------------------ evaluating
def evaluate(
    robot: Any,
    policy: Policy,
    reach: Reach,
    person: Person,
    track: Track,
    starts: list[np.ndarray],
    supervised: bool,
) -> dict[str, Any]:
    """An episode from each of ``starts``; with ``supervised``, a scripted supervisor
    corrects a policy that stopped getting closer (it drives 70 % of the way, then hands
    back), and the tool's path is split between the supervisor's control and the
    policy's."""
    from telerobot.client.rest import TelerobotError

    successes, interventions, finals, paused = 0, [], [], 0
    path_m = supervisor_m = 0.0
    for start in starts:
        hold_still(robot)
        reach.place(start)  # (an operator's move, handed back: the policy may drive)
        person.let_drive()
        policy.reset()
        stop = threading.Event()
        driver = threading.Thread(target=run_loop, args=(robot, policy, EPISODE_S, stop))
        began = person.now()
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
                took = person.now()
                try:
                    reach.place(q + 0.7 * (reach.goal_joints - q), name="supervisor")
                except TelerobotError as exc:  # said, and the episode goes on
                    print(f"the supervisor's correction failed: {exc}", file=sys.stderr)
                supervisor_m += track.path_m(took, person.now())
                corrections += 1
                best, best_at = reach.distance(), time.monotonic()
            time.sleep(0.1)
        stop.set()
        driver.join(EPISODE_S + 5)
        final = reach.distance()  # where the policy left the tool: held at the goal?
        path_m += track.path_m(began, person.now())
        paused += person.mode() != "autonomous"
        finals.append(final)
        successes += final < SUCCESS_M
        interventions.append(corrections)
    return {
        "success_rate": round(successes / len(starts), 3),
        "interventions": interventions,
        "final_mm": [round(f * 1000, 1) for f in finals],
        "ended_paused": paused,
        "supervisor_path_share": round(supervisor_m / path_m, 3) if path_m else None,
    }


def training_starts(policy: Path, reach: Reach, n: int) -> tuple[list[np.ndarray], str]:
    """The demonstrations' starts: all of STARTS_FILE beside the policy (--train leaves
    it), else the first ``n`` drawn again from TRAINING_SEED as --train drew them (the
    same server, the same draws skipped); and where they came from."""
    for folder in (policy, *policy.parents[:4]):
        if (folder / STARTS_FILE).is_file():
            said = json.loads((folder / STARTS_FILE).read_text())
            if said["seed"] != TRAINING_SEED:
                raise ValueError(f"{folder / STARTS_FILE}: seed {said['seed']}")
            return [np.array(q) for q in said["starts"]], str(folder / STARTS_FILE)
    return reach.starts(TRAINING_SEED, n), f"drawn again from seed {TRAINING_SEED}"


def apart(held_out: list[np.ndarray], training: list[np.ndarray]) -> dict[str, float]:
    """How far each held-out start is from the nearest training start (the largest joint
    difference, rad); none may be a training start."""
    nearest = [min(float(np.abs(h - t).max()) for t in training) for h in held_out]
    assert min(nearest) > 1e-6, "a held-out start is a training start"
    return {"min": round(min(nearest), 4), "median": round(float(np.median(nearest)), 4)}


# ------------------------------------------------------------ training
def train(out: Path, demos: int, steps: int, width: int, height: int) -> Path:
    """Demonstrations of the reach task through a server started here, exported, and a
    small ACT trained on them with lerobot-train: ``out/pretrained_model``."""
    from harness.servers import serve_for_bench
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
        rng = np.random.default_rng(TRAINING_SEED)
        starts: list[list[float]] = []
        for i in range(demos):
            q0 = reach.start(rng)
            starts.append(q0.tolist())
            reach.place(q0)
            http.post("recordings/active/episodes", json={"task": "reach above the block"})
            arm = TelerobotArm(ArmOptions(url, token, name="demonstrator", cameras=False))
            arm.connect()
            try:
                units = arm.only.units
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
    said = {"seed": TRAINING_SEED, "starts": starts}
    (out / STARTS_FILE).write_text(json.dumps(said))
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
    policy = out / "pretrained_model"  # the policy, with its demonstrations' starts
    if policy.exists():
        shutil.rmtree(policy)
    shutil.copytree(last, policy)
    shutil.copy(out / STARTS_FILE, policy / STARTS_FILE)
    return policy


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url")
    p.add_argument("--token")
    p.add_argument("--json", action="store_true")
    p.add_argument("--policy", type=Path)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--episodes", type=int, default=20, help="of each kind")
    p.add_argument("--handovers", type=int, default=10, help="takeovers and hand-backs")
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
    out: dict[str, Any] = {}
    reach, held_out, training = None, [], []
    if args.policy:  # its cameras' size, as it was trained
        features = json.loads((args.policy / "config.json").read_text())["input_features"]
        args.height, args.width = features["observation.images.left"]["shape"][1:]
        # The starts, before the policy joins: the demonstrations' and the held-out ones.
        reach = Reach(args.url, args.token)
        training, said = training_starts(args.policy, reach, args.episodes)
        held_out = reach.starts(HELD_OUT_SEED, args.episodes)
        out["start_seeds"] = {"training": TRAINING_SEED, "held_out": HELD_OUT_SEED}
        out["training_starts_from"] = said
        out["held_out_from_training_rad"] = apart(held_out, training)
        training = training[: args.episodes]
    out["camera"] = f"{args.width}x{args.height} each, {FPS:g} fps"
    robot = make_robot(args.url, args.token, args.width, args.height)
    with tempfile.TemporaryDirectory() as tmp:
        robot.connect()
        path = args.policy or build_untrained(
            Path(tmp) / "untrained", robot, robot.get_observation()
        )
        try:
            policy = Policy(path, robot)
            person = Person(args.url, args.token, robot)
            track = Track(robot)
            if reach is not None:  # the trained policy at its task
                hold_still(robot)
                reach.place(held_out[0])
            person.let_drive()  # (it took control paused: a person's go)
            policy.reset()
            steps = run_loop(robot, policy, args.seconds)
            out["obs_to_action_ms"] = p50_p99(obs_to_action(robot, steps))
            out["chunk_ms"] = p50_p99(policy.chunk_ms)
            out["steps"] = len(steps)
            out["policy"] = "trained: " + str(args.policy) if args.policy else "ACT, untrained"
            out.update(act_handovers(robot, policy, person, track, args.handovers, reach, held_out))
            if reach is not None:
                run = functools.partial(evaluate, robot, policy, reach, person, track)
                free = run(held_out, supervised=False)
                seen = run(training, supervised=False)
                helped = run(held_out, supervised=True)
                out["success_rate"] = {"held_out": free["success_rate"],
                                       "training_starts": seen["success_rate"],
                                       "supervised": helped["success_rate"]}  # fmt: skip
                out["supervisor_path_share"] = helped["supervisor_path_share"]
                out["interventions_per_episode"] = round(float(np.mean(helped["interventions"])), 2)
                out["final_distance_mm"] = {
                    "held_out": float(np.median(free["final_mm"])),
                    "training_starts": float(np.median(seen["final_mm"])),
                    "supervised": float(np.median(helped["final_mm"])),
                }
                out["ended_paused"] = {"held_out": free["ended_paused"],
                                       "training_starts": seen["ended_paused"],
                                       "supervised": helped["ended_paused"]}  # fmt: skip
                out["episodes"] = {"held_out": len(held_out), "training_starts": len(training),
                                   "supervised": len(held_out)}  # fmt: skip
                out["success_within_mm"] = SUCCESS_M * 1000
                out["episode_s"] = EPISODE_S
            else:
                out["success_rate"] = None
                out["supervisor_path_share"] = None
                out["interventions_per_episode"] = None
            out["person_resumes"] = person.resumes
        finally:
            robot.disconnect()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
