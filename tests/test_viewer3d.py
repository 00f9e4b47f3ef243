"""The 3D view of the workcell (viser): served on its own port, refreshed live,
cameras from the calibration."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from telerobot.calibration.affine import fit_affine
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.app import create_app, services_of
from telerobot.server.settings import Settings
from telerobot.server.viewer3d import decompose
from tests.support import TOKEN


def test_a_perspective_projection_decomposes_into_the_camera() -> None:
    cam = default_workcell().rig.left
    parts = decompose(cam.P * -3.7)  # any scale, either sign
    assert parts is not None
    K, R, t = parts
    assert pytest.approx(cam.K, abs=1e-6) == K
    assert pytest.approx(cam.R, abs=1e-9) == R and t == pytest.approx(cam.t, abs=1e-9)
    cell = default_workcell()
    affine = fit_affine(cell.fiducials[:4], cam.project(cell.fiducials[:4]), "left", 1280, 720)
    assert decompose(affine.P) is None  # no centre, no frustum


def test_the_view_is_served_refreshes_and_follows_the_calibration(tmp_path: Path) -> None:
    settings = Settings(operator_token=TOKEN, state_dir=tmp_path, viewer=True, viewer_port=0)
    with TestClient(create_app(settings), base_url="http://localhost") as client:
        state = client.get("/api/v1/viewer").json()
        assert state["error"] is None and state["port"] > 0
        page = httpx.get(f"http://127.0.0.1:{state['port']}/", timeout=10)
        assert page.status_code == 200 and "<html" in page.text.lower()
        view = services_of(client.app).viewer.view  # type: ignore[arg-type]
        r0 = view.refreshes
        deadline = time.monotonic() + 5
        while view.refreshes < r0 + 3:  # 20 Hz
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert view.camera_updates == 1
        cell = default_workcell()
        cam = cell.rig.left
        r = client.post(
            "/api/v1/calibration/fit",
            json={"camera": "left", "method": "dlt", "points": cell.fiducials.tolist(),
                  "pixels": cam.project(cell.fiducials).tolist()},
            headers={"Authorization": f"Bearer {TOKEN}"},
        )  # fmt: skip
        assert r.status_code == 200, r.text
        deadline = time.monotonic() + 5
        while view.camera_updates < 2:  # the new calibration's frustum
            assert time.monotonic() < deadline
            time.sleep(0.05)


def test_a_taken_port_moves_the_view_to_a_free_one_and_the_api_says_where(
    tmp_path: Path,
) -> None:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        taken = s.getsockname()[1]
        settings = Settings(
            operator_token=TOKEN, state_dir=tmp_path, viewer=True, viewer_port=taken
        )
        with TestClient(create_app(settings), base_url="http://localhost") as client:
            state = client.get("/api/v1/viewer").json()
            assert state["port"] not in (None, taken)
            page = httpx.get(f"http://127.0.0.1:{state['port']}/", timeout=10)
            assert page.status_code == 200
