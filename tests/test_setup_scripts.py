"""What `make test` runs first on a fresh machine: finding a Python 3.12 that runs for
LeRobot's venv (tools/find-python312) and making or checking that venv
(tools/lerobot-venv), with a PATH holding pyenv's refusing ``python3.12`` shim and a HOME
with nothing in it. Fake interpreters are shell scripts: the scripts only run them."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FIND = REPO / "tools" / "find-python312"
VENV = REPO / "tools" / "lerobot-venv"

REFUSING_SHIM = """#!/bin/sh
echo "pyenv: python3.12: command not found" >&2
echo "The 'python3.12' command exists in these Python versions:" >&2
echo "  3.12.1" >&2
exit 127
"""
# Runs: answers the version check, says its version, and notes every call.
WORKING = """#!/bin/sh
echo "$@" >> "$(dirname "$0")/calls"
case "$*" in
  *"print(sys.version"*) echo 3.12.1 ;;
esac
exit 0
"""


def script(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(0o755)
    return path


def run(cmd: list[str], home: Path, shims: Path, **env: str) -> subprocess.CompletedProcess[str]:
    base = {"PATH": f"{shims}:/usr/bin:/bin", "HOME": str(home), "PYENV_ROOT": str(home / ".pyenv")}
    return subprocess.run(cmd, env={**base, **env}, capture_output=True, text=True, timeout=60)


def test_the_refusing_shim_is_passed_over_for_pyenvs_own_interpreter(tmp_path: Path) -> None:
    shims = tmp_path / "shims"
    script(shims / "python3.12", REFUSING_SHIM)
    real = script(tmp_path / "home/.pyenv/versions/3.12.1/bin/python3.12", WORKING)
    out = run([str(FIND)], tmp_path / "home", shims)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(real)


def test_nothing_that_runs_fails_with_one_line_naming_what_was_tried(tmp_path: Path) -> None:
    shims = tmp_path / "shims"
    script(shims / "python3.12", REFUSING_SHIM)
    (tmp_path / "home").mkdir()
    out = run([str(FIND)], tmp_path / "home", shims)
    assert out.returncode == 1 and out.stdout == ""
    line = out.stderr.strip()
    assert "\n" not in line and "tried:" in line and str(shims / "python3.12") in line
    assert "pyenv install 3.12" in line and "PYTHON312=" in line
    # The venv maker stops there too, with the same line, making nothing.
    venv = tmp_path / "home/.cache/telerobot/lerobot"
    out = run([str(VENV)], tmp_path / "home", shims, LEROBOT_VENV=str(venv), LEROBOT_SPEC="x==1")
    assert out.returncode != 0 and "LeRobot needs Python 3.12" in out.stderr
    assert not venv.exists()


def test_python312_set_by_hand_wins_if_it_runs(tmp_path: Path) -> None:
    shims = tmp_path / "shims"
    script(shims / "python3.12", REFUSING_SHIM)
    mine = script(tmp_path / "opt/python3.12", WORKING)
    script(tmp_path / "home/.pyenv/versions/3.12.1/bin/python3.12", WORKING)
    out = run([str(FIND)], tmp_path / "home", shims, PYTHON312=str(mine))
    assert out.stdout.strip() == str(mine)


def test_the_venv_stamp_holds_the_spec_and_a_changed_spec_installs_again(tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    python = script(venv / "bin/python", WORKING)
    calls = venv / "bin/calls"
    home, shims = tmp_path / "home", tmp_path / "shims"
    home.mkdir()
    shims.mkdir()
    env = {"LEROBOT_VENV": str(venv), "LEROBOT_SPEC": "lerobot[dataset]==0.6.1 pytest"}
    out = run([str(VENV)], home, shims, **env)
    assert out.returncode == 0, out.stderr
    assert "-m pip install --quiet lerobot[dataset]==0.6.1 pytest" in calls.read_text()
    stamp = (venv / ".installed-spec").read_text()
    assert "lerobot[dataset]==0.6.1 pytest" in stamp and "python 3.12.1" in stamp
    calls.unlink()
    out = run([str(VENV)], home, shims, **env)  # the same: nothing to do
    assert out.returncode == 0
    assert "pip install" not in (calls.read_text() if calls.exists() else "")
    out = run([str(VENV)], home, shims, **{**env, "LEROBOT_SPEC": "lerobot[dataset]==0.6.2"})
    assert out.returncode == 0 and "lerobot[dataset]==0.6.2" in calls.read_text()
    assert os.access(python, os.X_OK)
