"""A small client for scripted moves over the REST API (SPEC: scripted moves).

    from telerobot.client import Telerobot

    with Telerobot("http://localhost:8000", token) as robot:   # takes the lease
        robot.move_cartesian([0.6, -0.1, 0.9])                 # returns when done
        print(robot.state()["joints"])
    # leaving the block releases the lease; an error stops the arm first

On a server with two arms or more, every move and state call names its arm:
``robot.arm("left").move_cartesian(...)`` (``robot.arms()`` lists them); one that
does not is refused with their names.

The lease is kept alive by a background heartbeat (every second: a scripted lease is
kept 5 s between moves), so a script may pause between moves; every command still
goes through the server's DecisionServer (lease, limits, dead-man, e-stop). While a
task this client started holds the lease (``start_task``), the same heartbeat keeps
the client present as its supervisor, and the lease comes back at the task's end.

The server and the token are named the same way here, in ``telerobot move`` and in
``telerobot master``: ``TELEROBOT_URL`` (default ``http://localhost:8000``) and
``TELEROBOT_OPERATOR_TOKEN``, else the token ``telerobot serve`` keeps on this machine.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import httpx
from pydantic import SecretStr

from telerobot.client.tokens import bearer, secret

HEARTBEAT_S = 1.0
DEFAULT_URL = "http://localhost:8000"
TASK_ENDED = ("done", "stopped", "aborted")


def stored_token() -> str | None:
    """The operator token of a server on this machine: ``TELEROBOT_OPERATOR_TOKEN``, or
    the one ``telerobot serve`` keeps (``TELEROBOT_STATE_DIR``, ``$XDG_CONFIG_HOME`` or
    ``~/.config``, then ``telerobot/operator-token``)."""
    if os.environ.get("TELEROBOT_OPERATOR_TOKEN"):
        return os.environ["TELEROBOT_OPERATOR_TOKEN"]
    folder = os.environ.get("TELEROBOT_STATE_DIR")
    if folder:
        path = Path(folder) / "operator-token"
    else:
        base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
        path = Path(base) / "telerobot" / "operator-token"
    return path.read_text().strip() if path.is_file() else None


def local_url() -> str:
    """``TELEROBOT_URL``, or the address ``make run`` serves on."""
    return os.environ.get("TELEROBOT_URL", DEFAULT_URL)


class TelerobotError(RuntimeError):
    """The server refused a request; the message is its ``detail``."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(f"{detail} (HTTP {status})")
        self.status = status
        self.detail = detail


