"""What the server refused of the LeRobot robot's commands, said once a reason.

The robot's joint mirror sends 100 increments a second; while a policy is paused the
server refuses every one, each reply counting them ("412 refused so far"), and while a
person corrects it the robot sends none. ``Refusals`` takes those replies (on the link's
thread) and says, on the caller's (``say`` and ``withheld``, from ``send_action``):

- a refusal once, when its reason changes (its text, numbers aside), with what the
  supervisor can do in the state the server is in (``what_to_do``, from ``GET
  /api/v1/autonomy`` and the e-stop: a paused policy needs a person's resume, an
  e-stopped one a reset first, a correction the operator's hand-back);
- the robot not holding control, once, the same way;
- once commands are applied again, how many were refused (and actions not sent)
  meanwhile.
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable
from typing import Any

import httpx

from telerobot.client.lerobot.parts import read_json
from telerobot.client.master.link import Reply

log = logging.getLogger(__name__)

NUMBERS = re.compile(r"\d+(?:\.\d+)?")
NO_CONTROL = "no control"  # the reason of actions not sent: someone else holds control


def reason(text: str) -> str:
    """A refusal's reason: its text with the numbers taken out, so one state's refusals
    ("(412 refused so far)", "it waited 212 ms") are one reason."""
    return NUMBERS.sub("#", text)


def what_to_do(name: str, autonomy: dict[str, Any], estop: bool, refused: str | None) -> str:
    """The line said of a policy's commands not applied, for the server's supervision
    state (``GET /api/v1/autonomy``) and e-stop: why, and what a person does about it,
    at the page or over REST (docs/lerobot.md, "Supervising over REST"). ``refused``:
    the server's words, said where the state is no supervision's (a limit, a stale
    command)."""
    mode = autonomy.get("mode")
    cause = autonomy.get("cause") or "no cause said"
    if mode == "paused" and estop:
        return (
            f"{name} is PAUSED ({cause}) and the e-stop is latched: its commands are refused"
            " until a person resets the e-stop and lets it drive: at the page, reset, then P;"
            " over REST, take over (POST /api/v1/lease), POST /api/v1/safety/reset with its"
            " X-Client-Id, then POST /api/v1/autonomy/resume"
        )
    if mode == "paused":
        return (
            f"{name} is PAUSED ({cause}): its commands are refused until a person lets it"
            " drive: P at the page, or POST /api/v1/autonomy/resume with the operator token"
        )
    if mode == "correcting":
        who = autonomy.get("operator") or "an operator"
        return (
            f"{who} is correcting {name}: its actions are not applied until they hand back"
            " (H or letting go at the page; over REST, DELETE /api/v1/lease with their"
            " X-Client-Id) or a person resumes it (P, POST /api/v1/autonomy/resume)"
        )
    if mode == "off" and refused is None:
        return (
            f"{name} does not hold control ({cause}): a person gives it back with POST"
            " /api/v1/autonomy/resume (the operator token)"
        )
    if refused is None:
        return f"{name} does not hold control: its actions are not sent"
    return f"the server refused {name}'s commands: {refused}"


def supervision_of(url: str, headers: dict[str, str]) -> tuple[dict[str, Any], bool]:
    """The server's supervision state and whether the e-stop is latched."""
    base = url if url.endswith("/") else url + "/"
    with httpx.Client(base_url=base, headers=headers, timeout=5, verify=False) as http:
        autonomy = read_json(http, base, "api/v1/autonomy", {}, "its supervision")
        safety = read_json(http, base, "api/v1/safety", {}, "its e-stop")
    return dict(autonomy), bool(safety.get("estop"))


class Refusals:
    """The replies to the robot's increments (``on_reply``, on the link's thread) and the
    actions it did not send (``withheld``), said on the caller's thread (``say``).
    ``explain(refused)``: the line for a reason (``refused``: the server's words; None:
    not in control)."""

    def __init__(self, name: str, explain: Callable[[str | None], str]) -> None:
        self.name = name
        self._explain = explain
        self._lock = threading.Lock()
        self.refused = 0  # increments refused since connecting
        self._refused_run = 0  # refused since the last applied
        self._withheld_run = 0  # actions not sent since the last applied
        self._newest: str | None = None  # the newest refusal's words, in this run
        self._away = False  # not in control: refusals of increments sent before are old news
        self._ended: tuple[int, int] | None = None  # a run that ended, not yet said
        self._said_reason: str | None = None  # in this run
        self._said_line: str | None = None

    # ------------------------------------------------------------ the link's thread
    def on_reply(self, reply: Reply) -> None:
        with self._lock:
            if reply.name == "ERROR":
                self.refused += 1
                self._refused_run += 1
                if not self._away:
                    self._newest = reply.text
            elif reply.name == "ACK" and (self._refused_run or self._withheld_run):
                runs = self._ended or (0, 0)
                self._ended = (runs[0] + self._refused_run, runs[1] + self._withheld_run)
                self._refused_run = self._withheld_run = 0
                self._newest = None

    # ------------------------------------------------------------ the caller's thread
    def withheld(self) -> None:
        """An action not sent: someone else holds control."""
        with self._lock:
            self._withheld_run += 1
            self._away = True
            self._newest = None
        self._say(NO_CONTROL, None)

    def say(self) -> None:
        """In control: say what changed since the last call (a run of refusals that
        ended, a new reason)."""
        with self._lock:
            self._away = False
            ended, self._ended = self._ended, None
            newest = self._newest
        if ended is not None:
            self._said_reason = self._said_line = None
            refused, withheld = ended
            meanwhile = [f"{refused} of its commands refused"] if refused else []
            meanwhile += [f"{withheld} actions not sent"] if withheld else []
            log.info("%s drives again (meanwhile %s)", self.name, ", ".join(meanwhile))
        if newest is not None:
            self._say(reason(newest), newest)

    def _say(self, why: str, refused: str | None) -> None:
        if why == self._said_reason:
            return
        self._said_reason = why
        # Refused: a warning; not in control (a person corrects): what happens.
        level = logging.INFO if refused is None else logging.WARNING
        if not log.isEnabledFor(level):
            return  # (a caller that says them itself: no need to ask the server)
        line = self._explain(refused)
        if line != self._said_line:  # (a correction's refusals, then its lost control)
            log.log(level, "%s", line)
        self._said_line = line
