"""The wheel is the product (docs/architecture.md, "The package"): built from this
checkout and installed into a fresh environment outside it, ``telerobot serve`` runs the
simulation and serves the operator page with its assets, the REST API and video to an
aiortc viewer; ``telerobot move`` and the Python client drive the arm through it. One
top-level package in it, neither ``bench``, ``harness`` nor ``tests``.

The fresh environment takes the wheel's dependencies from this one (a ``.pth`` line
naming its site-packages) instead of downloading ~500 MB again each run; the wheel
itself, its entry point, its package data and its imports are the wheel's own."""

from __future__ import annotations

import asyncio
import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from harness.aiortc_viewers import open_viewer
from tests.support import TOKEN
from tests.support.servers import serving

ROOT = Path(__file__).resolve().parents[1]


# What the wheel is built from (as the Dockerfile's wheel stage copies it).
SOURCES = ("pyproject.toml", "README.md", "telerobot", "backend", "drivers", "calibration")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert (ROOT / "backend" / "web" / "index.html").is_file(), "build the page first: make web"
    # From a copy: a build in the checkout would reuse (and pack) its build/ folder's
    # leftovers, e.g. an earlier page's assets.
    context = tmp_path_factory.mktemp("src")
    subprocess.run(["cp", "-a", *(str(ROOT / s) for s in SOURCES), str(context)], check=True)
    out = tmp_path_factory.mktemp("dist")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
         "--wheel-dir", str(out), "."],
        check=True, timeout=300, cwd=context, capture_output=True,
    )  # fmt: skip
    [built] = out.glob("telerobot-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh environment outside the checkout with the wheel installed: its bin/."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    bin_ = venv / "bin"
    [own] = (venv / "lib").glob("python3*/site-packages")
    # The dependencies, from this environment (not the checkout: nothing of it is on
    # the path), and Pinocchio's library path (cmeel's start-up hook) with them.
    (own / "_deps_from_the_test_env.pth").write_text(
        "\n".join([*(p for p in sys.path if p.endswith("site-packages")), "import cmeel_pth"])
        + "\n"
    )
    subprocess.run(
        [str(bin_ / "python"), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
         str(wheel)],
        check=True, timeout=300, cwd=venv, capture_output=True,
    )  # fmt: skip
    return bin_


def test_the_wheel_holds_one_package_and_the_built_page(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"telerobot"}
    for part in ("server", "drivers", "calibration", "protocol", "client"):
        assert f"telerobot/{part}/__init__.py" in names
    assert "telerobot/server/web/index.html" in names
    assert any(re.fullmatch(r"telerobot/server/web/assets/main-.*\.js", n) for n in names)
    assert not any(n.startswith(("bench/", "harness/", "tests/", "telerobot/bench")) for n in names)


def test_the_installed_wheel_serves_the_page_the_api_and_video_and_moves_the_arm(
    installed: Path, tmp_path: Path
) -> None:
    python = installed / "python"
    where = subprocess.run(
        [str(python), "-c", "import telerobot.server, sys; print(telerobot.server.__file__)"],
        capture_output=True, text=True, check=True, cwd=tmp_path,
    ).stdout  # fmt: skip
    assert str(ROOT) not in where and "site-packages" in where, where
    with serving({"TELEROBOT_VIDEO": "true"}, exe=installed / "telerobot", cwd=tmp_path) as base:
        page = httpx.get(base, timeout=10)
        assert page.status_code == 200 and "<html" in page.text.lower()
        assets = re.findall(r'(?:src|href)="/?(assets/[^"]+\.(?:js|css))"', page.text)
        assert any(a.endswith(".js") for a in assets) and any(a.endswith(".css") for a in assets)
        for asset in assets:
            r = httpx.get(base + asset, timeout=10)
            assert r.status_code == 200 and len(r.content) > 100, asset
        assert httpx.get(base + "api/v1/health", timeout=10).json()["status"] == "ok"
        assert asyncio.run(first_frame_mean(base)) > 10.0  # the simulated scene, not black

        before = np.array(httpx.get(base + "api/v1/robot/state").json()["position"])
        target = before + [0.0, 0.02, 0.0]
        env = {"TELEROBOT_URL": base, "TELEROBOT_OPERATOR_TOKEN": TOKEN, "PATH": str(installed)}
        moved = subprocess.run(
            [str(installed / "telerobot"), "move", "cartesian", *map(str, target)],
            capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env,
        )  # fmt: skip
        assert moved.returncode == 0, moved.stdout + moved.stderr
        after = np.array(httpx.get(base + "api/v1/robot/state").json()["position"])
        np.testing.assert_allclose(after, target, atol=2e-3)

        script = (
            "import json, sys\n"
            "from telerobot.client import Telerobot\n"
            "with Telerobot(sys.argv[1], sys.argv[2]) as robot:\n"
            "    robot.move_cartesian(json.loads(sys.argv[3]))\n"
            "    print(json.dumps(robot.state()['position']))\n"
        )
        back = subprocess.run(
            [str(python), "-c", script, base, TOKEN, json.dumps(before.tolist())],
            capture_output=True, text=True, timeout=120, cwd=tmp_path, check=True,
        ).stdout  # fmt: skip
        np.testing.assert_allclose(json.loads(back), before, atol=2e-3)


async def first_frame_mean(base: str) -> float:
    pc, track = await open_viewer(base)
    try:
        frame = await asyncio.wait_for(track.recv(), 30)
        return float(frame.to_ndarray(format="rgb24").mean())
    finally:
        await pc.close()


def test_the_benches_say_they_need_a_checkout(installed: Path, tmp_path: Path) -> None:
    done = subprocess.run(
        [str(installed / "telerobot"), "bench", "browser"],
        capture_output=True, text=True, timeout=60, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 2 and "checkout" in done.stderr, done.stderr


def dockerfile_stages() -> dict[str, list[tuple[str, str]]]:
    """docker/Dockerfile's instructions by stage (its ``AS`` name, the last one "")."""
    stages: dict[str, list[tuple[str, str]]] = {}
    current: list[tuple[str, str]] = []
    text = (ROOT / "docker" / "Dockerfile").read_text().replace("\\\n", " ")
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        word, _, rest = line.partition(" ")
        if word == "FROM":
            name = rest.split(" AS ")[1] if " AS " in rest else ""
            current = stages.setdefault(name, [])
        current.append((word, rest))
    return stages


def test_the_image_is_built_from_the_wheel_and_its_python_stages_work(
    tmp_path: Path, installed: Path
) -> None:
    # No container engine can pull base images here: the Python stages' commands run
    # as written against a copy of what they COPY, with this environment's pip.
    stages = dockerfile_stages()
    assert set(stages) == {"web", "wheel", ""}
    assert ("RUN", "npm run build") in stages["web"]  # into ../backend/web: vite.config.ts
    assert '"../backend/web"' in (ROOT / "web" / "vite.config.ts").read_text()
    context = tmp_path / "src"
    context.mkdir()
    for word, rest in stages["wheel"]:
        if word == "COPY" and not rest.startswith("--from"):
            *sources, dest = rest.split()
            for source in sources:
                target = context / dest / source if dest.endswith("/") else context / dest
                if (ROOT / source).is_dir():
                    subprocess.run(["cp", "-a", str(ROOT / source), str(target)], check=True)
                else:
                    target.write_bytes((ROOT / source).read_bytes())
        elif word == "COPY":  # the page from the web stage
            assert rest == "--from=web /src/backend/web backend/web"
            subprocess.run(["cp", "-a", str(ROOT / "backend" / "web"), str(context / "backend")])
    assert (context / "telerobot" / "server").is_symlink()  # kept as a link, as COPY does
    [build] = [rest for word, rest in stages["wheel"] if word == "RUN"]
    assert build == "pip wheel --no-cache-dir --no-deps --wheel-dir /dist ."
    dist = tmp_path / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", *build.split()[1:-2], str(dist), "--no-build-isolation", "."],
        check=True, timeout=300, cwd=context, capture_output=True,
    )  # fmt: skip
    [whl] = dist.glob("telerobot-*.whl")
    assert ("COPY", "--from=wheel /dist /dist") in stages[""]
    installs = [rest for word, rest in stages[""] if word == "RUN" and "pip install" in rest]
    assert installs == ["pip install --no-cache-dir /dist/telerobot-*.whl && rm -rf /dist"]
    assert not any("-e" in rest.split() for _, rest in stages[""])  # not editable
    # The final stage's install, into a throw-away environment (dependencies as in
    # `installed`), then what the image runs: the CLI, its page, the client.
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    [own] = (venv / "lib").glob("python3*/site-packages")
    [deps] = (installed.parent / "lib").glob("python3*/site-packages/_deps_from_the_test_env.pth")
    (own / deps.name).write_text(deps.read_text())
    subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "--no-cache-dir", "--no-deps",
         "--no-index", str(whl)],
        check=True, timeout=300, capture_output=True, cwd=tmp_path,
    )  # fmt: skip
    cmd = json.loads(next(rest for word, rest in stages[""] if word == "CMD"))
    assert cmd[:2] == ["telerobot", "serve"]
    for args in (["serve", "--help"], ["move", "--help"], ["master", "--help"]):
        done = subprocess.run(
            [str(venv / "bin" / "telerobot"), *args],
            capture_output=True, text=True, timeout=60, cwd=tmp_path,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
    probe = (
        "import pathlib, telerobot.server.app as a, telerobot.client as c;"
        " print((pathlib.Path(a.__file__).parent / 'web' / 'index.html').is_file(), c.Telerobot)"
    )
    out = subprocess.run(
        [str(venv / "bin" / "python"), "-c", probe],
        capture_output=True, text=True, check=True, cwd=tmp_path,
    ).stdout  # fmt: skip
    assert out.startswith("True <class 'telerobot.client.rest.Telerobot'>"), out
