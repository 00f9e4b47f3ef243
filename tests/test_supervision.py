"""A task supervised by a script: the task holds the lease for its
run, and the script that started it stays present by its heartbeats whether or not it
holds the lease, so a task longer than the window in which a silent script is
forgotten runs to its end; a script that does go silent is gone after that window and
its task stops, saying so. In virtual time on the DecisionServer and TaskRunner, and
end to end with the Python client against a real server (the window shortened by the
setting ``rest_client_idle_s``)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import httpx
import pytest

from harness.sim_cell import TOKEN as CELL_TOKEN
from harness.sim_cell import SimCell, push_start
from telerobot.client import Telerobot
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.control.errors import NotAllowed
from telerobot.server.tasks.runner import TaskSpec, TaskState
from telerobot.server.tasks.trajectory import StateSample, Trajectory
from tests.support import TOKEN
from tests.support.servers import serving

AUTH = {"Authorization": f"Bearer {TOKEN}"}


# ------------------------------------------------------------ virtual time
def slow_path(cell: SimCell, seconds: float, distance_m: float) -> Trajectory:
    """From the tool's pose along +x, ``distance_m`` in ``seconds`` (a slow taught move)."""
    pose = cell.robot.pose
    steps = int(seconds * 5)
    states = [
        StateSample(
            seconds * i / steps,
            pose.position + [distance_m * i / steps, 0.0, 0.0],
            pose.rotation.copy(),
        )
        for i in range(steps + 1)
    ]
    return Trajectory.from_samples(states, [], dt=0.1, source="a slow move")


async def supervised_run(
    cell: SimCell, path: Trajectory, *, heartbeats_until: float, limit_s: float
) -> tuple[str, float, float]:
    """A script's client (as ``POST /lease`` makes it: forgotten 60 s after its last
    request) takes the lease, starts the task and heartbeats every second until
    ``heartbeats_until`` (virtual s after the start); the task runs to its end. Returns
    the script's client id, when it last sent a heartbeat and when the task ended
    (virtual s after the start)."""
    ds = cell.decision
    script = ds.join("script", CELL_TOKEN, idle_expiry_s=60.0, lease_idle_s=5.0, source="rest")
    await ds.take_lease(script.id, force=True)
    task = await cell.runner.start(TaskSpec(path), script.id)
    assert ds.lease_holder == task.client_id and ds.supervises_holder(script.id)
    t0 = cell.clock.now()
    next_beat, last_beat = t0 + 1.0, 0.0
    while not task.state.finished:
        now = cell.clock.now()
        assert now - t0 < limit_s, f"task still {task.state} after {limit_s} s"
        if now >= next_beat and now - t0 <= heartbeats_until:
            ds.heartbeat(script.id)  # not the holder: kept present as the supervisor
            next_beat, last_beat = next_beat + 1.0, now - t0
        await cell.clock.advance(0.02)
    return script.id, last_beat, cell.clock.now() - t0


async def test_a_heartbeating_script_supervises_a_task_longer_than_its_idle_window() -> None:
    base = default_workcell()
    cell = SimCell(base, push_start(base))
    await cell.setup()
    try:
        path = slow_path(cell, 75.0, 0.03)  # as long as the 81 s task that used to stop at 74 %
        script_id, _, took = await supervised_run(cell, path, heartbeats_until=1e9, limit_s=120.0)
        task = cell.runner.list()[-1]
        assert task.state is TaskState.DONE, task.reason
        assert took > 60.0 + 5.0  # longer than a silent script is remembered
        assert cell.decision.lease_holder == script_id  # handed back at the end
        # The heartbeat keeps a lease its client holds; anyone else is told it is not theirs.
        cell.decision.heartbeat(script_id)
        bystander = cell.decision.join("bystander", CELL_TOKEN, source="rest")
        with pytest.raises(NotAllowed, match="you do not hold the lease"):
            cell.decision.heartbeat(bystander.id)
    finally:
        await cell.close()


