"""The operator at a Telerobot server (at its page, in a headset, at a master arm or a
leader arm) as LeRobot sees a teleoperator. Used by the ``lerobot_teleoperator_telerobot``
plugin (``integrations/lerobot/teleoperator``); it needs no LeRobot itself.

- ``action()``: the operator's joint targets, in LeRobot's units (``units``): the
  server's target for each arm (``GET /api/v1/robot/state``'s ``target_joints``), which
  is what the operator's input, whatever it is, has commanded, after the server's
  limits. The operator's commands reach the arm through the server already, so the
  ``telerobot`` robot plugin does not send these again while the operator holds
  control (docs/lerobot.md says how the two cooperate).
- **Two arms**: the robot plugin's shape (``parts``): every arm's keys prefixed with its
  name, two SO-101s named left and right as LeRobot's ``bi_so_leader`` gives
  ``bi_so_follower`` (``left_shoulder_pan.pos`` … ``right_gripper.pos``, left first).
- ``intervening()``: someone other than the robot plugin's client holds control
  (``GET /api/v1/safety``'s ``controller``): LeRobot's ``IS_INTERVENTION``.
- Force feedback needs nothing from LeRobot: the server streams the forces to the
  operator's page and master arm itself, at 1 kHz; ``send_feedback`` has nothing to do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import httpx
from pydantic import SecretStr

from telerobot.client.lerobot.parts import ArmPart, describe_arms, read_json
from telerobot.client.tokens import bearer, secret


@dataclass
class OperatorOptions:
    url: str
    # Reading needs none; sent if given (a str is held as a SecretStr: never shown).
    token: SecretStr | str
    robot_client_name: str = "lerobot"  # the robot plugin's name: its control is no intervention

    def __post_init__(self) -> None:
        self.token = secret(self.token)


class TelerobotOperator:
    def __init__(self, options: OperatorOptions) -> None:
        self.options = options
        self.parts: list[ArmPart] = []  # the server's arms, in their columns' order
        self._http: httpx.Client | None = None

    @property
    def connected(self) -> bool:
        return self._http is not None

    @property
    def keys(self) -> list[str]:
        """Every arm's joint keys, in order: the teleoperator's action."""
        return [k for p in self.parts for k in p.keys]

    def connect(self) -> None:
        o = self.options
        self.parts = describe_arms(o.url)
        base = o.url if o.url.endswith("/") else o.url + "/"
        self._http = httpx.Client(
            base_url=base + "api/v1/", headers=bearer(secret(o.token)), timeout=10, verify=False
        )

    def disconnect(self) -> None:
        if self._http is not None:
            self._http.close()
        self._http = None

    def _get(self, path: str, params: dict[str, str], what: str) -> dict[str, Any]:
        if self._http is None:
            raise ConnectionError("the Telerobot operator is not connected: call connect() first")
        body: dict[str, Any] = read_json(self._http, self.options.url, path, params, what)
        return body

    def action(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for part in self.parts:
            state = self._get("robot/state", part.query, f"{part.name}'s target")
            values = part.units.to_lerobot(state["target_joints"])
            out |= dict(zip(part.keys, map(float, values), strict=True))
        return out

    def controller(self) -> str | None:
        name = self._get("safety", {}, "who is in control").get("controller")
        return None if name is None else str(name)

    def intervening(self) -> bool:
        who = self.controller()
        return who is not None and who != self.options.robot_client_name
