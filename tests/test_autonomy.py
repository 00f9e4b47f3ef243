"""Supervised autonomy (telerobot/server/control/autonomy.py): a policy drives once a
person lets it, an operator pauses, takes over and hands back; the e-stop, the force
limit and a lapse pause it. The DecisionServer on the simulated PUMA in virtual time.
The rule over generated sequences: tests/test_autonomy_rule.py."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from telerobot.drivers.base import ForceSample
from telerobot.drivers.clock import ManualClock
from telerobot.server.control.autonomy import AutonomyState, Mode, ReleaseTo, Supervised
from telerobot.server.control.clients import Client
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed, SafetyStop
from tests.support import TOKEN
from tests.support.decision import RecordingPuma, join_policy, make, policy_let_drive

STEP = np.array([0.01, 0, 0, 0, 0, 0])


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


async def policy_driving(
    clock: ManualClock,
) -> tuple[DecisionServer, RecordingPuma, Client, Client, list[AutonomyState]]:
    """A policy holding the lease and driving; "alice", an operator, supervising."""
    ds, robot = await make(clock)
    said: list[AutonomyState] = []
    ds.events.autonomy_changed.subscribe(said.append)
    policy, alice = await policy_let_drive(ds)
    await ds.joint_increment(policy.id, STEP)
    return ds, robot, policy, alice, said


async def test_a_policy_needs_a_policy_token_and_the_operator_token_is_refused(
    clock: ManualClock,
) -> None:
    ds, _ = await make(clock)
    with pytest.raises(NotAllowed, match="needs a policy token"):
        ds.join("sneaky", None, policy=True)
    with pytest.raises(NotAllowed, match=r"operator token cannot join as a policy.*policy-token"):
        ds.join("act-policy", TOKEN, policy=True)
    _, secret = ds.clients.policy_tokens.issue("act")
    with pytest.raises(NotAllowed, match="joins only as a policy"):
        ds.join("act", secret)  # as a person: refused
    token = ds.clients.policy_tokens.list()[0]
    policy = ds.join("act", secret, policy=True)
    assert policy.policy and policy.policy_token == token.id
    await ds.revoke_policy_token(token.id)
    assert ds.clients.known(policy.id) is None  # gone with its token
    with pytest.raises(NotAllowed, match="not valid \\(revoked\\?\\)"):
        ds.join("act", secret, policy=True)


async def test_a_policy_token_can_only_drive(clock: ManualClock) -> None:
    ds, _, policy, alice, _ = await policy_driving(clock)
    await ds.estop(None, "e-stop pressed")
    with pytest.raises(NotAllowed, match="only a person can reset"):
        await ds.reset(policy.id)
    for act in (ds.pause, ds.resume_policy):
        with pytest.raises(NotAllowed, match="only an operator supervises"):
            await act(policy.id)
    with pytest.raises(NotAllowed):
        ds.master_energy(policy.id, 0.0, 0.0)
    await ds.reset(alice.id)
    await ds.take_lease(alice.id)
    with pytest.raises(NotAllowed, match="never takes it from anyone"):
        await ds.take_lease(policy.id, force=True)
    other = join_policy(ds, "other-policy")
    await ds.release_lease(alice.id)  # back to the first policy
    with pytest.raises(NotAllowed, match="never takes it from anyone"):
        await ds.take_lease(other.id, force=True)  # nor from another policy


async def test_a_policy_taking_control_waits_for_a_person(clock: ManualClock) -> None:
    ds, robot = await make(clock)
    policy = join_policy(ds)
    alice = ds.join("alice", TOKEN)
    await ds.take_lease(policy.id)
    assert ds.autonomy.mode is Mode.PAUSED and "waits until a person" in ds.autonomy.cause
    with pytest.raises(Supervised, match="resumes you"):
        await ds.joint_increment(policy.id, STEP)
    assert robot.sent == []
    await ds.resume_policy(alice.id)
    await ds.joint_increment(policy.id, STEP)
    assert len(robot.sent) == 1


async def test_path_1_a_hand_back_with_the_estop_latched_stays_paused_after_the_reset(
    clock: ManualClock,
) -> None:
    """The page's own sequence: the dead-man takes over, Escape, let go (the page hands
    back with the e-stop latched), then the operator resets the e-stop."""
    ds, robot, policy, alice, _ = await policy_driving(clock)
    await ds.take_lease(alice.id)
    await ds.estop(alice.id, "e-stop pressed")
    await ds.release_lease(alice.id)  # the page's hand-back, 0.6 s after letting go
    assert ds.lease_holder == policy.id and ds.autonomy.mode is Mode.PAUSED
    assert "e-stop latched" in ds.autonomy.cause
    await ds.reset(alice.id)
    sent = len(robot.sent)
    await clock.advance(0.05)
    with pytest.raises(Supervised):
        await ds.joint_increment(policy.id, STEP)
    assert len(robot.sent) == sent and ds.autonomy.mode is Mode.PAUSED
    await ds.resume_policy(alice.id)  # a person's go
    await ds.joint_increment(policy.id, STEP)


async def test_path_2_a_policy_cannot_reset_the_estop_and_retaking_the_lease_stays_paused(
    clock: ManualClock,
) -> None:
    ds, robot, policy, alice, _ = await policy_driving(clock)
    await ds.estop(None, "e-stop pressed")
    with pytest.raises(NotAllowed):
        await ds.reset(policy.id)
    await ds.reset(alice.id)
    await ds.release_lease(policy.id)
    await ds.take_lease(policy.id)
    sent = len(robot.sent)
    await clock.advance(0.05)
    with pytest.raises(Supervised):
        await ds.joint_increment(policy.id, STEP)
    assert len(robot.sent) == sent and ds.autonomy.mode is Mode.PAUSED


async def test_path_3_a_paused_policy_does_not_unpause_itself(clock: ManualClock) -> None:
    ds, robot = await make(clock)
    _, secret = ds.clients.policy_tokens.issue("act-policy")
    policy = ds.join("act-policy", secret, policy=True)
    alice = ds.join("alice", TOKEN)
    await ds.take_lease(policy.id)
    await ds.resume_policy(alice.id)
    await ds.pause(alice.id)
    await ds.release_lease(policy.id)  # release and take again
    await ds.take_lease(policy.id)
    await clock.advance(0.05)
    with pytest.raises(Supervised):
        await ds.joint_increment(policy.id, STEP)
    await ds.leave(policy.id)  # or reconnect: a restarted rollout, a crash-looping script
    again = ds.join("act-policy", secret, policy=True)
    await ds.take_lease(again.id)
    await clock.advance(0.05)
    with pytest.raises(Supervised):
        await ds.joint_increment(again.id, STEP)
    assert robot.sent == [] and ds.autonomy.mode is Mode.PAUSED


async def test_the_operator_takes_over_without_force_and_the_policy_is_told(
    clock: ManualClock,
) -> None:
    ds, robot, policy, alice, said = await policy_driving(clock)
    assert ds.autonomy.mode is Mode.AUTONOMOUS and said[-1].policy == "act-policy"
    sent = len(robot.sent)
    await ds.take_lease(alice.id)  # no force: a person always may
    assert ds.lease_holder == alice.id and ds.autonomy.mode is Mode.CORRECTING
    assert said[-1].operator == "alice" and said[-1].interventions == 1
    with pytest.raises(Supervised, match="alice is correcting: your command was not applied"):
        await ds.joint_increment(policy.id, STEP)
    assert ds.autonomy.refused == 1 and len(robot.sent) == sent  # nothing moved
    await clock.advance(0.05)
    await ds.joint_increment(alice.id, STEP)  # the operator drives
    await ds.release_lease(alice.id)  # hands back
    assert ds.lease_holder == policy.id and ds.autonomy.mode is Mode.AUTONOMOUS
    assert "handed back by 'alice'" in ds.autonomy.cause
    await ds.joint_increment(policy.id, STEP)  # drives on from where the arm is


async def test_release_can_leave_the_policy_paused(clock: ManualClock) -> None:
    ds, _, policy, alice, _ = await policy_driving(clock)
    ds.supervision.release_to = ReleaseTo.PAUSE
    await ds.take_lease(alice.id)
    await ds.release_lease(alice.id)
    assert ds.lease_holder == policy.id and ds.autonomy.mode is Mode.PAUSED
    with pytest.raises(Supervised, match="paused"):
        await ds.joint_increment(policy.id, STEP)
    await ds.resume_policy(alice.id)
    await clock.advance(0.05)
    await ds.joint_increment(policy.id, STEP)


async def test_pause_holds_the_policy_still_and_only_an_operator_resumes(
    clock: ManualClock,
) -> None:
    ds, robot, policy, alice, _ = await policy_driving(clock)
    with pytest.raises(NotAllowed, match="only an operator"):
        await ds.pause(policy.id)
    watcher = ds.join("watcher", None)
    with pytest.raises(NotAllowed):
        await ds.pause(watcher.id)
    await ds.pause(alice.id)
    assert ds.autonomy.mode is Mode.PAUSED and ds.lease_holder == policy.id
    sent = len(robot.sent)
    with pytest.raises(Supervised, match="paused by 'alice'"):
        await ds.joint_increment(policy.id, STEP)
    assert len(robot.sent) == sent
    with pytest.raises(NotAllowed):
        await ds.resume_policy(policy.id)  # a policy does not resume itself
    await ds.resume_policy(alice.id)
    assert ds.autonomy.mode is Mode.AUTONOMOUS
    await ds.joint_increment(policy.id, STEP)


async def test_a_correction_can_end_paused(clock: ManualClock) -> None:
    ds, _, policy, alice, _ = await policy_driving(clock)
    await ds.take_lease(alice.id)
    await ds.pause(alice.id)
    assert ds.lease_holder == policy.id and ds.autonomy.mode is Mode.PAUSED


async def test_the_estop_during_autonomy_pauses_it_until_reset_and_resumed(
    clock: ManualClock,
) -> None:
    ds, _, policy, alice, _ = await policy_driving(clock)
    await ds.estop(None, "e-stop pressed")
    assert ds.autonomy.mode is Mode.PAUSED and "e-stop" in ds.autonomy.cause
    with pytest.raises(SafetyStop, match="reset it first"):
        await ds.resume_policy(alice.id)
    await ds.reset(alice.id)  # the supervisor resets, though the policy holds the lease
    with pytest.raises(Supervised):
        await ds.joint_increment(policy.id, STEP)  # still paused: a person resumes it
    await ds.resume_policy(alice.id)
    await ds.joint_increment(policy.id, STEP)


async def test_the_force_limit_during_autonomy_pauses_it(clock: ManualClock) -> None:
    ds, _robot, _policy, _, said = await policy_driving(clock)
    ds.on_force(ForceSample(1, clock.now(), (80.0, 0.0, 0.0, 0.0, 0.0, 0.0)), ds.arms[0])
    await asyncio.sleep(0)
    assert ds.autonomy.mode is Mode.PAUSED and said[-1].cause == "force limit: 80.0 N"


async def test_a_policy_never_takes_control_from_a_person(clock: ManualClock) -> None:
    ds, _ = await make(clock)
    alice = ds.join("alice", TOKEN)
    policy = join_policy(ds)
    await ds.take_lease(alice.id)
    with pytest.raises(NotAllowed, match="never takes it from anyone"):
        await ds.take_lease(policy.id, force=True)
    assert ds.lease_holder == alice.id and ds.autonomy.mode is Mode.OFF


async def test_a_correcting_operator_whose_lease_lapses_hands_back_paused(
    clock: ManualClock,
) -> None:
    ds, _, policy, alice, _ = await policy_driving(clock)
    await ds.take_lease(alice.id)
    await ds.leave(alice.id)  # the page closed mid-correction
    assert ds.lease_holder == policy.id and ds.autonomy.mode is Mode.PAUSED
    assert "alice's control lapsed" in ds.autonomy.cause


async def test_the_policy_leaving_ends_the_session_and_the_operator_keeps_control(
    clock: ManualClock,
) -> None:
    ds, _, policy, alice, said = await policy_driving(clock)
    await ds.take_lease(alice.id)
    await ds.leave(policy.id)
    assert ds.autonomy.mode is Mode.OFF and ds.lease_holder == alice.id
    assert said[-1].cause == "the policy left"
    with pytest.raises(NotAllowed, match="no policy"):
        await ds.pause(alice.id)


async def test_every_command_is_reported_with_who_drove_and_the_mode(
    clock: ManualClock,
) -> None:
    ds, _robot = await make(clock)
    reports = []
    ds.events.command.subscribe(reports.append)
    policy, alice = await policy_let_drive(ds)
    await ds.joint_increment(policy.id, STEP)
    await ds.take_lease(alice.id)
    with pytest.raises(Supervised):
        await ds.joint_increment(policy.id, STEP)
    await clock.advance(0.05)
    await ds.joint_increment(alice.id, STEP)
    moves = [(r.role, r.autonomy, r.error is None) for r in reports if r.kind == "joint_increment"]
    assert moves == [
        ("policy", "autonomous", True),
        ("policy", "correcting", False),
        ("operator", "correcting", True),
    ]
