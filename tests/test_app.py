"""The server in-process (FastAPI TestClient runs the real lifespan)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from telerobot.drivers.robot.puma560.val_emulator import EmulatorLink, ValControllerEmulator
from telerobot.server.app import create_app
from telerobot.server.settings import Settings


def wait_for_status(client: TestClient, wanted: str, timeout: float = 10.0) -> dict[str, object]:
    deadline = time.monotonic() + timeout
    while True:
        state: dict[str, object] = client.get("/api/v1/robot/state").json()
        if state["status"] == wanted or time.monotonic() > deadline:
            return state
        time.sleep(0.02)


@pytest.fixture
def client() -> Iterator[TestClient]:
    # the sim starts at qz: no wait
    with TestClient(create_app(Settings(home_pose="qz")), base_url="http://localhost") as c:
        yield c


def test_health_and_status_page(client: TestClient) -> None:
    r = client.get("/api/v1/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    page = client.get("/status")
    assert (
        page.status_code == 200 and "Telerobot" in page.text and "/api/v1/robot/state" in page.text
    )


def test_state_of_the_simulated_robot(client: TestClient) -> None:
    state = wait_for_status(client, "READY")
    assert state["status"] == "READY" and state["driver"] == "sim-puma560"
    assert state["joints"] == pytest.approx([0] * 6, abs=1e-9)
    assert state["position"] == pytest.approx([0.4521, -0.15005, 1.10363 + 0.10], abs=1e-4)
    assert state["frame"] == "base"


def test_model_and_workcell_for_the_clients(client: TestClient) -> None:
    model = client.get("/api/v1/robot/model").json()
    assert model["model"] == "puma560" and model["dof"] == 6 and len(model["joints"]) == 6
    # Joint 3 sits a2 = 0.4318 m along joint 2's x axis (the DH table's row 2).
    assert model["joints"][2]["origin"][0][3] == pytest.approx(0.4318)
    assert [j["parent"] for j in model["joints"]] == [-1, 0, 1, 2, 3, 4]
    assert model["joint_limits_deg"][1] == pytest.approx([-45, 225]) and model["home_pose"] == "qz"
    urdf = client.get(model["urdf"])
    assert urdf.headers["content-type"].startswith("application/xml")
    assert urdf.text.count("<joint ") == 7 and 'name="puma560"' in urdf.text
    cell = client.get("/api/v1/workcell").json()
    assert [c["name"] for c in cell["cameras"]] == ["left", "right"]
    assert len(cell["fiducials"]) == 12 and cell["baseline"] == pytest.approx(0.12)


def test_openapi_schema_lists_the_endpoints(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    assert {
        "/api/v1/health",
        "/api/v1/robot/state",
        "/api/v1/robot/model",
        "/api/v1/workcell",
    } <= set(paths)


def test_unknown_route_is_404(client: TestClient) -> None:
    assert client.get("/api/v1/nope").status_code == 404


def test_server_keeps_serving_when_the_robot_cannot_connect() -> None:
    settings = Settings(robot="val", serial_port="/dev/no-such-port")
    with TestClient(create_app(settings), base_url="http://localhost") as c:
        state = wait_for_status(c, "ERROR")
        assert state["status"] == "ERROR"
        assert "cannot open serial port '/dev/no-such-port'" in str(state["message"])
        assert c.get("/api/v1/health").status_code == 200


def test_server_drives_the_val_emulator() -> None:
    with EmulatorLink.on_tcp(ValControllerEmulator(time_scale=0.02)) as link:
        settings = Settings(robot="val", serial_port=link.url)
        with TestClient(create_app(settings), base_url="http://localhost") as c:
            state = wait_for_status(c, "READY")
            assert state["status"] == "READY" and state["driver"] == "val-puma560"
            assert state["joints_deg"] == pytest.approx([0, 45, -180, 0, 45, 0], abs=1e-3)
        assert link.emulator.loaded["TRINC"]
