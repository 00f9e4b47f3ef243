"""``telerobot policy demo`` (docs/policy-demo.md) end to end: the command against a real
simulated server, supervised over REST as a person would from the page: it drives as a
policy (AUTONOMOUS, the arm moves), a take-over is said and stops it, a hand-back lets it
drive again, a pause has its actions refused and said once, Ctrl+C stops it cleanly and
revokes the token it issued itself. Without a server it says so in one line."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest

from telerobot.client.policy_demo import ArmChain, ReachTargets
from tests.support import TOKEN, until
from tests.support.browser import NO_VIDEO
from tests.support.commands import Running, running
from tests.support.servers import free_port, serving

AUTH = {"Authorization": f"Bearer {TOKEN}"}
DEMO_ENV = {"TELEROBOT_OPERATOR_TOKEN": TOKEN}


@pytest.fixture(scope="module")
def sim() -> Iterator[str]:
    with serving(NO_VIDEO) as base:
        yield base


def autonomy(base: str) -> dict[str, Any]:
    return dict(httpx.get(base + "api/v1/autonomy", timeout=10).json())


def joints(base: str) -> np.ndarray:
    return np.array(httpx.get(base + "api/v1/robot/state", timeout=10).json()["joints"])


def moves(base: str, demo: Running, within: float = 45.0) -> None:
    """The arm moves (more than 0.01 rad at some joint) within ``within`` s."""
    start = joints(base)
    until(
        lambda: np.abs(joints(base) - start).max() > 0.01,
        timeout=within,
        what=lambda: f"the arm did not move; the demo said:\n{demo.output}\n{autonomy(base)}",
        poll=0.1,
    )


def test_the_demo_drives_as_a_policy_under_a_persons_supervision(sim: str) -> None:
    with running("policy", "demo", "--url", sim, "--seed", "1", env=DEMO_ENV) as demo:
        demo.wait_for(r"^AUTONOMOUS \(resumed by ")
        said = autonomy(sim)
        assert said["mode"] == "autonomous" and said["policy"] == "policy demo"
        moves(sim, demo)
        demo.wait_for(r"^target 1 reached: \(")

        with httpx.Client(base_url=sim + "api/v1/", headers=AUTH, timeout=10) as rest:
            took = rest.post("lease", json={"name": "supervisor"})  # a take-over
            assert took.status_code == 200, took.text
            me = {"X-Client-Id": took.json()["client_id"]}
            demo.wait_for(r"^CORRECTING \(taken over by 'supervisor'\): a person drives")
            assert autonomy(sim)["mode"] == "correcting"

            assert rest.delete("lease", headers=me).status_code == 200  # the hand-back
            demo.wait_for(r"^AUTONOMOUS \(handed back by 'supervisor'\): the policy drives")
            assert autonomy(sim)["mode"] == "autonomous"
            moves(sim, demo)  # it drives again

            paused = rest.post("autonomy/pause").json()
            assert paused["mode"] == "paused"
            demo.wait_for(r"^PAUSED \(paused by ")
            # Held still, its actions are refused many times a second: said once.
            until(lambda: autonomy(sim)["refused"] >= 30, timeout=20, poll=0.1)
            demo.wait_for(r"^refused: autonomy is paused")
            assert len(demo.said(r"^refused: autonomy is paused")) == 1, demo.output
            assert len(demo.said(r"^PAUSED")) == 2  # at joining, and now

        assert demo.interrupt() == 0, demo.output
    out = demo.output
    assert "Traceback" not in out and out.splitlines()[-1] == "stopped: control given back"
    assert TOKEN not in out
    until(lambda: autonomy(sim)["mode"] == "off", timeout=10, poll=0.1)  # it left
    issued = httpx.get(sim + "api/v1/policy-tokens", headers=AUTH, timeout=10).json()
    assert issued == []  # the token it issued itself is revoked


def test_the_demo_stops_after_its_targets_and_leaves_nothing_behind(sim: str) -> None:
    with running("policy", "demo", "--url", sim, "--targets", "2", env=DEMO_ENV) as demo:
        assert demo.wait(timeout=90) == 0, demo.output
    assert demo.said(r"^target 2 reached") and demo.output.endswith("control given back")
    assert httpx.get(sim + "api/v1/policy-tokens", headers=AUTH, timeout=10).json() == []


def test_without_a_server_it_says_so_in_one_line() -> None:
    url = f"http://127.0.0.1:{free_port()}/"
    with running("policy", "demo", "--url", url, env=DEMO_ENV) as demo:
        assert demo.wait() == 1
    assert demo.lines == [
        f"telerobot policy demo: no Telerobot server at {url}: start one (telerobot serve)"
        " or name it with --url (or TELEROBOT_URL)"
    ]


def test_the_operator_token_is_refused_as_a_policys(sim: str) -> None:
    with running("policy", "demo", "--url", sim, "--token", TOKEN, env=DEMO_ENV) as demo:
        assert demo.wait() == 1
    assert len(demo.lines) == 1 and "takes a policy token" in demo.lines[0]
    assert TOKEN not in demo.output


def test_its_targets_are_inside_the_workspace_by_the_arms_own_kinematics(sim: str) -> None:
    model = httpx.get(sim + "api/v1/robot/model", timeout=10).json()
    state = httpx.get(sim + "api/v1/robot/state", timeout=10).json()
    safety = httpx.get(sim + "api/v1/safety", timeout=10).json()
    chain = ArmChain.from_described(model)
    assert np.allclose(chain.tool_position(state["joints"]), state["position"], atol=1e-6)
    box = (np.array(safety["workspace_min"]), np.array(safety["workspace_max"]))
    limits = np.radians(np.array(model["joint_limits_deg"]))
    start = np.array(state["joints"])
    targets = ReachTargets(chain, start, limits, box, np.random.default_rng(0))
    for _ in range(50):
        q = targets.draw()
        p = chain.tool_position(q)
        assert np.all(np.abs(q - start) <= targets.reach_rad + 1e-9)
        assert np.all(p > box[0]) and np.all(p < box[1])
        assert p[2] >= targets.start_tool[2] - 0.021
