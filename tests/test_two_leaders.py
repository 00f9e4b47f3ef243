"""Two leaders (issue 33, part 5): a server driving two simulated SO-101s, the master
link learning its arms and their forces apart, two emulated leader buses (pseudo-
terminals) each mirrored into its own arm over one link, and `telerobot master`
choosing leaders for arms (or refusing, naming the arms)."""

from __future__ import annotations

import itertools
import subprocess
import threading
from collections.abc import Iterator

import httpx
import numpy as np
import pytest

from telerobot.client.master.bridge import BridgeSettings, MasterBridge
from telerobot.client.master.cli import LeaderPlan, master_arm, plan_leaders
from telerobot.client.master.joints import JointMirror, JointMirrors
from telerobot.client.master.link import LinkArm, PriorityLink, Reply, open_link
from telerobot.drivers.base import FloatArray, ForceSample, InvalidCommand, TelerobotError
from telerobot.drivers.master.sim import SimMaster
from telerobot.drivers.master.sim_leader import SimLeader
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.calibration import JointCalibration, So101Calibration
from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator
from telerobot.drivers.robot.so101.leader import So101Leader
from telerobot.protocol import messages as m
from tests.support import TOKEN, until
from tests.support.browser import NO_VIDEO
from tests.support.servers import BIN, serving, telerobot

SO101 = load_model("so101")
ARMS = {**NO_VIDEO, "TELEROBOT_ARMS": "left=so101:sim,right=so101:sim"}


def leader_calibration(zeros: list[float], dirs: list[int]) -> So101Calibration:
    """A leader assembled its own way: its zeros and directions are its own."""
    return So101Calibration(
        SO101.joint_names,
        tuple(
            JointCalibration(i + 1, z, d) for i, (z, d) in enumerate(zip(zeros, dirs, strict=True))
        ),
    )


LEFT_CAL = leader_calibration([2000, 2048, 2150, 1980, 2048, 2200], [-1, 1, 1, -1, 1, -1])
RIGHT_CAL = leader_calibration([2100, 1990, 2048, 2060, 1900, 2000], [1, -1, 1, 1, -1, 1])


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with serving(ARMS) as base:
        yield base


def joints(base: str, arm: str, field: str = "joints") -> FloatArray:
    state = httpx.get(base + "api/v1/robot/state", params={"arm": arm}).json()
    return np.array(state[field])


def place(base: str, arm: str, q: FloatArray) -> None:
    """Move one arm to ``q`` by REST (the lease taken and given back)."""
    with httpx.Client(
        base_url=base + "api/v1/", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
    ) as rest:
        lease = rest.post("lease", json={"name": "setup", "force": True}).json()
        rest.headers["X-Client-Id"] = lease["client_id"]
        r = rest.post(
            "robot/move",
            params={"arm": arm},
            json={"space": "joint", "mode": "absolute", "joints": q.tolist()},
        )
        assert r.status_code == 200, r.text
        rest.delete("lease")


class TwoArmLink:
    """What the bridge and ``master_arm`` use of a link to a two-arm server, recording
    the commands with the arm each names."""

    arms = (LinkArm(1, "left", 6), LinkArm(2, "right", 6))
    arm_names = ("left", "right")
    joint_count = 6
    arm_index = PriorityLink.arm_index
    arm = PriorityLink.arm
    _listed = PriorityLink._listed

    def __init__(self) -> None:
        self.offset = 0.0
        self.closed_reason = None
        self.autonomy = "off"
        self.force_arm = 0
        self.on_force = self.on_state = self.on_reply = None
        self.sent: list[tuple[str, int]] = []

    def cartesian(self, dX: object, rotvec: object, frame: object = None, arm: int = 0) -> int:
        self.sent.append(("CART_INC", arm))
        return len(self.sent)

    def energy(self, e_in: float, e_out: float, arm: int = 0) -> int:
        self.sent.append(("ENERGY", arm))
        return len(self.sent)

    def heartbeat(self) -> None:
        pass


# ---------------------------------------------------------------- the link
def test_the_link_learns_the_arms_and_keeps_each_sensors_samples(server: str) -> None:
    """Each arm's sensor numbers its own samples: one stream's stale filter would drop
    one arm's as older than the other's. Per arm, none is dropped, and each says whose.
    (Not that none is lost: a loaded server's sensor or socket may skip some.)"""
    got: dict[int, list[int]] = {1: [], 2: []}
    lock = threading.Lock()

    def on_arm_force(arm: int, sample: ForceSample, received: float) -> None:
        with lock:
            got[arm].append(sample.seq)

    link = open_link(server, TOKEN, datagrams=False)
    link.on_arm_force = on_arm_force
    try:
        assert link.arms == (LinkArm(1, "left", 6), LinkArm(2, "right", 6))
        assert link.arm_index("right") == 2 and link.arm("left").joints == 6
        with pytest.raises(InvalidCommand, match=r"drives 2 arms \(left, right\): name the arm"):
            link.arm(0)
        with pytest.raises(InvalidCommand, match="no arm named 'middle' here"):
            link.arm_index("middle")
        until(lambda: min(map(len, got.values())) >= 200, what=lambda: f"{link.received_by_arm}")
        with lock:  # each arm's samples in order: none dropped as stale, none twice
            for seqs in got.values():
                assert all(b > a for a, b in itertools.pairwise(seqs)), seqs
        assert link.stale_samples == 0
        assert set(link.received_by_arm) == {1, 2}
        until(lambda: set(link.states) == {1, 2})  # a STATE for each arm
    finally:
        link.close()


