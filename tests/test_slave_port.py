"""The arm's side of a master arm's two-port passivity (``telerobot.server.control.slave_port``,
docs/protocol.md, Passivity): the arm puts into a contact no more energy than the
master's operator put in, holds the rest back as owed, and catches up."""

from __future__ import annotations

import math

import numpy as np
import pytest

from telerobot.client.master.passivity import PassivityController
from telerobot.server.control.slave_port import (
    FORCE_FLOOR_N,
    MAX_OWED_M,
    OWED_FORGET_S,
    START_STIFFNESS_N_M,
    SlavePort,
)

UP = np.array([0.0, 0.0, 1.0])
DOWN_1MM = np.array([0.0, 0.0, -0.001])
EYE = np.eye(3)


def at(port: SlavePort, newtons: float, z: float, samples: int = 10) -> None:
    """The block pushes the tool up with ``newtons`` while the tool is measured at
    height ``z``, then an increment comes (``settle``)."""
    for _ in range(samples):
        port.add_sample(newtons * UP, z * UP)
    port.settle()


def test_free_space_is_not_charged() -> None:
    port = SlavePort()
    at(port, 0.5 * FORCE_FLOOR_N, 0.0)  # a sensor's offset, no contact
    assert port.allow(DOWN_1MM, np.zeros(3)) == pytest.approx(DOWN_1MM)
    at(port, 0.5 * FORCE_FLOOR_N, -0.001)
    assert port.out == 0.0 and port.budget == 0.0


def test_into_a_contact_only_as_far_as_the_masters_energy() -> None:
    port = SlavePort()
    assert not np.any(port.owed_for(0.0))
    at(port, 10.0, 0.0)
    # No energy from the master yet: the part into the contact is held back; along the
    # surface the tool still moves.
    sideways = np.array([0.001, 0.0, -0.001])
    allowed = port.allow(sideways, np.zeros(3))
    assert allowed == pytest.approx([0.001, 0.0, 0.0])
    port.moved(allowed, sideways)
    assert port.owed == pytest.approx([0.0, 0.0, -0.001])
    # The operator pressed on what they felt: 5 mJ in. Against 10 N on a contact as
    # stiff as seen so far (none seen: START_STIFFNESS_N_M, slowly forgotten), it pays
    # for d with 10·d + k·d²/2 = 0.005; the rest of the 2 mm asked (1 new, 1 owed)
    # stays owed.
    at(port, 10.0, 0.0)
    port.master_energy(0.005, 0.0)
    want = DOWN_1MM + port.owed_for(0.01)
    allowed = port.allow(want, np.zeros(3))
    k = port.stiffness
    assert 0.9 * START_STIFFNESS_N_M < k <= START_STIFFNESS_N_M
    reach = (math.sqrt(100 + 2 * k * 0.005) - 10) / k
    assert allowed[2] == pytest.approx(-reach) and 0.0001 < reach < 0.0005
    port.moved(allowed, want)
    assert port.owed[2] == pytest.approx(-0.002 + reach)
    # The tool measured moving in, the force rising with it: the books count the work
    # as it happens, and the contact's stiffness is seen from it.
    port.add_sample(10.0 * UP, np.zeros(3))
    port.add_sample((10.0 + 2 * k * reach) * UP, -reach * UP)
    assert port.out == pytest.approx(reach * (10.0 + k * reach))
    at(port, 10.0 + 2 * k * reach, -reach)
    assert port.stiffness == pytest.approx(2 * k)


def test_the_target_ahead_of_a_lagging_arm_is_spent_already() -> None:
    # A busy machine: the arm lags its target into the block. The lead will cost
    # F·lead + k·lead²/2 as the arm gets there, at a force rising to F + k·lead; the
    # budget (5 mJ, at 10 N, k = 2·10⁴ N/m) pays only for the rest: 0.37 mm more with
    # the arm at its target, 0.17 mm with 0.2 mm of lead, nothing with 0.4 mm (5.6 mJ).
    port = SlavePort()
    port.stiffness = 2.0e4
    port.master_energy(0.005, 0.0)
    at(port, 10.0, 0.0)
    reach = [-port.allow(DOWN_1MM, np.array([0.0, 0.0, -lead]))[2] for lead in (0, 2e-4, 4e-4)]
    assert reach == pytest.approx([3.66e-4, 1.66e-4, 0.0], abs=2e-6)


def test_a_long_step_into_a_stiff_contact_is_cut_to_what_the_budget_pays() -> None:
    # A catch-up after a stall (2 mm at once) against a 5·10⁴ N/m block at 5 N, with
    # 10 mJ in the budget: on the force alone it would cost 10 mJ and pass, and then
    # push 100 N more; with the stiffness seen it stops at ~0.55 mm (≈ 33 N).
    port = SlavePort()
    port.stiffness = 5.0e4
    port.master_energy(0.01, 0.0)
    at(port, 5.0, 0.0)
    allowed = port.allow(np.array([0.0, 0.0, -0.002]), np.zeros(3))
    assert -0.0006 < allowed[2] < -0.0005


def test_away_from_the_contact_is_free_and_gives_energy_back() -> None:
    port = SlavePort()
    at(port, 10.0, 0.0)
    up = np.array([0.0, 0.0, 0.002])
    assert port.allow(up, np.zeros(3)) == pytest.approx(up)
    port.add_sample(10.0 * UP, up)
    assert port.given == pytest.approx(0.02) and port.out == 0.0


def test_what_is_owed_is_bounded_and_forgotten_after_a_pause() -> None:
    port = SlavePort()
    at(port, 10.0, 0.0)
    far = np.array([0.0, 0.0, -0.05])
    port.owed_for(0.0)
    port.moved(np.zeros(3), far)
    assert np.linalg.norm(port.owed) == pytest.approx(MAX_OWED_M)
    assert port.dropped_m == pytest.approx(0.04)
    assert np.linalg.norm(port.owed_for(0.01)) == pytest.approx(MAX_OWED_M)
    assert not np.any(port.owed_for(0.01 + OWED_FORGET_S + 0.01))  # let go, re-centred


def test_the_masters_books_only_grow() -> None:
    port = SlavePort()
    port.master_energy(0.5, 0.1)
    port.master_energy(0.2, 0.05)  # late, or repeated: nothing changes
    port.master_energy(math.nan, math.inf)
    assert (port.master_in, port.master_out) == (0.5, 0.1)


def test_the_master_gives_back_no_more_than_the_arm_got_back() -> None:
    # The handle moves with the rendered force (the force does work on the hand): with
    # a budget of 1 mJ from the arm, the controller damps all output past it.
    pc = PassivityController()
    pc.budget = 0.001
    pc.put_in = pc.energy = 1.0  # plenty put in: the one-port alone would not damp
    v = np.array([0.0, 0.0, 0.1])
    for _ in range(1000):
        pc.step(np.array([0.0, 0.0, 1.0]), v, 0.001)
    assert pc.given <= 0.001 + 1e-9 and pc.dissipated > 0.09
