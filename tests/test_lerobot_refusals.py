"""The LeRobot robot says what the server refused of a supervised policy once a state,
not once a command (its mirror sends 100 increments a second, each refused while the
policy is paused: thousands of lines a minute), with the advice that state needs; and
once its commands are applied again, how many were refused meanwhile
(``telerobot.client.lerobot.refusals``)."""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Iterator

import httpx
import pytest

from telerobot.client import Telerobot
from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm
from telerobot.client.lerobot.refusals import Refusals, reason, what_to_do
from telerobot.client.master.link import Reply
from tests.support import TOKEN, until
from tests.support.servers import serving

PAUSED = "autonomy is paused (paused by 'page'): your command was not applied ({n} refused so far)"


def _error(text: str) -> Reply:
    return Reply("ERROR", {"seq": 1, "code": 8}, text)


def _ack() -> Reply:
    return Reply("ACK", {"seq": 1, "scale": 1.0, "server_time": 0.0}, "")


def test_one_states_refusals_are_one_reason_said_once(caplog: pytest.LogCaptureFixture) -> None:
    explained: list[str | None] = []

    def explain(refused: str | None) -> str:
        explained.append(refused)
        return f"explained: {refused}"

    refusals = Refusals("act", explain)
    caplog.set_level(logging.INFO, logger="telerobot.client.lerobot.refusals")
    for n in range(1, 301):
        refusals.on_reply(_error(PAUSED.format(n=n)))
        if n % 10 == 0:
            refusals.say()  # (LeRobot's actions come 10 times slower than the increments)
    assert reason(PAUSED.format(n=1)) == reason(PAUSED.format(n=300))
    assert len(explained) == 1 and refusals.refused == 300
    refusals.on_reply(_ack())
    refusals.say()
    refusals.say()
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [
        f"explained: {PAUSED.format(n=10)}",  # (the newest when said)
        "act drives again (meanwhile 300 of its commands refused)",
    ]
    # Refused again for the same reason after driving: a new run, said again; actions
    # not sent (someone else holds control) once, however many.
    refusals.on_reply(_error(PAUSED.format(n=301)))
    refusals.say()
    for _ in range(50):
        refusals.withheld()
    refusals.on_reply(_error(PAUSED.format(n=302)))  # on its way before the takeover: old news
    refusals.say()  # (in control again)
    refusals.on_reply(_ack())
    refusals.say()
    lines = [r.getMessage() for r in caplog.records][2:]
    assert lines == [
        f"explained: {PAUSED.format(n=301)}",
        "explained: None",
        "act drives again (meanwhile 2 of its commands refused, 50 actions not sent)",
    ]


def test_the_advice_is_the_states() -> None:
    paused = {"mode": "paused", "cause": "paused by 'page'"}
    assert "P at the page, or POST /api/v1/autonomy/resume" in what_to_do("act", paused, False, "x")
    estopped = what_to_do("act", {"mode": "paused", "cause": "e-stop: pressed"}, True, "x")
    assert "e-stop is latched" in estopped and "POST /api/v1/safety/reset" in estopped
    assert "take over (POST /api/v1/lease)" in estopped
    correcting = {"mode": "correcting", "cause": "taken over", "operator": "page"}
    said = what_to_do("act", correcting, False, None)
    assert said.startswith("page is correcting act") and "DELETE /api/v1/lease" in said
    lost = what_to_do("act", {"mode": "off", "cause": "the policy lost control"}, False, None)
    assert "does not hold control (the policy lost control)" in lost
    assert "POST /api/v1/autonomy/resume" in lost
    limit = what_to_do("act", {"mode": "autonomous"}, False, "joint limit")
    assert limit == "the server refused act's commands: joint limit"


