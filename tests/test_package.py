"""One package, split by where the code runs (docs/architecture.md, "The package"): the
client side (the REST client, the master-arm bridge: on the operator's machine) and the
protocol it shares with the server import nothing of the server's, and nothing in the
repository imports the folders by their own names (``backend``, ``drivers``,
``calibration``): each module has one name, under ``telerobot``."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SERVER_ONLY = ("fastapi", "starlette", "uvicorn", "aiortc", "av", "pinocchio", "telerobot.server")


def test_the_client_side_imports_nothing_of_the_server() -> None:
    probe = (
        "import sys, telerobot.client, telerobot.client.master.cli, telerobot.client.master.link,"
        " telerobot.client.master.bridge, telerobot.client.master.joints,"
        " telerobot.client.lerobot.arm, telerobot.client.lerobot.operator,"
        " telerobot.protocol.messages, telerobot.protocol.typed\n"
        f"print(sorted(n for n in sys.modules if n.split('.')[0] in {SERVER_ONLY!r}"
        f" or n.startswith({SERVER_ONLY!r})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True, cwd="/"
    ).stdout
    assert out.strip() == "[]"


def test_the_server_and_the_bridge_share_one_framing() -> None:
    from telerobot.client.master import link
    from telerobot.protocol import messages as m
    from telerobot.server.realtime import priority

    assert priority.LENGTH is m.LENGTH and priority.frame is m.frame
    assert "LENGTH" not in vars(link)  # it uses the protocol's, not a copy


def test_nothing_imports_the_folders_by_their_own_names() -> None:
    # Imported as `backend.x` and as `telerobot.server.x`, a module would be loaded twice
    # (two registries, two sets of settings): only the package's names are used.
    old = re.compile(r"^\s*(from|import)\s+(backend|drivers|calibration)\b", re.M)
    named = re.compile(r"[\"'](-m\s+)?(backend|drivers|calibration)\.(?!json|html)[a-z_]")
    found = []
    for folder in ("backend", "drivers", "calibration", "telerobot/client", "telerobot/protocol",
                   "bench", "harness", "tests"):  # fmt: skip
        for path in (ROOT / folder).rglob("*.py"):
            text = path.read_text()
            if path.name != "test_package.py" and (old.search(text) or named.search(text)):
                found.append(str(path.relative_to(ROOT)))
    assert found == []


def test_the_harness_imports_neither_the_benches_nor_the_tests() -> None:
    # harness/ is what tests/ and bench/ share: it leans on the product only, so either
    # imports it without pulling in the other.
    imports = re.compile(r"^\s*(from|import)\s+(bench|tests)\b", re.M)
    found = [
        str(path.relative_to(ROOT))
        for path in (ROOT / "harness").rglob("*.py")
        if imports.search(path.read_text())
    ]
    assert found == []


def test_drivers_know_no_http() -> None:
    # Their errors carry a code; the server maps them to statuses (server/errors.py).
    found = [
        str(path.relative_to(ROOT))
        for path in (ROOT / "drivers").rglob("*.py")
        if re.search(r"http_status|fastapi|starlette", path.read_text())
    ]
    assert found == []


# What a client-only install (docs/running.md) lacks: the server's dependencies.
SERVER_DEPENDENCIES = (
    "fastapi", "starlette", "uvicorn", "aiortc", "av", "pinocchio", "cv2", "viser",
    "pydantic_settings", "mcap", "pyarrow", "cryptography", "psutil", "swagger_ui_bundle",
)  # fmt: skip

LIGHT_PROBE = """
import contextlib, io, sys
class Missing:  # as if not installed
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {missing!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Missing())
from telerobot.server.cli import main
# The leader arms' joint mirror: the models' limits, the SO-101 leader's bus.
import telerobot.drivers.robot.so101.leader, telerobot.drivers.master.sim_leader
from telerobot.drivers.robot.models import load_model
print("models", [load_model(n).dof for n in ("so101", "puma560")])
for argv in (["move", "--help"], ["master", "--help"]):
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        main(argv)
    print(argv[0], "ok")
print("serve", main(["serve"]))
"""


def test_a_client_only_install_runs_move_and_master_and_serve_says_what_is_missing() -> None:
    done = subprocess.run(
        [sys.executable, "-c", LIGHT_PROBE.format(missing=SERVER_DEPENDENCIES)],
        capture_output=True, text=True, timeout=60, cwd="/",
    )  # fmt: skip
    assert done.stdout.split("\n")[:4] == ["models [6, 6]", "move ok", "master ok", "serve 2"], (
        done.stderr
    )
    assert "needs uvicorn, which is not installed" in done.stderr
    assert "pip install telerobot" in done.stderr and "Traceback" not in done.stderr


def test_the_benches_run_from_a_checkout_through_the_cli() -> None:
    # The console script's path has only its bin/: the checkout's bench/ is found
    # beside the package's folders (an installed wheel has none: tests/test_wheel.py).
    done = subprocess.run(
        [str(Path(sys.executable).parent / "telerobot"), "bench", "kinematics", "--poses", "20",
         "--json"],
        capture_output=True, text=True, timeout=120, cwd="/",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1].startswith("{")
