"""Supervised autonomy through a real server: a policy client drives over the priority
channel; a REST script, the simulated master arm's clutch and (test_web_autonomy.py)
the page take over from it, the policy's next command is refused and said to it, the
arm does not jump, and letting go hands back."""

from __future__ import annotations

import json
import time

import httpx
import numpy as np
import pytest

from harness.policy_stub import PolicyClient, issue_policy_token
from telerobot.client.master.bridge import HAND_BACK_S, BridgeSettings, MasterBridge
from telerobot.client.master.cli import open_link
from telerobot.drivers.base import FloatArray
from telerobot.drivers.master.sim import SimMaster
from tests.support import TOKEN, until
from tests.support.browser import NO_VIDEO

SERVER_ENV = NO_VIDEO
AUTH = {"Authorization": f"Bearer {TOKEN}"}
# The server's own step limit for one increment (max_speed_m_s over the longest interval
# it allows, 0.25 m/s × 0.1 s): a jump is anything beyond it. A STATE comes every 20 ms.
STEP_LIMIT_M = 0.025


def autonomy(server: str) -> dict[str, object]:
    return dict(httpx.get(server + "api/v1/autonomy").json())


def mode_is(server: str, mode: str) -> bool:
    return autonomy(server)["mode"] == mode


def test_a_script_takes_over_without_force_and_hands_back(server: str) -> None:
    with PolicyClient(server, TOKEN) as policy:
        until(lambda: mode_is(server, "autonomous"), timeout=10)
        until(lambda: len(policy.applied_since(0)) > 5, timeout=10, what=lambda: "it drives")
        with httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=10) as rest:
            r = rest.post("lease", json={"name": "supervisor"})  # no force
            assert r.status_code == 200, r.text
            took = time.monotonic()
            me = {"X-Client-Id": r.json()["client_id"]}
            state = autonomy(server)
            assert state["mode"] == "correcting" and state["operator"] == "supervisor"
            until(lambda: policy.refused_since(took), timeout=5, what=lambda: "refused")
            assert "supervisor is correcting" in policy.refused_since(took)[0].text
            assert not policy.applied_since(took + 0.5)  # nothing of its applied since
            paused = rest.post("autonomy/pause", headers=me).json()
            assert paused["mode"] == "paused" and "paused by 'supervisor'" in paused["cause"]
            resumed = rest.post("autonomy/resume", headers=me).json()
            assert resumed["mode"] == "autonomous"
            back = time.monotonic()
            until(lambda: policy.applied_since(back), timeout=5, what=lambda: "drives again")
            assert autonomy(server)["interventions"] == 1
            rest.delete("lease", headers=me)
        assert policy.largest_step_m() < STEP_LIMIT_M
    until(lambda: mode_is(server, "off"), timeout=5)  # the policy left


def test_the_masters_clutch_takes_over_and_letting_go_hands_back(server: str) -> None:
    """The operator grips the master's clutch while the policy drives: control is
    theirs at once, the arm stops where it is and follows the handle from there; let
    go, it goes back to the policy after HAND_BACK_S."""
    grip = {"on": False}

    def hand(t: float) -> tuple[FloatArray, bool]:
        # While gripped the hand moves 1 cm/s along the device's x.
        return np.array([0.01 * t if grip["on"] else 0.0, 0.0, 0.0]), grip["on"]

    with PolicyClient(server, TOKEN) as policy:
        until(lambda: mode_is(server, "autonomous"), timeout=10)
        device = SimMaster(hand)
        link = open_link(server, TOKEN)
        bridge = MasterBridge(device, link, BridgeSettings(force_scale=0.05))
        bridge.start(take_control=False)
        try:
            # Told at once on joining (the events say only changes).
            until(lambda: link.autonomy == "autonomous", timeout=5)
            grip["on"] = True
            took = time.monotonic()
            until(lambda: mode_is(server, "correcting"), timeout=5, what=lambda: "clutch takes")
            until(lambda: bridge.has_control, timeout=5)
            until(lambda: policy.refused_since(took), timeout=5, what=lambda: "refused")
            assert "is correcting" in policy.refused_since(took)[0].text
            target = httpx.get(server + "api/v1/robot/state").json()["target_joints"]
            until(
                lambda: httpx.get(server + "api/v1/robot/state").json()["target_joints"] != target,
                timeout=10,
                what=lambda: "the master drives",
            )
            grip["on"] = False
            let_go = time.monotonic()
            until(lambda: mode_is(server, "autonomous"), timeout=5 + HAND_BACK_S)
            assert time.monotonic() - let_go >= HAND_BACK_S * 0.9
            back = time.monotonic()
            until(lambda: policy.applied_since(back), timeout=5, what=lambda: "drives again")
            assert bridge.takeovers == 1
        finally:
            bridge.stop()
            link.close()
        assert policy.largest_step_m() < STEP_LIMIT_M


def test_an_estop_during_autonomy_pauses_it_until_an_operator_resumes(server: str) -> None:
    with PolicyClient(server, TOKEN) as policy:
        until(lambda: mode_is(server, "autonomous"), timeout=10)
        with httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=10) as rest:
            rest.post("safety/estop")
            state = autonomy(server)
            assert state["mode"] == "paused" and "e-stop" in str(state["cause"])
            t = time.monotonic()
            until(lambda: policy.refused_since(t), timeout=5)
            me = {"X-Client-Id": rest.post("lease", json={"name": "sup"}).json()["client_id"]}
            refused = rest.post("autonomy/resume", headers=me)
            assert refused.status_code == 409 and "reset it first" in refused.text
            assert rest.post("safety/reset", headers=me).status_code == 200
            # Taking control to reset it is a correction: resume hands back.
            assert rest.post("autonomy/resume", headers=me).json()["mode"] == "autonomous"
            back = time.monotonic()
            until(lambda: policy.applied_since(back), timeout=5, what=lambda: "drives again")
            rest.delete("lease", headers=me)
        events = [json.loads(e)["mode"] for e in policy.autonomy]
        # It took control paused, a person let it drive, the e-stop paused it, a person took over.
        assert events[:4] == ["paused", "autonomous", "paused", "correcting"], events


@pytest.mark.parametrize("force", [False, True])
def test_a_policy_never_takes_control_from_a_person(server: str, force: bool) -> None:
    with httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=10) as rest:
        me = {"X-Client-Id": rest.post("lease", json={"name": "person"}).json()["client_id"]}
        try:
            r = rest.post("lease", json={"name": "policy", "policy": True, "force": force})
            assert r.status_code == 403 and "operator token cannot join as a policy" in r.text
            policy = {"Authorization": f"Bearer {issue_policy_token(server, TOKEN, 'policy')}"}
            body = {"name": "policy", "policy": True, "force": force}
            r = rest.post("lease", json=body, headers=policy)
            assert r.status_code == 403 and "never takes it from anyone" in r.text
        finally:
            rest.delete("lease", headers=me)
