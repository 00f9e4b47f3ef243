"""A stand-in learned policy for the supervision tests and bench.rollout: a real
priority-channel client that joins as a policy (HELLO's POLICY flag, with a policy token
it is issued over REST with the operator token it is given), takes control, is let drive
by a person's resume over REST (``go``: a policy never starts by itself), and sends a
small joint increment 30 times a second, back and forth, noting every reply (its time on
this machine's monotonic clock) and the arm's states (tool position and joints, on the
server's clock)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import httpx
import numpy as np

from telerobot.client.master.link import PriorityLink, Reply, open_link
from telerobot.protocol import messages as m

RATE_HZ = 30.0
CONTROL_S = 10.0  # taking control may wait this long (a loaded machine's server)
STEP_RAD = 0.002  # joint 1, each command: 0.06 rad/s, well under every limit


@dataclass
class Answer:
    at: float  # time.monotonic() when it came
    applied: bool
    text: str


def issue_policy_token(server: str, operator_token: str, name: str) -> str:
    """A new policy token's secret, issued by an operator over REST."""
    r = httpx.post(
        server.rstrip("/") + "/api/v1/policy-tokens",
        json={"name": name},
        headers={"Authorization": f"Bearer {operator_token}"},
        timeout=30,
        verify=False,
    )
    r.raise_for_status()
    return str(r.json()["token"])


def resume_policy(server: str, operator_token: str) -> dict[str, object]:
    """A person lets the policy drive (POST /autonomy/resume, no lease of its own)."""
    r = httpx.post(
        server.rstrip("/") + "/api/v1/autonomy/resume",
        headers={"Authorization": f"Bearer {operator_token}", "X-Telerobot-Client": "bench"},
        timeout=30,
        verify=False,
    )
    r.raise_for_status()
    return dict(r.json())


@dataclass
class PolicyClient:
    """``token``: the operator token (the person who issues the policy its own token and
    lets it drive); ``go``: resume it once it holds control."""

    server: str
    token: str
    name: str = "test-policy"
    go: bool = True
    answers: list[Answer] = field(default_factory=list)
    # (server time, tool position, joints) of every STATE
    states: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    autonomy: list[str] = field(default_factory=list)  # the modes the server said
    autonomy_at: list[float] = field(default_factory=list)  # when each came (monotonic)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.policy_token = issue_policy_token(self.server, self.token, self.name)
        self.link: PriorityLink = open_link(
            self.server, self.policy_token, datagrams=False, name=self.name, policy=True
        )
        self.link.on_reply = self._on_reply
        self.link.on_state = self._on_state
        self.flags = 0
        self._thread = threading.Thread(target=self._run, name="test-policy", daemon=True)

    def _on_reply(self, reply: Reply) -> None:
        if reply.name in ("ACK", "ERROR"):
            with self._lock:
                self.answers.append(Answer(time.monotonic(), reply.name == "ACK", reply.text))
        elif reply.name == "EVENT" and int(reply.fields["kind"]) == m.EventKind.AUTONOMY:
            with self._lock:
                self.autonomy.append(reply.text)
                self.autonomy_at.append(time.monotonic())

    def _on_state(self, fields: dict[str, object]) -> None:
        self.flags = int(fields["flags"])  # type: ignore[call-overload]
        p = np.array([fields["x"], fields["y"], fields["z"]], float)
        q = np.array(fields["joints"], float)
        with self._lock:
            self.states.append((float(fields["server_time"]), p, q))  # type: ignore[arg-type]

    @property
    def has_control(self) -> bool:
        return bool(self.flags & m.StateFlags.YOU_HAVE_CONTROL)

    def start(self) -> PolicyClient:
        for _ in range(5):  # the clock offset (server_now)
            self.link.ping()
        self.link.lease(m.LeaseAction.TAKE)
        deadline = time.monotonic() + CONTROL_S
        while not self.has_control:
            if time.monotonic() > deadline:
                raise AssertionError(f"the policy was not given control: {self.answers[-1:]}")
            time.sleep(0.005)
        if self.go:
            resume_policy(self.server, self.token)
        self._thread.start()
        return self

    def _run(self) -> None:
        period = 1.0 / RATE_HZ
        joints = self.link.joint_count
        k = 0
        while not self._stop.is_set():
            dq = [0.0] * joints
            dq[0] = STEP_RAD if (k // 30) % 2 == 0 else -STEP_RAD  # a second each way
            self.link.joints(dq, self.link.next_seq())
            k += 1
            self._stop.wait(period)

    def since(self, t: float) -> list[Answer]:
        with self._lock:
            return [a for a in self.answers if a.at >= t]

    def told_since(self, t: float, mode: str) -> float | None:
        """When the server first told this policy it is in ``mode`` after ``t``."""
        with self._lock:
            for text, at in zip(self.autonomy, self.autonomy_at, strict=True):
                if at >= t and f'"mode": "{mode}"' in text:
                    return at
        return None

    def refused_since(self, t: float) -> list[Answer]:
        return [a for a in self.since(t) if not a.applied]

    def applied_since(self, t: float) -> list[Answer]:
        return [a for a in self.since(t) if a.applied]

    def largest_step_m(self) -> float:
        """The largest tool move between two consecutive STATEs (50 Hz)."""
        return self.largest_steps()[0]

    def largest_steps(self, since: float = -np.inf, until: float = np.inf) -> tuple[float, float]:
        """The largest tool move (m) and joint move (rad) between two consecutive STATEs
        whose server times are within [since, until]."""
        with self._lock:
            kept = [s for s in self.states if since <= s[0] <= until]
        if len(kept) < 2:
            return 0.0, 0.0
        p = np.array([s[1] for s in kept])
        q = np.array([s[2] for s in kept])
        tool = float(np.linalg.norm(np.diff(p, axis=0), axis=1).max())
        return tool, float(np.abs(np.diff(q, axis=0)).max())

    def server_now(self) -> float:
        """This machine's monotonic clock on the server's (PING-synced)."""
        return time.monotonic() + self.link.offset

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        self.link.close()

    def __enter__(self) -> PolicyClient:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
