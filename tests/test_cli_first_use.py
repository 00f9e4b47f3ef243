"""What a new user meets at the command line (issue 55): ``telerobot move --arm`` on a
two-arm server, one-line errors (a port in use, an unknown recording or benchmark), the
benchmarks listed, and what ``telerobot serve`` says at every start: where the operator
token is kept and how the page takes it, never the token itself (nor a policy's, in any
line the server or the policy demo prints), and no deprecation warnings."""

from __future__ import annotations

import os
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from harness import recordings
from harness.servers import wait_until_ready
from telerobot.client.master.link import open_link
from telerobot.drivers.base import TelerobotError
from tests.support import TOKEN, until
from tests.support.browser import NO_VIDEO
from tests.support.commands import running
from tests.support.servers import BIN, serving

TWO_SIM_ARMS = {**NO_VIDEO, "TELEROBOT_ARMS": "left=so101:sim,right=so101:sim"}
AUTH = {"Authorization": f"Bearer {TOKEN}"}
QUIET_SERVER = {
    "TELEROBOT_VIDEO": "false",
    "TELEROBOT_VIEWER": "false",
    "TELEROBOT_CPU_PRIORITY": "0",
    "TELEROBOT_SIM_STARTS_AT_HOME": "true",
}


@pytest.fixture(scope="module")
def two_arms() -> Iterator[str]:
    with serving(TWO_SIM_ARMS) as base:
        yield base


def joints(base: str, arm: str) -> np.ndarray:
    state = httpx.get(base + "api/v1/robot/state", params={"arm": arm}, timeout=10).json()
    return np.array(state["joints"])


def move(base: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BIN), "move", *args, "--url", base, "--token", TOKEN],
        capture_output=True,
        text=True,
        timeout=120,
    )


# ------------------------------------------------------------ telerobot move --arm
def test_move_drives_the_arm_it_names_on_a_two_arm_server(two_arms: str) -> None:
    left, right = joints(two_arms, "left"), joints(two_arms, "right")
    done = move(two_arms, "joints", "0.1", *["0"] * 5, "--relative", "--arm", "left")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("left: position (m):")
    assert joints(two_arms, "left") == pytest.approx(left + [0.1, 0, 0, 0, 0, 0], abs=2e-3)
    assert np.allclose(joints(two_arms, "right"), right, atol=1e-4)  # not the other
    cartesian = move(two_arms, "cartesian", "0", "0", "0.01", "--relative", "--arm", "right")
    assert cartesian.returncode in (0, 1)  # the server's answer (refused: in one line)
    assert len(cartesian.stderr.splitlines()) == (cartesian.returncode == 1)


def test_move_without_an_arm_on_a_two_arm_server_names_them_in_one_line(two_arms: str) -> None:
    refused = move(two_arms, "cartesian", "0", "0", "0.01", "--relative")
    assert refused.returncode == 2 and refused.stdout == ""
    assert refused.stderr.splitlines() == [
        "telerobot move: the server drives 2 arms (left, right): name one with --arm NAME"
        " (telerobot move --arm left …)"
    ]
    unknown = move(two_arms, "joints", *["0"] * 6, "--relative", "--arm", "middle")
    assert unknown.returncode == 2
    assert unknown.stderr.splitlines() == [
        "telerobot move: the server has no arm 'middle': it drives left, right (--arm NAME)"
    ]


def test_an_arm_named_where_numbers_go_is_said_in_one_line(two_arms: str) -> None:
    wrong = move(two_arms, "cartesian", "left", "0", "0")
    assert wrong.returncode == 2
    assert wrong.stderr.splitlines() == [
        "telerobot move: 'left' is not a number (the arm: --arm NAME)"
    ]


def test_the_policy_demo_moves_only_the_arm_it_is_given(two_arms: str) -> None:
    right = joints(two_arms, "right")
    env = {"TELEROBOT_OPERATOR_TOKEN": TOKEN}
    with running(
        "policy", "demo", "--url", two_arms, "--arm", "left", "--targets", "1", env=env
    ) as demo:
        assert demo.wait(timeout=90) == 0, demo.output
    assert demo.said(r"moving left; first target at \(") and demo.said(r"^target 1 reached")
    assert np.allclose(joints(two_arms, "right"), right, atol=1e-4)
    with running("policy", "demo", "--url", two_arms, "--arm", "middle", env=env) as demo:
        assert demo.wait() == 1
    assert demo.lines == [
        "telerobot policy demo: the server has no arm 'middle': it drives left, right (--arm NAME)"
    ]


