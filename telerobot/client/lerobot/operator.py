"""The operator at a Telerobot server (at its page, in a headset, at a master arm or a
leader arm) as LeRobot sees a teleoperator. Used by the ``lerobot_teleoperator_telerobot``
plugin (``integrations/lerobot/teleoperator``); it needs no LeRobot itself.

- ``action()``: the operator's joint targets, in LeRobot's units (``units``): the
  server's target for the arm (``GET /api/v1/robot/state``'s ``target_joints``), which
  is what the operator's input, whatever it is, has commanded, after the server's
  limits. The operator's commands reach the arm through the server already, so the
  ``telerobot`` robot plugin does not send these again while the operator holds
  control (docs/lerobot.md says how the two cooperate).
- ``intervening()``: someone other than the robot plugin's client holds control
  (``GET /api/v1/safety``'s ``controller``): LeRobot's ``IS_INTERVENTION``.
- Force feedback needs nothing from LeRobot: the server streams the forces to the
  operator's page and master arm itself, at 1 kHz; ``send_feedback`` has nothing to do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import httpx

from telerobot.client.lerobot.arm import describe_arm
from telerobot.client.lerobot.units import JointUnits


@dataclass
class OperatorOptions:
    url: str
    token: str
    robot_client_name: str = "lerobot"  # the robot plugin's name: its control is no intervention


class TelerobotOperator:
    def __init__(self, options: OperatorOptions) -> None:
        self.options = options
        self.units: JointUnits | None = None
        self._http: httpx.Client | None = None

    @property
    def connected(self) -> bool:
        return self._http is not None

    def connect(self) -> None:
        o = self.options
        self.units = describe_arm(o.url)
        base = o.url if o.url.endswith("/") else o.url + "/"
        headers = {"Authorization": f"Bearer {o.token}"} if o.token else {}
        self._http = httpx.Client(base_url=base + "api/v1/", headers=headers, timeout=10)

    def disconnect(self) -> None:
        if self._http is not None:
            self._http.close()
        self._http = None

    def _get(self, path: str) -> dict[str, Any]:
        if self._http is None:
            raise ConnectionError("the Telerobot operator is not connected: call connect() first")
        try:
            r = self._http.get(path)
            r.raise_for_status()
            body: dict[str, Any] = r.json()
        except (httpx.HTTPError, ValueError) as exc:
            raise ConnectionError(f"cannot read {path} from {self.options.url}: {exc}") from None
        return body

    def action(self) -> dict[str, float]:
        state = self._get("robot/state")
        assert self.units is not None
        values = self.units.to_lerobot(state["target_joints"])
        return {k: float(v) for k, v in zip(self.units.feature_names, values, strict=True)}

    def controller(self) -> str | None:
        name = self._get("safety").get("controller")
        return None if name is None else str(name)

    def intervening(self) -> bool:
        who = self.controller()
        return who is not None and who != self.options.robot_client_name
