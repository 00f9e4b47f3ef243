"""Supervised autonomy: a policy drives the simulated arm, an operator supervises from the
page and the master arm and takes over (docs/lerobot.md, Supervised rollout).

    python -m bench.rollout [--json] [--handovers 20] [--no-page] [--busy-core]
                            [--policy DIR] [--episodes 20] [--act-handovers 10] [--no-policy]

A policy never drives without a person's go: each policy here joins with a policy token
and starts paused; the bench, as the person, resumes it (or an operator's move handed
back lets it drive). The last line's keys:

- ``takeover_ms`` ``{"p50", "p99"}``: an operator's takeover (the page's T key, the
  master's clutch) → the first command of the stub policy refused, as the policy's
  client sees it (both on this machine's clock; the policy sends 30 commands a second,
  so up to a period of it is waiting for its next command). ``policy_period_ms`` for
  scale, and ``takeover_told_ms``: the takeover → the server's EVENT telling the policy
  (the instant from which its commands are refused, no command of its needed).
- ``handover_jump_mm``, ``handover_jump_rad`` ``{"stub", "act"}``: the worst tool and
  joint step between two consecutive STATEs (20 ms apart) within 0.5 s after a takeover
  or a hand-back. ``stub``: the stand-in policy (harness/policy_stub.py: joint 1 ±0.002 rad
  a command) over ``--handovers`` from the page and as many from the simulated master.
  ``act``: LeRobot's ACT (trained with ``--policy``, else untrained) driving through the
  robot plugin (absolute joint targets; the plugin re-anchors on the arm after a
  hand-back) while an operator takes over over REST (POST /lease), holds 0.5 s and hands
  back (DELETE /lease), ``--act-handovers`` times (``act_handover_jump_mm_by_kind``:
  after the takeovers and after the hand-backs). For scale: ``steady_step_mm`` /
  ``steady_step_rad`` ``{"stub", "act"}``, the largest while control stays put (the
  policy's own motion), and ``step_limit_mm`` / ``step_limit_rad``, what the server lets
  one command move (its speed limits over the longest interval it allows, 0.1 s).
- ``obs_to_action_ms`` ``{"p50", "p99"}``: LeRobot's ACT (untrained unless ``--policy``)
  driving through the robot plugin at 30 Hz with both cameras: the observation's frame
  captured → the server applying the first increment toward the action computed from it
  (bench.rollout_policy, in LeRobot's own venv; ``make lerobot-deps`` makes it).
- With ``--policy DIR`` (``python -m bench.rollout_policy --train`` makes one), the
  reach task, ``--episodes`` episodes of each kind (bench.rollout_policy's docstring):
  ``start_seeds`` ``{"training", "held_out"}`` (the demonstrations' starts and the
  evaluation's, drawn from different seeds; ``held_out_from_training_rad``: each held-out
  start's distance to the nearest demonstration start), ``success_rate`` ``{"held_out",
  "training_starts", "supervised"}`` (the first two unsupervised; supervised on the
  held-out starts), ``supervisor_path_share`` (the share of the tool's path in the
  supervised episodes driven while the scripted supervisor held control: a supervised
  success is partly the supervisor's), ``interventions_per_episode``,
  ``final_distance_mm`` and ``ended_paused``. Null without ``--policy``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from bench.common import busy_core, emit, machine, p50_p99, parser
from harness.policy_stub import RATE_HZ, PolicyClient
from harness.servers import serve_for_bench

TOKEN = "bench-rollout-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
REPO = Path(__file__).resolve().parents[1]
LEROBOT_PYTHON = (
    Path(os.environ.get("LEROBOT_VENV", Path.home() / ".cache/telerobot/lerobot-0.6.1"))
    / "bin/python"
)
AFTER_S = 0.5  # a handover's jump: the steps this long after it
MAX_INTERVAL_S = 0.1  # the server's longest interval for one increment's speed limit
STEPS = ("handover_jump_mm", "handover_jump_rad", "steady_step_mm", "steady_step_rad")


def _mode(http: httpx.Client) -> str:
    return str(http.get("autonomy").json()["mode"])


def _wait_mode(http: httpx.Client, mode: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while _mode(http) != mode:
        if time.monotonic() > deadline:
            raise RuntimeError(f"autonomy never became {mode}: {http.get('autonomy').json()}")
        time.sleep(0.01)


class Handovers:
    """Takeovers and releases, with when each was asked for (monotonic)."""

    def __init__(self, policy: PolicyClient) -> None:
        self.policy = policy
        self.takeover_ms: list[float] = []
        self.told_ms: list[float] = []  # the takeover → the policy told it is corrected
        self.times: list[float] = []  # every takeover and release

    def took(self, asked: float) -> None:
        deadline = time.monotonic() + 5
        while not self.policy.refused_since(asked):
            if time.monotonic() > deadline:
                raise RuntimeError("the policy was never refused after a takeover")
            time.sleep(0.001)
        self.takeover_ms.append((self.policy.refused_since(asked)[0].at - asked) * 1000)
        told = self.policy.told_since(asked, "correcting")
        if told is not None:
            self.told_ms.append((told - asked) * 1000)
        self.times.append(asked)

    def jumps(self) -> tuple[float, float]:
        offset = self.policy.link.offset
        worst = [self.policy.largest_steps(t + offset, t + offset + AFTER_S) for t in self.times]
        return max(w[0] for w in worst), max(w[1] for w in worst)


def from_the_page(base: str, http: httpx.Client, log: Handovers, n: int) -> None:
    from playwright.sync_api import sync_playwright

    from harness.chromium import ARGS, yield_browser_session

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(f"{base}?token={TOKEN}")
            yield_browser_session()
            page.wait_for_function(
                "window.telerobot && window.telerobot.state && "
                "document.getElementById('autonomy').textContent.startsWith('AUTONOMOUS')",
                timeout=60_000,
            )
            page.click("#view")
            for _ in range(n):
                asked = time.monotonic()
                page.keyboard.press("t")
                log.took(asked)
                _wait_mode(http, "correcting")
                page.wait_for_function("!document.getElementById('hand-back').hidden")
                time.sleep(0.3)
                log.times.append(time.monotonic())
                page.keyboard.press("h")
                _wait_mode(http, "autonomous")
                time.sleep(0.3)
        finally:
            browser.close()


def from_the_master(base: str, http: httpx.Client, log: Handovers, n: int) -> None:
    from telerobot.client.master.bridge import HAND_BACK_S, BridgeSettings, MasterBridge
    from telerobot.client.master.cli import open_link
    from telerobot.drivers.master.sim import SimMaster

    grip: dict[str, Any] = {"on": False, "since": None}

    def hand(t: float) -> tuple[np.ndarray, bool]:
        # Gripped: 1 cm/s along the device's x from where it was gripped.
        if not grip["on"]:
            grip["since"] = None
            return np.zeros(3), False
        if grip["since"] is None:
            grip["since"] = t
        return np.array([0.01 * (t - grip["since"]), 0.0, 0.0]), True

    device = SimMaster(hand)
    link = open_link(base, TOKEN, datagrams=False)
    bridge = MasterBridge(device, link, BridgeSettings(force_scale=0.05))
    bridge.start(take_control=False)
    try:
        deadline = time.monotonic() + 10
        while link.autonomy != "autonomous":
            if time.monotonic() > deadline:
                raise RuntimeError("the master bridge was never told a policy drives")
            time.sleep(0.01)
        for _ in range(n):
            asked = time.monotonic()
            grip["on"] = True
            log.took(asked)
            _wait_mode(http, "correcting")
            time.sleep(0.4)
            grip["on"] = False
            log.times.append(time.monotonic() + HAND_BACK_S)  # it hands back after this
            _wait_mode(http, "autonomous", timeout=5 + HAND_BACK_S)
            time.sleep(0.3)
    finally:
        bridge.stop()
        link.close()


def handovers(base: str, n: int, page: bool) -> dict[str, Any]:
    from telerobot.server.control.limits import SafetyLimits

    with (
        httpx.Client(base_url=base + "api/v1/", headers=AUTH, timeout=30) as http,
        PolicyClient(base, TOKEN, name="bench-policy") as policy,
    ):
        _wait_mode(http, "autonomous")
        time.sleep(3.0)  # the policy alone: its own steps, for scale
        steady = policy.largest_steps()
        log = Handovers(policy)
        if page:
            from_the_page(base, http, log, n)
        from_the_master(base, http, log, n)
        jump_m, jump_rad = log.jumps()
        said = http.get("autonomy").json()
    limits = SafetyLimits()
    return {
        "takeover_ms": p50_p99(log.takeover_ms),
        "takeover_told_ms": p50_p99(log.told_ms),
        "policy_period_ms": round(1000 / RATE_HZ, 2),
        "handover_jump_mm": round(jump_m * 1000, 3),
        "handover_jump_rad": round(jump_rad, 5),
        "steady_step_mm": round(steady[0] * 1000, 3),
        "steady_step_rad": round(steady[1], 5),
        "step_limit_mm": round(limits.max_speed_m_s * MAX_INTERVAL_S * 1000, 1),
        "step_limit_rad": round(limits.max_joint_speed_rad_s * MAX_INTERVAL_S, 3),
        "handovers": {"page": n if page else 0, "master": n},
        "interventions": said["interventions"],
    }


def with_lerobot(base: str, args: Any) -> dict[str, Any]:
    """bench.rollout_policy in LeRobot's venv against this server: its JSON's figures."""
    if not LEROBOT_PYTHON.exists():
        why = f"no LeRobot venv at {LEROBOT_PYTHON.parent.parent}: make lerobot-deps makes it"
        return {"obs_to_action_ms": None, "policy_note": why}
    cmd = [str(LEROBOT_PYTHON), "-m", "bench.rollout_policy", "--url", base, "--token", TOKEN,
           "--json", "--episodes", str(args.episodes),
           "--handovers", str(args.act_handovers)]  # fmt: skip
    if args.policy:  # (at the size of the images it was trained on)
        cmd += ["--policy", str(args.policy)]
    env = {**os.environ, "PYTHONPATH": str(REPO), "HF_HUB_OFFLINE": "1"}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        sys.stderr.write(done.stdout[-3000:] + done.stderr[-3000:])
        return {
            "obs_to_action_ms": None,
            "policy_note": f"bench.rollout_policy failed ({done.returncode})",
        }
    return dict(json.loads(lines[-1]))


def _policy_size(policy: Path) -> tuple[int, int]:
    """The cameras' size a trained policy saw: the server renders at it, as it did for
    the demonstrations (a picture scaled down from a larger one is not the same: the
    timecode's blocks, the lines' widths)."""
    features = json.loads((policy / "config.json").read_text())["input_features"]
    height, width = features["observation.images.left"]["shape"][1:]
    return int(width), int(height)


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--handovers", type=int, default=20, help="from the page, and from the master")
    p.add_argument("--no-page", action="store_true", help="no browser: the master's only")
    p.add_argument("--no-policy", action="store_true", help="no LeRobot policy part")
    p.add_argument("--policy", type=Path, help="a trained policy (bench.rollout_policy --train)")
    p.add_argument("--episodes", type=int, default=20, help="of each kind (--policy)")
    p.add_argument("--act-handovers", type=int, default=10, help="with LeRobot's ACT, over REST")
    p.add_argument("--busy-core", action="store_true", help="one core kept busy (stress-ng)")
    args = p.parse_args()
    width, height = _policy_size(args.policy) if args.policy else (640, 480)
    env = {"TELEROBOT_OPERATOR_TOKEN": TOKEN, "TELEROBOT_VIDEO": "true",
           "TELEROBOT_VIDEO_WIDTH": str(width), "TELEROBOT_VIDEO_HEIGHT": str(height),
           "TELEROBOT_SIM_STARTS_AT_HOME": "true"}  # fmt: skip
    with busy_core(args.busy_core), serve_for_bench(env=env, ready=True) as (_, base):
        figures = handovers(base, args.handovers, not args.no_page)
        act = {} if args.no_policy else with_lerobot(base, args)
    emit({**side_by_side(figures, act), "busy_core": args.busy_core, "machine": machine()},
         args.json)  # fmt: skip


def side_by_side(stub: dict[str, Any], act: dict[str, Any]) -> dict[str, Any]:
    """The stub's figures and the ACT's (bench.rollout_policy's) in one line: the
    handover and steady steps as ``{"stub", "act"}``."""
    out, act = dict(stub), dict(act)
    for key in STEPS:
        out[key] = {"stub": stub[key], "act": act.pop(key, None)}
    out["handovers"] = {**stub["handovers"], "act": act.pop("handovers", 0)}
    out["act_handover_jump_mm_by_kind"] = act.pop("handover_jump_mm_by_kind", None)
    return {**out, **act}


if __name__ == "__main__":
    main()