def test_a_command_names_its_arm_and_one_without_is_refused(server: str) -> None:
    replies: list[tuple[str, int, str]] = []
    link = open_link(server, TOKEN, datagrams=False)
    link.on_reply = lambda r: replies.append((r.name, int(r.fields.get("seq", -1)), r.text))
    try:
        nowhere = link.joints([0.0] * 6)  # arm 0: "the only arm", and there are two
        until(lambda: any(seq == nowhere for _, seq, _ in replies))
        name, _, text = next(r for r in replies if r[1] == nowhere)
        assert name == "ERROR" and "left, right" in text, text
    finally:
        link.close()


# ---------------------------------------------------------------- two leaders
def emulated(cal: So101Calibration, pose: FloatArray) -> FeetechBusEmulator:
    return FeetechBusEmulator(start=dict(zip(cal.ids, map(float, cal.to_steps(pose)), strict=True)))


def move(bus: BusLink, cal: So101Calibration, pose: FloatArray) -> None:
    """The operator's hand moves the leader (its servos' torque is off)."""
    for i, steps in zip(cal.ids, cal.to_steps(pose), strict=True):
        bus.servo(i).position = float(steps)


def test_two_leader_buses_each_mirror_into_their_own_arm(server: str) -> None:
    """Left leader → left arm only, then right → right only; one link, one lease."""
    home = SO101.pose(SO101.home_pose)
    # The arms apart, so that a mirror given the other arm's state would misalign.
    place(server, "left", home)
    place(server, "right", home + np.array([-0.4, 0.3, -0.3, -0.3, 0.5, 0.4]))
    left0, right0 = joints(server, "left"), joints(server, "right")
    with (
        BusLink.on_pty(emulated(LEFT_CAL, left0)) as left_bus,
        BusLink.on_pty(emulated(RIGHT_CAL, right0)) as right_bus,
    ):
        link = open_link(server, TOKEN, datagrams=False, name="two leaders")
        # A servo has 0.25 s to answer, not the driver's 20 ms: the emulators are threads
        # here, kept off the CPU for longer on a loaded machine.
        mirrors = JointMirrors(
            [
                JointMirror(
                    So101Leader(bus.url, cal, reply_timeout=0.25), link, SO101.joint_names, arm=arm
                )
                for bus, cal, arm in ((left_bus, LEFT_CAL, "left"), (right_bus, RIGHT_CAL, "right"))
            ]
        )
        left, right = mirrors.mirrors
        assert (left.arm, right.arm) == (1, 2)
        mirrors.start()
        try:
            until(
                lambda: left.following and right.following,
                what=lambda: f"{left.status}; {right.status}; {mirrors.last_error}",
            )
            # Should the dead-man halt an arm on a loaded machine (a command held up past
            # it), the arm stops where it is and the increments on their way are lost:
            # it ends a few hundredths of a radian short. So: it follows (0.3 rad, to
            # within 0.05); the other arm does not move (within 0.01).
            step = np.array([0.3, -0.3, 0.3, -0.2, 0.3, 0.3])
            move(left_bus, LEFT_CAL, left0 + step)
            until(
                lambda: np.abs(joints(server, "left") - (left0 + step)).max() < 0.05,
                what=lambda: f"{left.status}; {left.last_error}; {joints(server, 'left')}",
                poll=0.1,
            )
            assert np.abs(joints(server, "right", "target_joints") - right0).max() < 0.01
            move(right_bus, RIGHT_CAL, right0 - step)
            until(
                lambda: np.abs(joints(server, "right") - (right0 - step)).max() < 0.05,
                what=lambda: f"{right.status}; {right.last_error}; {joints(server, 'right')}",
                poll=0.1,
            )
            # (Within 0.05 of where the left leader took it, as above; it did not move on.)
            left1 = joints(server, "left", "target_joints")
            assert np.abs(left1 - (left0 + step)).max() < 0.05
            assert left.commands_sent > 0 and right.commands_sent > 0
            safety = httpx.get(server + "api/v1/safety").json()
            assert safety["controller"] == "two leaders"  # one client holds both arms
        finally:
            mirrors.stop()
            link.close()


