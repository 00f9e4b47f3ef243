"""The README's plain-REST block and the names of the server and the token: the block
runs as written twice in a row (it releases its lease when it ends); a script that
could not release it, run again under the same name from the same address, takes its
own idle lease back, while anyone else is refused and told when it lapses; a refused
lease prints the server's reason, not a traceback; and `telerobot master` finds the
server and the token as `telerobot move` and the Python client do; the README's e-stop
line and its reset over REST work as written."""

from __future__ import annotations

import json
import os
import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from tests.support import TOKEN
from tests.support.servers import serving, telerobot

ROOT = Path(__file__).resolve().parents[1]
AUTH = {"Authorization": f"Bearer {TOKEN}"}
RELEASE = re.compile(r"^\s*curl [^\n]*-X DELETE [^\n]*\n", re.M)


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


@pytest.fixture
def home(tmp_path: Path) -> dict[str, str]:
    """The environment of a user of this machine: the token where the server keeps it
    (``~/.config/telerobot``), the server named by ``TELEROBOT_URL``."""
    folder = tmp_path / ".config" / "telerobot"
    folder.mkdir(parents=True)
    (folder / "operator-token").write_text(TOKEN + "\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("TELEROBOT_")}
    return {**env, "HOME": str(tmp_path), "XDG_CONFIG_HOME": str(tmp_path / ".config")}


def run_block(block: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["bash", "-c", block], env=env, capture_output=True, text=True, timeout=60, cwd=ROOT
    )


def moved_there(stdout: str) -> bool:
    """The move's answer (the block prints it): the tool at the block's position."""
    position = json.loads(stdout)["state"]["position"]
    return bool(position == pytest.approx([0.6, -0.1, 0.9], abs=1e-6))


def safety(base: str) -> dict[str, object]:
    result: dict[str, object] = httpx.get(base + "api/v1/safety").json()
    return result


def test_the_rest_block_runs_twice_in_a_row(server: str, home: dict[str, str]) -> None:
    env = {**home, "TELEROBOT_URL": server.rstrip("/")}
    block = readme_block("rest")
    for _ in range(2):  # back to back: the first run's lease is released, not left idle
        run = run_block(block, env)
        assert run.returncode == 0 and not run.stderr, run.stderr
        assert moved_there(run.stdout)
        assert safety(server)["controller"] is None
    assert "released" in str(safety(server)["lease_note"])


def test_a_script_run_again_takes_back_its_own_idle_lease(
    server: str, home: dict[str, str]
) -> None:
    """The block without its last line (a script killed before it released the lease):
    run again at once under the same name from the same address, it takes its own idle
    lease back; another name is refused, told who has control and when it lapses."""
    env = {**home, "TELEROBOT_URL": server.rstrip("/")}
    crashed = RELEASE.sub("", readme_block("rest"))
    assert "DELETE" not in crashed
    try:
        first = run_block(crashed, env)
        assert first.returncode == 0 and not first.stderr, first.stderr
        assert safety(server)["controller"] == "my script"  # left idle, 5 s to lapse
        other = httpx.post(server + "api/v1/lease", json={"name": "another"}, headers=AUTH)
        assert other.status_code == 403, other.text
        detail = other.json()["detail"]
        assert "'my script' has control" in detail and "it lapses in" in detail, detail
        again = run_block(crashed, env)
        assert again.returncode == 0 and not again.stderr, again.stderr
        assert moved_there(again.stdout)
        view = safety(server)
        assert view["controller"] == "my script"
        assert "taken again by 'my script'" in str(view["lease_note"]), view
    finally:  # a forced lease of our own, released: the next test finds it free
        h = {**AUTH, "X-Client-Id": take(server, "cleanup", force=True)}
        httpx.delete(server + "api/v1/lease", headers=h)


def take(base: str, name: str, *, force: bool = False) -> str:
    r = httpx.post(base + "api/v1/lease", json={"name": name, "force": force}, headers=AUTH)
    assert r.status_code == 200, r.text
    client_id: str = r.json()["client_id"]
    return client_id


def test_a_refused_lease_prints_the_servers_reason_and_moves_nothing(
    server: str, home: dict[str, str]
) -> None:
    env = {**home, "TELEROBOT_URL": server.rstrip("/")}
    holder = take(server, "the page")
    h = {**AUTH, "X-Client-Id": holder}
    try:
        before = httpx.get(server + "api/v1/robot/state").json()["position"]
        run = run_block(readme_block("rest"), env)
        assert "Traceback" not in run.stderr and "KeyError" not in run.stderr, run.stderr
        assert "'the page' has control" in run.stderr, run.stderr
        assert run.stdout == ""  # no move was sent
        assert httpx.get(server + "api/v1/robot/state").json()["position"] == before
        assert safety(server)["controller"] == "the page"
    finally:
        httpx.delete(server + "api/v1/lease", headers=h)


def readme_curl(endpoint: str) -> str:
    """The README's inline `curl ...` (in its prose, not a block) for ``endpoint``."""
    text = (ROOT / "README.md").read_text()
    m = re.search(rf"`(curl [^`]*{re.escape(endpoint)}[^`]*)`", text)
    assert m, f"the README shows no curl for {endpoint}"
    return m.group(1)


def test_the_readmes_estop_and_its_reset_over_rest_work(server: str, home: dict[str, str]) -> None:
    """The README says how to reset the e-stop over REST, beside the
    e-stop's line, and both work as written: its e-stop line latches it (the server's
    port put in), its reset line, with a lease's id as the REST block gets one, clears
    it."""
    address = server.removeprefix("http://").rstrip("/")
    estop = readme_curl("/safety/estop").replace("localhost:8000", address)
    reset = readme_curl("/safety/reset")
    assert "X-Client-Id" in reset, reset
    run = run_block(estop + " -o /dev/null -w '%{http_code}'", home)
    assert run.stdout == "200", (run.stdout, run.stderr)
    assert safety(server)["estop"] is True
    client_id = take(server, "my script")
    env = {
        **home,
        "API": server + "api/v1",
        "AUTH": f"Authorization: Bearer {TOKEN}",
        "JSON": "Content-Type: application/json",
        "ID": client_id,
    }
    try:
        run = run_block(reset + " -o /dev/null -w '%{http_code}'", env)
        assert run.stdout == "200", (run.stdout, run.stderr)
        assert safety(server)["estop"] is False
    finally:  # the next test finds the e-stop clear and the lease free
        h = {**AUTH, "X-Client-Id": client_id}
        if safety(server)["estop"]:
            httpx.post(server + "api/v1/safety/reset", headers=h)
        httpx.delete(server + "api/v1/lease", headers=h)


def test_refused_lease_requests_leave_no_client_behind(client: TestClient) -> None:
    """A refused ``POST /lease`` is not kept as a client for a minute: a script retrying
    in a loop does not fill the server's table of clients (MAX_CLIENTS)."""
    decision = client.app.state.services.decision  # type: ignore[attr-defined]
    assert client.post("/api/v1/lease", json={"name": "holder"}, headers=AUTH).status_code == 200
    known = len(decision.clients)
    for i in range(20):
        r = client.post("/api/v1/lease", json={"name": f"retry {i}"}, headers=AUTH)
        assert r.status_code == 403 and "'holder' has control" in r.json()["detail"]
    assert len(decision.clients) == known


def test_the_master_names_the_server_and_token_as_move_does(server: str, tmp_path: Path) -> None:
    """`telerobot master` with no --url and no --token: the server from TELEROBOT_URL,
    the token the server keeps on this machine (as `telerobot move` and the client)."""
    (tmp_path / "operator-token").write_text(TOKEN)
    env = {
        "TELEROBOT_URL": server.rstrip("/"),
        "TELEROBOT_STATE_DIR": str(tmp_path),
        "TELEROBOT_OPERATOR_TOKEN": "",
    }
    with telerobot(
        "master", "--no-force", env=env, wait_for=r"bridged to (\S+) as (\w+)", timeout=60
    ) as (_, match):
        assert match.group(1) == server.rstrip("/") and match.group(2) == "operator", match.string