class Telerobot:
    """``token``: the operator token (a ``str`` or a ``pydantic.SecretStr``), held as a
    ``SecretStr``: no repr, log line or error of the client shows it."""

    def __init__(
        self,
        url: str,
        token: str | SecretStr,
        *,
        name: str = "python client",
        idle_timeout_s: float = 5.0,
        take_over: bool = False,
        timeout_s: float = 120.0,
    ) -> None:
        self.url = url
        self.token = secret(token)
        self._http = httpx.Client(
            base_url=url.rstrip("/") + "/api/v1/",
            headers={**bearer(self.token), "X-Telerobot-Client": "python"},
            timeout=timeout_s,
        )
        self.name = name
        self.idle_timeout_s = idle_timeout_s
        self.take_over = take_over
        self.client_id: str | None = None
        self._stop = threading.Event()
        self._heartbeat: threading.Thread | None = None
        self.lease_error: str | None = None  # why the background heartbeat stopped

    def __repr__(self) -> str:
        return f"Telerobot({self.url!r}, name={self.name!r}, client_id={self.client_id!r})"

    @classmethod
    def local(cls, url: str | None = None, **options: Any) -> Telerobot:
        """The server on this machine (``local_url``) with its stored operator token."""
        token = stored_token()
        if not token:
            raise TelerobotError(
                401,
                "no operator token: set TELEROBOT_OPERATOR_TOKEN or run this where"
                " `telerobot serve` keeps it (~/.config/telerobot/operator-token)",
            )
        return cls(url or local_url(), token, **options)

    # ------------------------------------------------------------ requests
    def _call(
        self,
        method: str,
        path: str,
        body: dict[str, Any] | None = None,
        *,
        arm: str | None = None,
    ) -> Any:
        headers = {"X-Client-Id": self.client_id} if self.client_id else {}
        params = {"arm": arm} if arm is not None else None
        r = self._http.request(method, path, json=body, headers=headers, params=params)
        if r.status_code >= 400:
            try:
                detail = str(r.json().get("detail", r.text))
            except ValueError:
                detail = r.text
            raise TelerobotError(r.status_code, detail)
        return r.json()

    # ------------------------------------------------------------ the lease
    def connect(self) -> Self:
        granted = self._call(
            "POST",
            "lease",
            {"name": self.name, "force": self.take_over, "idle_timeout_s": self.idle_timeout_s},
        )
        self.client_id = granted["client_id"]
        self._stop.clear()
        self._heartbeat = threading.Thread(target=self._keep_alive, daemon=True)
        self._heartbeat.start()
        return self

    def _keep_alive(self) -> None:
        while not self._stop.wait(min(HEARTBEAT_S, self.idle_timeout_s / 3)):
            try:
                self._call("POST", "lease/heartbeat")
            except (TelerobotError, httpx.HTTPError) as exc:
                self.lease_error = str(exc)
                return

    def close(self) -> None:
        self._stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join(5)
        if self.client_id is not None:
            # If this fails, the server lets an idle script's lease lapse by itself.
            with contextlib.suppress(TelerobotError, httpx.HTTPError):
                self._call("DELETE", "lease")
            self.client_id = None
        self._http.close()

    def __enter__(self) -> Self:
        return self.connect()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc is not None and self.client_id is not None:
            with contextlib.suppress(TelerobotError, httpx.HTTPError):
                self.stop()
        self.close()

    # ------------------------------------------------------------ motion
    def arms(self) -> list[dict[str, Any]]:
        """The arms the server drives (name, index, model, dof, status, mount)."""
        result: list[dict[str, Any]] = self._call("GET", "robot/arms")
        return result

    def arm(self, name: str) -> Arm:
        """The arm called ``name``, driven under this client's lease."""
        return Arm(self, name)

    def move_joints(
        self,
        joints: Sequence[float],
        *,
        relative: bool = False,
        wait: bool = True,
        arm: str | None = None,
    ) -> dict[str, Any]:
        """One angle per joint (radians), absolute or relative; returns when done."""
        body = {
            "space": "joint",
            "mode": "incremental" if relative else "absolute",
            "joints": [float(j) for j in joints],
            "wait": wait,
        }
        result: dict[str, Any] = self._call("POST", "robot/move", body, arm=arm)
        return result

    def move_cartesian(
        self,
        position: Sequence[float],
        rotation: Sequence[Sequence[float]] | None = None,
        *,
        relative: bool = False,
        frame: str | None = None,
        wait: bool = True,
        arm: str | None = None,
    ) -> dict[str, Any]:
        """The tool to ``position`` (metres, robot base; keeps its orientation unless
        ``rotation``, a 3×3 matrix, is given), or by it if ``relative``."""
        body: dict[str, Any] = {
            "space": "cartesian",
            "mode": "incremental" if relative else "absolute",
            "position": [float(p) for p in position],
            "wait": wait,
        }
        if rotation is not None:
            body["rotation"] = [[float(v) for v in row] for row in rotation]
        if frame is not None:
            body["frame"] = frame
        result: dict[str, Any] = self._call("POST", "robot/move", body, arm=arm)
        return result

    def stop(self, *, arm: str | None = None) -> list[dict[str, Any]]:
        """Stop the arm named, or every arm: each stopped arm's state."""
        result: list[dict[str, Any]] = self._call("POST", "robot/stop", arm=arm)
        return result

    def estop(self) -> dict[str, Any]:
        result: dict[str, Any] = self._call("POST", "safety/estop")
        return result

    # ------------------------------------------------------------ tasks
    def start_task(self, recording: str, **options: Any) -> dict[str, Any]:
        """Repeat a recording (or its ``episode=``, or ``segment=(t0, t1)``) as a task
        on the server (``POST /api/v1/tasks``; the other options as there: ``speed``,
        ``approach``, ``compliance``, ``force_margin_n``, ``allow_jumps``). The task
        takes the lease for its run and hands it back at its end; this client supervises
        it meanwhile (its heartbeat keeps it present: closing the client ends the task).
        Returns the task's view (``id``, ``state``, ``progress``, …)."""
        result: dict[str, Any] = self._call("POST", "tasks", {"recording": recording, **options})
        return result

    def task(self, task_id: str) -> dict[str, Any]:
        result: dict[str, Any] = self._call("GET", f"tasks/{task_id}")
        return result

    def wait_task(self, task_id: str, *, timeout_s: float = 600.0) -> dict[str, Any]:
        """The task's view once it has ended (``state`` done, stopped or aborted, and
        ``reason``); TimeoutError if it runs longer than ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while (view := self.task(task_id))["state"] not in TASK_ENDED:
            if time.monotonic() > deadline:
                raise TimeoutError(f"task {task_id} still {view['state']} after {timeout_s:g} s")
            time.sleep(0.2)
        return view

    # ------------------------------------------------------------ reading
    def state(self, *, arm: str | None = None) -> dict[str, Any]:
        result: dict[str, Any] = self._call("GET", "robot/state", arm=arm)
        return result

    def force(self) -> dict[str, Any]:
        result: dict[str, Any] = self._call("GET", "force")
        return result

    def safety(self) -> dict[str, Any]:
        result: dict[str, Any] = self._call("GET", "safety")
        return result


class Arm:
    """One arm of a server that drives more (``Telerobot.arm``): the same calls, each
    naming this arm; the lease, its heartbeat and the e-stop are the client's."""

    def __init__(self, robot: Telerobot, name: str) -> None:
        self.robot = robot
        self.name = name

    def move_joints(
        self, joints: Sequence[float], *, relative: bool = False, wait: bool = True
    ) -> dict[str, Any]:
        return self.robot.move_joints(joints, relative=relative, wait=wait, arm=self.name)

    def move_cartesian(
        self,
        position: Sequence[float],
        rotation: Sequence[Sequence[float]] | None = None,
        *,
        relative: bool = False,
        frame: str | None = None,
        wait: bool = True,
    ) -> dict[str, Any]:
        return self.robot.move_cartesian(
            position, rotation, relative=relative, frame=frame, wait=wait, arm=self.name
        )

    def state(self) -> dict[str, Any]:
        return self.robot.state(arm=self.name)

    def stop(self) -> dict[str, Any]:
        return self.robot.stop(arm=self.name)[0]
