"""The Python client and `telerobot move` against a real server, and the README's
scripted-move examples run exactly as written there."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from telerobot.client import Telerobot, TelerobotError
from tests.support import TOKEN
from tests.support.servers import serving

ROOT = Path(__file__).resolve().parents[1]


def readme_block(kind: str) -> str:
    """The code block after ``<!-- readme-example: KIND`` in the README."""
    text = (ROOT / "README.md").read_text()
    m = re.search(rf"<!-- readme-example: {kind}\b.*?-->\s*```\w*\n(.*?)```", text, re.S)
    assert m, f"the README has no {kind} example"
    return m.group(1)


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with serving() as base:
        yield base


def env_for(base: str) -> dict[str, str]:
    return {**os.environ, "TELEROBOT_URL": base, "TELEROBOT_OPERATOR_TOKEN": TOKEN}


def controller(base: str) -> object:
    return httpx.get(base + "api/v1/safety").json()["controller"]


def test_the_readme_python_example_runs_as_written(server: str) -> None:
    run = subprocess.run(
        [sys.executable, "-c", readme_block("python")],
        env=env_for(server), capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().startswith("[")  # the position it printed
    assert controller(server) is None  # the block released the lease


def test_the_readme_shell_example_runs_as_written(server: str) -> None:
    run = subprocess.run(
        ["bash", "-c", readme_block("shell")],
        env=env_for(server), capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "position (m): 0.6000 -0.1000 0.9000" in run.stdout
    assert controller(server) is None


def test_a_script_may_pause_between_moves_and_keeps_its_lease(server: str) -> None:
    with Telerobot(server, TOKEN, name="pausing script") as robot:
        robot.move_cartesian([0.6, 0.0, 0.9])
        time.sleep(1.5)  # a person reading the screen: 10× the dead-man
        assert controller(server) == "pausing script"
        robot.move_cartesian([0.6, 0.05, 0.9])
        assert robot.lease_error is None
    assert controller(server) is None


def test_an_error_in_the_block_stops_the_arm_and_releases_the_lease(server: str) -> None:
    robot = Telerobot(server, TOKEN)
    with pytest.raises(ZeroDivisionError), robot:
        robot.move_cartesian([0.6, -0.05, 0.9], wait=False)
        _ = 1 / 0
    assert controller(server) is None
    state = httpx.get(server + "api/v1/robot/state").json()
    assert state["status"] in ("READY", "MOVING")


def test_refusals_say_why(server: str) -> None:
    with pytest.raises(TelerobotError) as refused:
        Telerobot(server, "not-the-token-0123456789").connect()
    assert refused.value.status == 403 and "operator token" in refused.value.detail
    with Telerobot(server, TOKEN) as robot, pytest.raises(TelerobotError) as far:
        robot.move_cartesian([3.0, 0.0, 0.9])
    assert far.value.status == 422
