"""``telerobot serve`` and ``telerobot val-emulator`` as a user runs them."""

from __future__ import annotations

import subprocess
import time

import httpx
import pytest

from tests.support import TOKEN
from tests.support.servers import BIN, telerobot

URL = r"(http://localhost:\d+/)"


def wait_ready(base: str, timeout: float = 20.0) -> dict[str, object]:
    deadline = time.monotonic() + timeout
    while True:
        state: dict[str, object] = httpx.get(base + "api/v1/robot/state").json()
        if state["status"] == "READY" or time.monotonic() > deadline:
            return state
        time.sleep(0.1)


def test_serve_prints_its_url_and_runs_the_simulation() -> None:
    with telerobot("serve", "--http-port", "0", wait_for=URL) as (_, m):
        state = wait_ready(m.group(1))
        assert state["status"] == "READY" and state["driver"] == "sim-puma560"


def test_serve_runs_the_simulated_so101_from_its_model_flag() -> None:
    with telerobot(
        "serve",
        "--model",
        "so101",
        "--http-port",
        "0",
        wait_for=r"running on the simulated SO-101: " + URL,
    ) as (_, m):
        base = m.group(1)
        state = wait_ready(base)
        assert state["status"] == "READY" and state["driver"] == "sim-so101"
        model = httpx.get(base + "api/v1/robot/model").json()
        assert model["model"] == "so101" and model["joint_names"][-1] == "gripper"
        assert model["home_pose"] == "ready" and len(state["joints"]) == 6  # type: ignore[arg-type]


def test_a_val_driver_refuses_another_models_settings() -> None:
    out = subprocess.run(
        [str(BIN), "serve", "--robot", "val", "--model", "so101", "--http-port", "0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode != 0
    assert "drives a PUMA 560, not the SO-101" in out.stdout + out.stderr


def test_serve_against_the_val_emulator_over_tcp() -> None:
    with (
        telerobot(
            "val-emulator",
            "--tcp",
            "127.0.0.1:0",
            "--time-scale",
            "0.05",
            wait_for=r"(socket://\S+)",
        ) as (
            _,
            emu,
        ),
        telerobot(
            "serve", "--robot", "val", "--port", emu.group(1), "--http-port", "0", wait_for=URL
        ) as (_, m),
    ):
        state = wait_ready(m.group(1))
        assert state["status"] == "READY" and state["driver"] == "val-puma560"


def test_serve_against_the_val_emulator_on_a_pty() -> None:
    with (
        telerobot("val-emulator", "--time-scale", "0.05", wait_for=r"listening on (/dev/\S+)") as (
            _,
            emu,
        ),
        telerobot(
            "serve", "--robot", "val", "--port", emu.group(1), "--http-port", "0", wait_for=URL
        ) as (_, m),
    ):
        assert wait_ready(m.group(1))["status"] == "READY"


def test_bad_settings_exit_with_a_message() -> None:
    out = subprocess.run(
        [str(BIN), "serve", "--config", "/nonexistent.toml"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2 and "settings file /nonexistent.toml does not exist" in out.stderr


def test_serve_reads_forces_from_the_netft_emulator() -> None:
    with (
        telerobot("netft-emulator", "--port", "0", wait_for=r"udp://(\S+)") as (_, emu),
        telerobot(
            "serve",
            "--http-port",
            "0",
            wait_for=URL,
            env={"TELEROBOT_FORCE": "netft", "TELEROBOT_NETFT_ADDRESS": emu.group(1)},
        ) as (_, m),
    ):
        deadline = time.monotonic() + 10
        while (force := httpx.get(m.group(1) + "api/v1/force").json())["latest"] is None:
            assert time.monotonic() < deadline, force
            time.sleep(0.1)
        assert force["driver"] == "netft" and force["error"] is None
        assert force["latest"]["values"][0] == 0.5  # the emulator's Fx, in newtons
        assert force["counters"]["received"] > 0 and force["counters"]["bad_packets"] == 0


def test_serve_takes_the_3d_views_port_from_its_flag() -> None:
    import socket

    with socket.socket() as s:  # a free port, given by the flag
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with telerobot(
        "serve", "--http-port", "0", "--viewer-port", str(port),
        wait_for=r"3D view: http://\S+:(\d+)/", env={"TELEROBOT_VIEWER": "true"},
    ) as (_, m):  # fmt: skip
        assert int(m.group(1)) == port


def test_policy_tokens_from_the_command_line(
    server: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``telerobot policy-token new NAME``, ``list`` and ``revoke ID`` against a server."""
    from telerobot.server.cli import main

    where = ["--url", server, "--token", TOKEN]
    assert main(["policy-token", "new", "act-policy", *where]) == 0
    out, err = capsys.readouterr()
    secret = out.strip()
    assert secret.startswith("tpol_") and "shown this once" in err
    ident = err.split()[2]
    assert main(["policy-token", "list", *where]) == 0
    listed = capsys.readouterr().out
    assert ident in listed and "act-policy" in listed and secret not in listed
    assert main(["policy-token", "revoke", ident, *where]) == 0
    assert "revoked" in capsys.readouterr().out
    assert main(["policy-token", "revoke", ident, *where]) == 1
    assert "no policy token" in capsys.readouterr().err
    assert main(["policy-token", "list", "--url", server, "--token", "wrong-token-000000000"]) == 1