def test_a_mirror_takes_only_its_own_arms_state_and_status() -> None:
    link = TwoArmLink()
    mir = JointMirror(SimLeader(SO101), link, SO101.joint_names, arm="right")  # type: ignore[arg-type]
    here = SO101.pose("ready")
    mir._on_state({"arm": 1, "status": 3, "flags": 1, "joints": (here + 1).tolist()})
    assert mir._follower is None  # the left arm's
    mir._on_state({"arm": 2, "status": 3, "flags": 1, "joints": here.tolist()})
    assert np.allclose(mir._follower, here)  # type: ignore[arg-type]
    status = {"kind": int(m.EventKind.STATUS)}
    mir._on_reply(Reply("EVENT", status, "left: ERROR: servo 3 stopped answering"))
    assert mir.arm_message is None
    mir._on_reply(Reply("EVENT", status, "right: ERROR: servo 2 stopped answering"))
    assert mir.arm_message == "ERROR: servo 2 stopped answering"


# ---------------------------------------------------------------- the command line
def test_leaders_are_planned_per_arm_or_refused_with_the_arms_named() -> None:
    one, two = ["arm"], ["left", "right"]
    assert plan_leaders("so101", None, None, None, one) == [LeaderPlan("", "/dev/ttyACM1", None)]
    assert plan_leaders("so101", ["/dev/x"], ["c.json"], None, one) == [
        LeaderPlan("", "/dev/x", "c.json")
    ]
    ports = ["left=/dev/ttyACM0", "right=socket://127.0.0.1:7010"]
    cals = ["left=l.json", "right=r.json"]
    assert plan_leaders("so101", ports, cals, None, two) == [
        LeaderPlan("left", "/dev/ttyACM0", "l.json"),
        LeaderPlan("right", "socket://127.0.0.1:7010", "r.json"),
    ]
    assert plan_leaders("so101", ["/dev/x"], None, ["right"], two) == [
        LeaderPlan("right", "/dev/x", None)
    ]
    assert [p.arm for p in plan_leaders("sim", None, None, ["left", "right"], two)] == two
    refusals = [
        (dict(), r"drives 2 arms \(left, right\): give each leader the bus of its arm"),
        (dict(ports=["middle=/dev/x"]), "no arm 'middle': it drives left, right"),
        (dict(ports=["/dev/x", "/dev/y"]), "2 given without their arms"),
        (dict(ports=ports), "each leader has its own calibration"),
        (dict(ports=ports, cals=["one.json"]), "each leader has its own calibration"),
        (dict(arms=["left", "right"]), "would read one bus"),
        (dict(ports=["left=/dev/x"], cals=["right=r.json"]), "no leader drives right"),
    ]
    for given, said in refusals:
        with pytest.raises(TelerobotError, match=said):
            plan_leaders("so101", given.get("ports"), given.get("cals"), given.get("arms"), two)


def test_the_master_command_mirrors_a_scripted_leader_into_each_arm(server: str) -> None:
    home = SO101.pose(SO101.home_pose)  # where the scripted leaders start
    for arm in ("left", "right"):
        place(server, arm, home)
    with telerobot(
        "master", "--server", server, "--token", TOKEN, "--device", "sim-leader",
        "--arm", "left", "--arm", "right",
        wait_for=r"Leader sim-leader mirrored onto the right SO-101 .* as operator",
    ):  # fmt: skip
        # The scripted leaders sway each arm's first joint: both arms follow.
        for arm in ("left", "right"):
            start = joints(server, arm, "target_joints")[0]
            until(
                lambda arm=arm, start=start: (
                    abs(joints(server, arm, "target_joints")[0] - start) > 0.05
                ),
                timeout=20,
                poll=0.1,
            )
    # One leader, no arm named: refused, the arms listed, nothing opened.
    out = subprocess.run(
        [str(BIN), "master", "--server", server, "--token", TOKEN, "--device", "so101-leader"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1 and "drives 2 arms (left, right)" in out.stderr, out.stderr


# ---------------------------------------------------------------- a haptic master's arm
def test_a_haptic_master_drives_the_arm_it_names() -> None:
    link = TwoArmLink()
    with pytest.raises(TelerobotError, match=r"drives 2 arms \(left, right\).*--arm NAME"):
        master_arm(link, None)  # type: ignore[arg-type]
    with pytest.raises(TelerobotError, match="no arm named 'middle'"):
        master_arm(link, ["middle"])  # type: ignore[arg-type]
    assert master_arm(link, ["right"]) == 2  # type: ignore[arg-type]
    clock = [0.0]
    device = SimMaster(
        lambda t: (np.array([0.0, 0.0, -0.01 * t]), True), time_source=lambda: clock[0]
    )
    bridge = MasterBridge(device, link, BridgeSettings(), arm=2)  # type: ignore[arg-type]
    assert link.force_arm == 2  # its arm's forces only
    R = {f"r{i}{j}": float(i == j) for i in range(3) for j in range(3)}
    bridge._on_state({"arm": 1, "flags": int(m.StateFlags.YOU_HAVE_CONTROL), **R})
    assert not bridge.has_control and bridge.states_received == 0  # the left arm's
    bridge._on_state({"arm": 2, "flags": int(m.StateFlags.YOU_HAVE_CONTROL), **R})
    assert bridge.has_control
    device.open()
    for n in range(100):
        clock[0] = n / 1000
        bridge.tick()
    assert {"CART_INC", "ENERGY"} <= {kind for kind, _ in link.sent}
    assert {arm for _, arm in link.sent} == {2}