async def test_a_script_that_goes_silent_is_gone_after_its_window_and_its_task_stops() -> None:
    base = default_workcell()
    cell = SimCell(base, push_start(base))
    await cell.setup()
    try:
        path = slow_path(cell, 100.0, 0.03)
        _, silent_from, took = await supervised_run(
            cell, path, heartbeats_until=10.0, limit_s=120.0
        )
        task = cell.runner.list()[-1]
        assert task.state is TaskState.STOPPED
        assert "supervising operator 'script' disconnected" in task.reason, task.reason
        assert "heartbeat" in task.reason  # how a script stays present
        assert 60.0 <= took - silent_from <= 60.0 + 1.5  # its window, then a sweep (1 s)
        assert cell.decision.lease_holder is None  # nobody to hand it back to
    finally:
        await cell.close()


# ------------------------------------------------------------ end to end
WINDOW_S = 1.5  # a silent script is forgotten this long after its last request


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with serving({"TELEROBOT_REST_CLIENT_IDLE_S": str(WINDOW_S)}) as base:
        yield base


def controller(base: str) -> object:
    return httpx.get(base + "api/v1/safety").json()["controller"]


@pytest.fixture(scope="module")
def taught(server: str) -> tuple[str, list[float]]:
    """A recording of a 2 cm move down with pauses around it (about 1.5 s), the arm
    back at its start: repeated at 0.25× it runs for several windows."""
    with Telerobot(server, TOKEN, name="teacher") as robot:
        start = robot.state()["position"]
        http = httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=30)
        assert http.post("recordings", json={"name": "supervision"}).status_code == 200
        time.sleep(0.6)
        robot.move_cartesian([0.0, 0.0, -0.02], relative=True, frame="base")
        time.sleep(0.6)
        file = http.post("recordings/active/stop").json()["file"]
        robot.move_cartesian(start)
    return file, start


def test_a_task_supervised_by_the_python_client_runs_to_its_end_and_hands_back(
    server: str, taught: tuple[str, list[float]]
) -> None:
    file, start = taught
    with Telerobot(server, TOKEN, name="python client", idle_timeout_s=1.0) as robot:
        task = robot.start_task(file, speed=0.25)
        assert task["state"] == "running", task
        # The task's run at 0.25× is several of the server's windows long.
        assert task["duration"] / 0.25 > 2.5 * WINDOW_S, task
        assert controller(server) == f"task {task['id']}"
        view = robot.wait_task(task["id"], timeout_s=120)
        assert view["state"] == "done", view
        # The keep-alive never stopped (its heartbeats were taken while the task held
        # the lease), so the lease came back and is kept past its idle timeout.
        assert robot.lease_error is None
        assert controller(server) == "python client"
        time.sleep(1.5)  # beyond idle_timeout_s
        assert controller(server) == "python client"
        robot.move_cartesian(start)
    assert controller(server) is None


def test_a_script_that_stops_sending_heartbeats_loses_its_task(
    server: str, taught: tuple[str, list[float]]
) -> None:
    file, _ = taught
    http = httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=30)
    cid = http.post("lease", json={"name": "silent script"}).json()["client_id"]
    r = http.post("tasks", json={"recording": file, "speed": 0.25}, headers={"X-Client-Id": cid})
    assert r.status_code == 200, r.text
    task_id = r.json()["id"]
    deadline = time.monotonic() + 60
    while (view := http.get(f"tasks/{task_id}").json())["state"] not in ("done", "stopped"):
        assert time.monotonic() < deadline, view
        time.sleep(0.1)
    assert view["state"] == "stopped", view
    assert "'silent script' disconnected" in view["reason"], view
    assert view["progress"] < 1.0
    assert controller(server) is None
    # Its id is forgotten: a late heartbeat says so.
    late = http.post("lease/heartbeat", headers={"X-Client-Id": cid})
    assert late.status_code == 403 and "unknown client" in late.json()["detail"]
    http.close()