class Policy:
    """A stand-in policy on the robot: the first joint ±1.5° around where it started,
    30 actions a second, on its own thread (as lerobot-rollout calls send_action)."""

    def __init__(self, arm: TelerobotArm) -> None:
        self.arm = arm
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.start = arm.observation()
        self.thread = threading.Thread(target=self._run)
        self.thread.start()

    def _run(self) -> None:
        k = 0
        try:
            while not self.stop.is_set():
                action = dict(self.start)
                action["shoulder_pan.pos"] += 1.5 * math.sin(k / 5)
                self.arm.send(action)
                k += 1
                self.stop.wait(1 / 30)
        except BaseException as exc:  # said by end()
            self.error = exc

    def end(self) -> None:
        self.stop.set()
        self.thread.join(30)
        if self.error is not None:
            raise self.error


@pytest.fixture
def so101() -> Iterator[str]:
    with serving({}, "--model", "so101") as base:
        yield base


def test_a_supervised_policys_refusals_are_said_once_a_state_with_its_advice(
    so101: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Paused at the start, corrected by a REST supervisor, paused when that supervisor's
    lease lapsed, paused by the e-stop: each state said once, with what it needs (the
    e-stop: a REST supervisor takes over, resets it, resumes, as said); a line each time
    the policy drives again, with the count refused meanwhile."""
    http = httpx.Client(
        base_url=so101 + "api/v1/", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
    )
    secret = http.post("policy-tokens", json={"name": "act"}).json()["token"]
    caplog.set_level(logging.INFO, logger="telerobot.client")
    arm = TelerobotArm(ArmOptions(so101, secret, name="act", cameras=False, policy=True))
    arm.connect()

    def lines(level: int = logging.INFO) -> list[str]:
        return [
            r.getMessage()
            for r in caplog.records
            if r.name.startswith("telerobot.client") and r.levelno >= level
        ]

    def said(*words: str) -> list[str]:
        return [line for line in lines() if all(w in line for w in words)]

    def refused() -> int:
        return int(http.get("autonomy").json()["refused"])

    def refused_a_while() -> None:  # a hundred refusals and more, all in this state
        before = refused()
        until(lambda: refused() >= before + 100, timeout=60, what="the server refusing")

    def wait_said(*words: str) -> None:
        until(lambda: said(*words), timeout=60, what=lambda: f"{words} in {lines()[-5:]}")

    def drives_again(since: int) -> None:
        until(lambda: len(said("act drives again")) > since, timeout=60, what=lines)

    policy = Policy(arm)
    try:
        refused_a_while()  # it took control: paused until a person says go
        wait_said("act is PAUSED", "took control")
        assert "POST /api/v1/autonomy/resume" in said("act is PAUSED")[0]
        assert http.post("autonomy/resume").json()["mode"] == "autonomous"  # no lease needed
        wait_said("act drives again", "of its commands refused")

        with Telerobot(so101, TOKEN, name="supervisor"):  # a REST supervisor takes over
            wait_said("supervisor is correcting act", "DELETE /api/v1/lease")
        wait_said("act drives again", "actions not sent")  # handed back on closing

        # A supervisor whose lease lapses (no heartbeat): the policy is paused again.
        http.post("lease", json={"name": "quiet", "idle_timeout_s": 1})
        until(lambda: http.get("autonomy").json()["mode"] == "paused", timeout=30)
        refused_a_while()
        wait_said("act is PAUSED", "control lapsed")
        before = len(said("act drives again"))
        http.post("autonomy/resume")
        drives_again(before)

        http.post("safety/estop")
        refused_a_while()
        wait_said("act is PAUSED", "e-stop is latched")
        # As said: take over, reset the e-stop, let it drive.
        before = len(said("act drives again"))
        with Telerobot(so101, TOKEN, name="resetter") as person:
            reset = http.post("safety/reset", headers={"X-Client-Id": str(person.client_id)})
            assert reset.json()["estop"] is False, reset.text
            assert http.post("autonomy/resume").json()["mode"] == "autonomous"
        drives_again(before)
    finally:
        policy.end()
        arm.disconnect(settle=False)
    # Each paused state said once, however many refusals (hundreds each); the mirror
    # said none of them itself.
    for cause in ("took control", "control lapsed", "e-stop is latched"):
        assert len(said("act is PAUSED", cause)) == 1, lines()
    assert not [r for r in caplog.records if r.name == "telerobot.client.master.joints"]
    assert len(lines(logging.WARNING)) < 10, lines(logging.WARNING)
