"""The tasks REST API on the app (sim, real time): record a short scripted move,
repeat it as a task from that recording, read its path and state; the token and
the lease are needed to start one. A recording made with another arm model is listed
as such and refused (a PUMA's recording was offered on an SO-101)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from telerobot.server.app import create_app
from telerobot.server.recording.reader import read
from telerobot.server.settings import Settings
from tests.support import TOKEN

AUTH = {"Authorization": f"Bearer {TOKEN}"}


def wait_for(tc: TestClient, task_id: str, timeout: float = 60.0) -> dict[str, object]:
    deadline = time.monotonic() + timeout
    while True:
        view: dict[str, object] = tc.get(f"/api/v1/tasks/{task_id}").json()
        if view["state"] in ("done", "stopped", "aborted") or time.monotonic() > deadline:
            return view
        time.sleep(0.05)


def test_a_recorded_move_repeats_as_a_task(client: TestClient, tmp_path: Path) -> None:
    tc = client
    cid = tc.post("/api/v1/lease", json={"name": "script"}, headers=AUTH).json()["client_id"]
    h = {**AUTH, "X-Client-Id": cid}
    start = tc.get("/api/v1/robot/state").json()["position"]
    assert tc.post("/api/v1/recordings", json={"name": "teach"}, headers=AUTH).status_code == 200
    time.sleep(0.3)
    move = {"space": "cartesian", "mode": "incremental", "position": [0.0, 0.0, -0.02]}
    assert tc.post("/api/v1/robot/move", json=move, headers=h).status_code == 200
    time.sleep(0.3)
    rec = tc.post("/api/v1/recordings/active/stop", headers=AUTH).json()["file"]
    back = {"space": "cartesian", "mode": "absolute", "position": start}
    assert tc.post("/api/v1/robot/move", json=back, headers=h).status_code == 200

    body = {"recording": rec, "speed": 0.5, "compliance": {"axes": "z"}}
    # Its path before it runs (anyone may look; nothing moves): the task's own path.
    preview = tc.post("/api/v1/tasks/preview", json={"recording": rec}).json()
    assert tc.get("/api/v1/tasks").json() == []
    assert tc.post("/api/v1/tasks", json=body, headers=AUTH).status_code == 403  # no lease id
    # The repeat is recorded too: its status changes and its commands (source "task").
    assert tc.post("/api/v1/recordings", json={"name": "repeat"}, headers=AUTH).status_code == 200
    r = tc.post("/api/v1/tasks", json=body, headers=h)
    assert r.status_code == 200, r.text
    task = r.json()
    assert task["state"] == "running" and task["duration"] > 0.3
    path = tc.get(f"/api/v1/tasks/{task['id']}/path").json()
    assert abs(path["positions"][0][2] - start[2]) < 0.002
    assert abs(path["positions"][-1][2] - (start[2] - 0.02)) < 0.002
    assert preview["positions"] == path["positions"] and preview["id"] == "preview"
    view = wait_for(tc, task["id"])
    assert view["state"] == "done", view
    repeat = tc.post("/api/v1/recordings/active/stop", headers=AUTH).json()["file"]
    data = tc.get(f"/api/v1/recordings/{repeat}/download").content
    path = tmp_path / repeat
    path.write_bytes(data)
    states = [m["state"] for topic, _, m in read(path, ["/tasks"]) if m["id"] == task["id"]]
    assert states[0] == "running" and states[-1] == "done", states
    sources = {m["source"] for _, _, m in read(path, ["/commands"])}
    assert "task" in sources, sources
    end = tc.get("/api/v1/robot/state").json()["position"]
    assert abs(end[2] - (start[2] - 0.02)) < 0.003
    # The lease is back with the script: it can move again, and a second repeat from
    # here (the path's end, 2 cm from its start) is refused without an approach.
    r = tc.post("/api/v1/tasks", json=body, headers=h)
    assert r.status_code == 422 and "first pose" in r.json()["detail"], r.text
    assert tc.get("/api/v1/tasks/nope").status_code == 404


def serving_in_process(state: Path, **settings: Any) -> TestClient:
    """The app on the simulation with its state (and recordings) in ``state``."""
    app = create_app(
        Settings(
            state_dir=state,
            video=False,
            viewer=False,
            priority_port=0,
            operator_token=TOKEN,
            **settings,
        )
    )
    return TestClient(app, base_url="http://localhost")


def ready(tc: TestClient) -> None:
    deadline = time.monotonic() + 10
    while tc.get("/api/v1/robot/state").json()["status"] != "READY":
        assert time.monotonic() < deadline, tc.get("/api/v1/robot/state").json()
        time.sleep(0.01)


def test_a_recording_of_another_arm_model_is_listed_as_such_and_refused(tmp_path: Path) -> None:
    with serving_in_process(tmp_path, home_pose="qz") as puma:
        ready(puma)
        assert (
            puma.post("/api/v1/recordings", json={"name": "puma"}, headers=AUTH).status_code == 200
        )
        episode = puma.post(
            "/api/v1/recordings/active/episodes", json={"task": "stay"}, headers=AUTH
        )
        assert episode.status_code == 200, episode.text
        time.sleep(0.3)  # some states in it
        end = puma.post("/api/v1/recordings/active/episodes/end", json={}, headers=AUTH)
        assert end.status_code == 200, end.text
        rec = puma.post("/api/v1/recordings/active/stop", headers=AUTH).json()
        assert rec["robot_model"] == "puma560", rec  # the list says which arm made it
        source = {"recording": rec["file"], "episode": 0}
        preview = puma.post("/api/v1/tasks/preview", json=source, headers=AUTH)
        assert preview.status_code == 200, preview.text  # on its own arm model: fine

    # The same state folder, served with the SO-101: the PUMA's recording is listed with
    # its model (the page greys it out), and neither previewed nor run.
    with serving_in_process(tmp_path, robot_model="so101", home_pose="ready") as so101:
        ready(so101)
        assert so101.get("/api/v1/robot/model").json()["model"] == "so101"
        listed = so101.get("/api/v1/recordings", headers=AUTH).json()
        assert [(r["file"], r["robot_model"]) for r in listed] == [(rec["file"], "puma560")]
        refused = so101.post("/api/v1/tasks/preview", json=source, headers=AUTH)
        assert refused.status_code == 422, refused.text
        problem = refused.json()
        assert problem["type"] == "urn:telerobot:error:another_arm", problem
        assert "(puma560)" in problem["detail"] and "(so101)" in problem["detail"], problem
        assert rec["file"] in problem["detail"], problem
        cid = so101.post("/api/v1/lease", json={"name": "script"}, headers=AUTH).json()["client_id"]
        run = so101.post("/api/v1/tasks", json=source, headers={**AUTH, "X-Client-Id": cid})
        assert run.status_code == 422 and run.json()["type"] == problem["type"], run.text
        assert so101.get("/api/v1/tasks").json() == []  # nothing started
