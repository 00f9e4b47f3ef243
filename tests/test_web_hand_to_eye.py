"""Hand to eye in Debian's Chromium (issue 56; bench/hand_to_eye.py): a few motions
driven from the keys as an operator does, each found by the page in its decoded frames
(the simulated camera's motion mark) with every part of the loop present, none
negative, and the parts adding up to the whole. Behaviour only: the figures are the
bench's."""

from __future__ import annotations

import time

import pytest
from playwright.sync_api import Browser

from bench.hand_to_eye import PARTS, directions, drive
from tests.support.browser import open_page, take_control, wait

pytestmark = pytest.mark.browser

MOTIONS = 6
# A part may come out a hair below zero from the clock sync's error (the page's offset
# to the server's clock is known to within half the best ping's round trip).
CLOCK_SLACK_MS = 3.0


def test_each_motion_is_found_with_its_parts_adding_up(browser: Browser, server: str) -> None:
    import random

    page, errors = open_page(browser, server)
    take_control(page)
    wait(page, "window.telerobot.state && (window.telerobot.state.flags & 1)")
    page.evaluate("window.telerobot.handEye.start()")
    time.sleep(1.0)  # the glass meter reads the mark from its next clock message on
    rng = random.Random(1)
    drive(page, directions(MOTIONS, rng), rng)
    time.sleep(1.0)
    found = page.evaluate("window.telerobot.handEye.motions()")
    motions = found["motions"]
    # A loaded machine may lose one (a halt from a stalled page), never most.
    assert len(motions) >= MOTIONS - 1, found["missed"]
    for m in motions:
        parts = m["parts"]
        assert set(parts) == set(PARTS)
        assert all(parts[p] >= -CLOCK_SLACK_MS for p in PARTS), m
        assert sum(parts.values()) == pytest.approx(m["wholeMs"], abs=0.5), m
        assert m["movedPx"] >= 3
    assert not errors
