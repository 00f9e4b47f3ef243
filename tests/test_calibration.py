"""Calibration: each method recovers the simulated cameras from simulated clicks,
degenerate input is refused with a reason, results persist and serve the AR view."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from harness.work_area import work_area
from telerobot.calibration.affine import fit_affine
from telerobot.calibration.charuco import calibrate_intrinsics, fit_charuco, stereo_pose
from telerobot.calibration.dlt import fit_dlt
from telerobot.calibration.model import CalibrationError, CameraModel
from telerobot.calibration.store import CalibrationStore
from telerobot.drivers.camera.charuco_board import BoardSpec, board_poses, render_view
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.app import create_app
from telerobot.server.settings import Settings
from tests.support import TOKEN

CELL = default_workcell()
GRID = work_area()


def errors_px(model: CameraModel, cam: object) -> np.ndarray:
    return np.linalg.norm(model.project(GRID) - cam.project(GRID), axis=1)  # type: ignore[attr-defined]


def test_the_affine_method_is_exact_for_an_affine_camera_and_fits_its_four_points() -> None:
    rng = np.random.default_rng(1)
    P = np.vstack([rng.normal(0, 500, (2, 4)), [0, 0, 0, 1]])  # a weak-perspective camera
    X = CELL.fiducials[:4]
    uv = (np.hstack([X, np.ones((4, 1))]) @ P.T)[:, :2]
    model = fit_affine(X, uv, "left", 1280, 720)
    assert pytest.approx(P, abs=1e-6) == model.P
    # On the (perspective) simulated camera it fits its four fiducials exactly…
    cam = CELL.rig.left
    model = fit_affine(X, cam.project(X), "left", 1280, 720)
    assert model.max_px < 1e-6 and model.method == "affine"
    # …and misses the rest of the work area by pixels to tens of pixels (weak perspective).
    assert np.percentile(errors_px(model, cam), 95) > 5


@pytest.mark.parametrize("noise_px", [0.0, 0.5])
def test_dlt_recovers_the_ground_truth_projection(noise_px: float) -> None:
    rng = np.random.default_rng(2)
    for cam in (CELL.rig.left, CELL.rig.right):
        clicks = cam.project(CELL.fiducials) + rng.normal(0, noise_px, (len(CELL.fiducials), 2))
        model = fit_dlt(CELL.fiducials, clicks, cam.name, 1280, 720)
        if noise_px == 0:
            assert errors_px(model, cam).max() < 1e-6
            assert model.P / model.P[2, 3] == pytest.approx(cam.P / cam.P[2, 3], rel=1e-6)
        else:
            # Clicks off by 0.5 px (σ) at 12 points: the work area within a few pixels.
            assert np.percentile(errors_px(model, cam), 95) < 3.0
            assert 0 < model.rms_px < 1.0


def test_charuco_finds_the_intrinsics_the_pose_and_the_baseline() -> None:
    spec = BoardSpec()
    models = []
    for cam in (CELL.rig.left, CELL.rig.right):
        size = (cam.width, cam.height)
        views = [
            render_view(cam.K, cam.R, cam.t, size, bR, bt, spec)
            for bR, bt in board_poses(cam.R, cam.t, 0.9, spec, 10)
        ]
        K, dist, rms, used = calibrate_intrinsics(views, spec, size)
        assert used == 10 and rms < 0.5
        assert pytest.approx(cam.K, rel=0.01, abs=3.0) == K  # focal ±1 %, centre ±3 px
        model = fit_charuco(K, dist, CELL.fiducials, np.round(cam.project(CELL.fiducials)),
                            cam.name, cam.width, cam.height)  # fmt: skip
        assert np.percentile(errors_px(model, cam), 95) < 1.0
        models.append(model)
    _, t, baseline = stereo_pose(*models)
    assert baseline == pytest.approx(CELL.rig.baseline, rel=0.05)
    assert t[0] == pytest.approx(-baseline, rel=0.05)  # the right camera sits along +x


def test_charuco_without_a_visible_board_says_so() -> None:
    blank = [np.full((720, 1280), 110, np.uint8)] * 5
    with pytest.raises(CalibrationError, match="found in 0 of 5 views"):
        calibrate_intrinsics(blank, BoardSpec(), (1280, 720))


@pytest.mark.parametrize(
    ("fit", "points", "pixels", "message"),
    [
        (fit_affine, np.eye(3)[[0, 1, 2, 0]] * [1, 1, 0], np.zeros((4, 2)), "coplanar"),
        (fit_dlt, CELL.fiducials[8:].repeat(2, axis=0), np.zeros((8, 2)), "coplanar"),
        (fit_dlt, CELL.fiducials[:5], np.zeros((5, 2)), "at least 6 points"),
        (fit_affine, CELL.fiducials[:4], np.zeros((3, 2)), "4 points but 3 pixels"),
        (fit_affine, CELL.fiducials[:4, :2], np.zeros((4, 2)), "N×3"),
        (fit_dlt, CELL.fiducials, np.full((12, 2), np.nan), "NaN"),
    ],
)
def test_degenerate_input_is_refused_with_a_reason(
    fit: object, points: np.ndarray, pixels: np.ndarray, message: str
) -> None:
    with pytest.raises(CalibrationError, match=message):
        fit(points, pixels, "left", 1280, 720)  # type: ignore[operator]


def test_the_store_round_trips_and_refuses_unknown_files(tmp_path: Path) -> None:
    cam = CELL.rig.left
    model = fit_dlt(CELL.fiducials, cam.project(CELL.fiducials), "left", 1280, 720)
    store = CalibrationStore(tmp_path / "calibration.json")
    store.put(model)
    loaded = CalibrationStore(tmp_path / "calibration.json").load().cameras["left"]
    assert pytest.approx(model.P) == loaded.P and loaded.method == "dlt"
    assert loaded.residuals_px == pytest.approx(model.residuals_px)
    assert [p.name for p in tmp_path.iterdir()] == ["calibration.json"]  # no temp file left
    (tmp_path / "calibration.json").write_text(json.dumps({"format": "x", "version": 9}))
    with pytest.raises(CalibrationError, match="not a version-1"):
        CalibrationStore(tmp_path / "calibration.json").load()
    (tmp_path / "calibration.json").write_text("{not json")
    with pytest.raises(CalibrationError, match="cannot read"):
        CalibrationStore(tmp_path / "calibration.json").load()


@pytest.fixture
def state_dir(tmp_path: Path) -> Path:
    return tmp_path


def serve(state: Path) -> TestClient:
    return TestClient(
        create_app(Settings(operator_token=TOKEN, state_dir=state)), base_url="http://localhost"
    )


def test_the_api_fits_persists_serves_and_forgets(state_dir: Path) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    cam = CELL.rig.right
    body = {
        "camera": "right",
        "method": "dlt",
        "points": CELL.fiducials.tolist(),
        "pixels": np.round(cam.project(CELL.fiducials)).tolist(),
    }
    with serve(state_dir) as client:
        before = client.get("/api/v1/calibration").json()
        assert [c["source"] for c in before["cameras"]] == ["ground truth (simulation)"] * 2
        assert len(before["fiducials"]) == 12
        assert client.post("/api/v1/calibration/fit", json=body).status_code == 403
        r = client.post("/api/v1/calibration/fit", json=body, headers=auth)
        assert r.status_code == 200, r.text
        right = r.json()["cameras"][1]
        assert right["source"] == "calibrated" and right["method"] == "dlt"
        assert right["rms_px"] < 0.6
        bad = client.post(
            "/api/v1/calibration/fit",
            json={**body, "points": body["points"][:5], "pixels": body["pixels"][:5]},
            headers=auth,
        )
        assert bad.status_code == 422 and "at least 6 points" in bad.json()["detail"]
        no_k = client.post(
            "/api/v1/calibration/fit", json={**body, "method": "charuco"}, headers=auth
        )
        assert no_k.status_code == 422 and "intrinsics" in no_k.json()["detail"]
    with serve(state_dir) as client:  # a restart loads it
        again = client.get("/api/v1/calibration").json()["cameras"][1]
        assert again["source"] == "calibrated" and again["P"] == right["P"]
        r = client.delete("/api/v1/calibration", headers=auth)
        assert [c["source"] for c in r.json()["cameras"]] == ["ground truth (simulation)"] * 2
    assert not (state_dir / "calibration-sim.json").exists()


def test_the_api_runs_the_charuco_flow_on_the_simulation(state_dir: Path) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with serve(state_dir) as client:
        for cam in (CELL.rig.left, CELL.rig.right):
            r = client.post(
                f"/api/v1/calibration/intrinsics?camera={cam.name}&views=8", headers=auth
            )
            assert r.status_code == 200, r.text
            assert r.json()["views_used"] == 8 and r.json()["rms_px"] < 0.5
            assert client.get("/api/v1/calibration").json()["intrinsics_pending"]
            r = client.post(
                "/api/v1/calibration/fit",
                json={
                    "camera": cam.name,
                    "method": "charuco",
                    "points": CELL.fiducials.tolist(),
                    "pixels": np.round(cam.project(CELL.fiducials)).tolist(),
                },
                headers=auth,
            )
            assert r.status_code == 200, r.text
        state = client.get("/api/v1/calibration").json()
        assert state["baseline_m"] == pytest.approx(CELL.rig.baseline, rel=0.05)


def test_an_unreadable_calibration_file_is_kept_reported_and_the_server_serves(
    state_dir: Path,
) -> None:
    (state_dir / "calibration-sim.json").write_text("{broken")
    with serve(state_dir) as client:
        state = client.get("/api/v1/calibration").json()
        assert "cannot read" in state["error"]
        assert state["cameras"][0]["source"] == "ground truth (simulation)"
        assert client.get("/api/v1/robot/state").status_code == 200
    assert (state_dir / "calibration-sim.json").read_text() == "{broken"  # nothing lost


def _jpeg(image: np.ndarray) -> str:
    import base64

    import cv2

    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return "data:image/jpeg;base64," + base64.b64encode(data.tobytes()).decode()


def test_intrinsics_from_uploaded_views_and_their_checks(state_dir: Path) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    cam = CELL.rig.left
    spec = BoardSpec()
    size = (cam.width, cam.height)
    images = [
        _jpeg(render_view(cam.K, cam.R, cam.t, size, bR, bt, spec))
        for bR, bt in board_poses(cam.R, cam.t, 0.9, spec, 6)
    ]
    url = "/api/v1/calibration/intrinsics/views"
    with serve(state_dir) as client:
        r = client.post(url, json={"camera": "left", "images": images}, headers=auth)
        assert r.status_code == 200, r.text
        assert r.json()["views_used"] == 6
        assert np.array(r.json()["K"]) == pytest.approx(cam.K, rel=0.01, abs=3.0)
        assert client.get("/api/v1/calibration").json()["intrinsics_pending"] == ["left"]
        for bad, why in (
            (["not base64!"] * 4, "base64"),
            (["aGVsbG8="] * 4, "PNG or JPEG"),
            ([_jpeg(np.zeros((10, 10), np.uint8))] * 4, "must be 1280×720"),
        ):
            r = client.post(url, json={"camera": "left", "images": bad}, headers=auth)
            assert r.status_code == 422 and why in r.json()["detail"], r.text
        r = client.post(url, json={"camera": "left", "images": images[:2]}, headers=auth)
        assert r.status_code == 422  # fewer than 4 views
        # No video on this server: no board to show, and it says why.
        r = client.post("/api/v1/calibration/board", json={"view": 0}, headers=auth)
        assert r.status_code == 503 and "video is turned off" in r.json()["detail"]


def test_the_fiducials_come_from_the_settings_when_given(state_dir: Path) -> None:
    from pydantic import ValidationError

    mine = [[0.5, 0.0, 0.4], [0.7, 0.0, 0.4], [0.5, 0.2, 0.4], [0.5, 0.0, 0.6], [0.7, 0.2, 0.6]]
    with TestClient(
        create_app(Settings(operator_token=TOKEN, state_dir=state_dir, fiducials=mine)),
        base_url="http://localhost",
    ) as client:
        assert client.get("/api/v1/calibration").json()["fiducials"] == mine
    for bad in ([[0, 0, 0]] * 3, [[0, 0]] * 4, [[0, 0, float("nan")]] * 4):
        with pytest.raises(ValidationError, match="fiducials"):
            Settings(fiducials=bad)


def test_each_camera_rig_keeps_its_own_calibration() -> None:
    assert Settings().rig_name == "sim"
    assert Settings(camera="opencv", camera_devices=["/dev/video0", "/dev/video2"]).rig_name == (
        "opencv-dev_video0-dev_video2"
    )
    assert Settings(camera="opencv", camera_rig="bench-a").rig_name == "bench-a"