def test_move_on_a_one_arm_server_takes_its_arms_name_or_none(tmp_path: Path) -> None:
    with serving(NO_VIDEO) as base:
        assert move(base, "joints", *["0"] * 6, "--relative").returncode == 0
        named = move(base, "joints", *["0"] * 6, "--relative", "--arm", "arm")
        assert named.returncode == 0, named.stderr
        wrong = move(base, "joints", *["0"] * 6, "--relative", "--arm", "left")
        assert wrong.stderr.splitlines() == [
            "telerobot move: the server has no arm 'left': it drives arm (--arm NAME)"
        ]


# ------------------------------------------------------------ one-line errors
def taken_port() -> tuple[socket.socket, int]:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s, s.getsockname()[1]


@pytest.mark.parametrize(
    ("flag", "what"),
    [("--http-port", "the HTTP"), ("--priority-port", "the priority channel's")],
)
def test_a_port_in_use_is_said_in_one_line(tmp_path: Path, flag: str, what: str) -> None:
    holder, port = taken_port()
    with holder:
        ports = {"--http-port": "0", "--priority-port": "0", flag: str(port)}
        args = [a for pair in ports.items() for a in pair]
        out = subprocess.run(
            [str(BIN), "serve", *args, "--state-dir", str(tmp_path)],
            capture_output=True,
            text=True,
            timeout=120,
            env={**os.environ, **QUIET_SERVER},
        )
    assert out.returncode == 1 and out.stdout == ""
    variable = "TELEROBOT_HTTP_PORT" if flag == "--http-port" else "TELEROBOT_PRIORITY_PORT"
    assert out.stderr.splitlines() == [
        f"telerobot serve: {what} port {port} on 127.0.0.1 is in use (another `telerobot"
        f" serve`?): pick another with {flag} PORT (or {variable}; 0: any free port), or"
        " stop what holds it"
    ]


def test_export_takes_the_recording_id_the_page_shows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from telerobot.server.cli import main

    folder = tmp_path / "state" / "recordings"
    folder.mkdir(parents=True)
    recordings.build(folder / "20260101T120000Z-demo.mcap", duration=2.0)
    out = tmp_path / "ds"
    state = ["--state-dir", str(tmp_path / "state")]
    assert main(["export", "lerobot", "20260101T120000Z-demo", str(out), *state]) == 0
    assert "episodes" in capsys.readouterr().out and (out / "meta" / "info.json").is_file()
    # The id with .mcap, and the state folder from the environment.
    monkeypatch.setenv("TELEROBOT_STATE_DIR", str(tmp_path / "state"))
    again = tmp_path / "ds2"
    assert main(["export", "lerobot", "20260101T120000Z-demo.mcap", str(again)]) == 0
    capsys.readouterr()

    assert main(["export", "lerobot", "no-such-recording", str(tmp_path / "ds3")]) == 1
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "telerobot export lerobot: no recording 'no-such-recording': not a file here, nor"
        f" in the recordings folder {folder} (a recording's id is its file name, as the"
        " page's Recordings list and GET /api/v1/recordings show it; another server's"
        " folder: --state-dir)"
    ]
    assert "Errno" not in err


def test_an_unknown_benchmark_is_said_in_one_line_listing_them(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from telerobot.server.cli import main

    assert main(["bench", "no_such_bench"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("telerobot bench: no benchmark 'no_such_bench': ")
    assert "kinematics" in err[0] and "stopping" in err[0] and "common" not in err[0]


def test_bench_help_lists_each_benchmark_with_what_it_measures(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from telerobot.server.cli import benchmarks, main

    with pytest.raises(SystemExit) as done:
        main(["bench", "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    listed = benchmarks()
    assert {"kinematics", "stopping", "wan", "rollout"} <= set(listed)
    assert "common" not in listed  # a helper, not a benchmark
    for name, what in listed.items():
        assert what and "\n" not in what
        assert f"  {name} " in out and what in out
    assert "Kinematics of a robot model" in listed["kinematics"]


# ------------------------------------------------------------ what serve says at a start
def test_a_serial_port_given_to_a_robot_without_one_is_said_in_one_line(tmp_path: Path) -> None:
    out = subprocess.run(
        [str(BIN), "serve", "--port", "8765", "--state-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **QUIET_SERVER},
    )
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.splitlines() == [
        "telerobot serve: --port is a robot's serial port (--robot val); the sim robot has"
        " none. The page's port is --http-port PORT"
    ]


def test_serve_says_where_the_token_is_and_never_a_token(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A real server with a known operator token (kept in its state folder, as after a
    first start), a few requests that succeed and some that fail, the policy demo with a
    policy token: neither token is in any line either prints."""
    monkeypatch.delenv("TELEROBOT_OPERATOR_TOKEN", raising=False)
    monkeypatch.delenv("TELEROBOT_POLICY_TOKEN", raising=False)
    state = tmp_path / "state"
    state.mkdir()
    (state / "operator-token").write_text(TOKEN + "\n")
    args = ("serve", "--http-port", "0", "--priority-port", "0", "--state-dir", str(state))
    with running(*args, env=QUIET_SERVER) as server:
        line = server.wait_for(r"Telerobot is running on .*: http://localhost:(\d+)/", 60)
        base = "http://127.0.0.1:" + line.rsplit(":", 1)[1].strip("/ ") + "/"
        shown = base.replace("127.0.0.1", "localhost")
        server.wait_for(r"^Take control: ")
        wait_until_ready(base)
        assert server.said(r"^Operator token: ") == [
            f"Operator token: kept in {state / 'operator-token'}"
        ]
        assert server.said(r"^Take control: ") == [
            f"Take control: open {shown}?token=<the token in {state / 'operator-token'}>"
            " (without it the page watches)"
        ]
        with httpx.Client(base_url=base, timeout=10) as http:
            assert http.get("", params={"token": TOKEN}).status_code == 200
            http.get("api/v1/robot/state", params={"token": TOKEN})
            assert http.post("api/v1/lease", json={"name": "x"},
                             headers={"Authorization": f"Bearer {TOKEN}x"}).is_error  # fmt: skip
            assert http.post("api/v1/lease", json={"name": "x"},
                             params={"token": TOKEN}).is_error  # fmt: skip
            issued = http.post("api/v1/policy-tokens", json={"name": "p"}, headers=AUTH)
            secret = issued.json()["token"]
            refused = http.post("api/v1/lease", json={"name": "p"},
                                headers={"Authorization": f"Bearer {secret}"})  # fmt: skip
            assert refused.is_error and secret not in refused.text
            assert http.get("api/v1/policy-tokens", headers={
                "Authorization": f"Bearer {secret}"}).is_error  # fmt: skip
        with pytest.raises(TelerobotError):  # a HELLO with a wrong policy token
            open_link(base, secret + "x", datagrams=False, policy=True)
        demo_args = ("policy", "demo", "--url", base, "--token", secret, "--targets", "1")
        with running(*demo_args, env={"TELEROBOT_OPERATOR_TOKEN": TOKEN}) as demo:
            assert demo.wait(timeout=90) == 0, demo.output
        assert demo.said(r"^target 1 reached")
        until(lambda: server.said(r"/api/v1/policy-tokens"), timeout=10, poll=0.05)
        assert server.interrupt() == 0, server.output
    said = server.output
    assert said.splitlines()[-1] == "Telerobot stopped."
    assert "?token=[redacted]" in said  # the requests above were logged
    for name, secret_value in (("operator", TOKEN), ("policy", secret)):
        assert secret_value not in said, f"the {name} token is in the server's output"
        assert secret_value not in demo.output, f"the {name} token is in the demo's output"
    assert "Warning" not in said and "deprecated" not in said, said
    assert "Traceback" not in said
