"""The video's own frame rate (backend/media/frame_rate.py): 60 fps configured, 30 when
the encoder cannot keep it with room to spare, back only after a clean stretch. Made-up
encode times on a made-up clock: behaviour, never this machine's speed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from telerobot.drivers.base import StereoFrame
from telerobot.server.media import frame_rate as fr
from telerobot.server.media.frame_rate import FrameRateRule

CADENCE_HZ = 10.0  # frames pulled a second in these runs (the rule counts, never paces)

# A frame's encoding, ms, at 60 fps configured (period 16.7 ms: down above 14.2, back
# up at or below 10)
SLOW, MID, FAST = 15.0, 12.0, 4.0


@dataclass
class Run:
    rule: FrameRateRule
    now: float = 0.0
    n: int = 0
    changes: list[tuple[float, float]] | None = None  # (when, to)

    def __post_init__(self) -> None:
        self.changes = []

    def feed(self, seconds: float, work_ms: float | None, skip_every: int = 0) -> None:
        """Frames pulled at CADENCE_HZ for ``seconds``; at the floor every other one is
        encoded (as ``Encoding`` passes over the rest); None: nobody watching."""
        end = self.now + seconds
        while self.now < end:
            self.now += 1.0 / CADENCE_HZ
            if work_ms is None:
                changed = self.rule.decide(self.now)
            else:
                self.n += 1
                encoded = self.rule.target >= self.rule.configured or self.n % 2 == 0
                skipped = 1 if skip_every and self.n % skip_every == 0 else 0
                self.rule.frame(self.now, skipped, work_ms if encoded else None)
                changed = self.rule.decide(self.now)
            if changed:
                assert self.changes is not None
                self.changes.append((self.now, self.rule.target))


def test_a_slow_encoder_drops_to_30_with_the_reason_and_comes_back_after_a_clean_stretch() -> None:
    run = Run(FrameRateRule(60.0))
    run.feed(20, MID)  # 12 ms a frame: room enough at 60, no change
    assert run.rule.target == 60 and run.changes == []
    run.feed(8, SLOW)
    assert run.rule.target == 30
    assert "encoding took 15.0 ms a frame (p90 over 5 s), over 14.2 ms" in run.rule.why
    run.feed(60, MID)  # 12 ms: not clean enough to go back (hysteresis), not slow
    assert run.rule.target == 30 and len(run.changes or []) == 1
    dropped_at = run.now
    run.feed(fr.UP_HOLD_S + fr.WINDOW_S + 2, FAST)
    assert run.rule.target == 60 and run.rule.why.startswith("clean for 3")
    assert (run.changes or [])[-1][0] - dropped_at >= fr.UP_HOLD_S


def test_frames_skipped_drop_it_too() -> None:
    run = Run(FrameRateRule(60.0))
    run.feed(10, FAST, skip_every=8)  # 1 in 9 skipped: the loop does not keep up
    assert run.rule.target == 30 and "of the camera's frames skipped" in run.rule.why


def test_a_failed_return_doubles_the_wait_and_nobody_watching_is_no_clean_stretch() -> None:
    run = Run(FrameRateRule(60.0))
    run.feed(7, SLOW)
    run.feed(fr.UP_HOLD_S + 7, FAST)
    assert run.rule.target == 60
    run.feed(7, SLOW)  # down again soon after: the probe failed
    assert run.rule.target == 30 and run.rule.up_hold_s == 2 * fr.UP_HOLD_S
    run.feed(300, None)  # nobody watching: no evidence of room
    assert run.rule.target == 30
    run.feed(2 * fr.UP_HOLD_S - 5, FAST)
    assert run.rule.target == 30
    run.feed(fr.WINDOW_S + 7, FAST)
    assert run.rule.target == 60


def test_a_rate_of_30_or_less_or_one_held_is_kept_whatever_happens() -> None:
    for rule in (FrameRateRule(25.0), FrameRateRule(60.0, auto=False)):
        run = Run(rule)
        run.feed(20, 100.0, skip_every=2)
        assert run.rule.target == rule.configured and run.changes == [] and not rule.active


segments = st.lists(
    st.tuples(
        st.one_of(st.sampled_from([2.0, 6.0, 20.0, 40.0, 130.0, 260.0]), st.floats(0.2, 60.0)),
        st.sampled_from(["slow", "mid", "fast", "skipping", "idle"]),
    ),
    min_size=1,
    max_size=6,
)
KIND = {
    "slow": (SLOW, 0),
    "mid": (MID, 0),
    "fast": (FAST, 0),
    "skipping": (FAST, 6),
    "idle": (None, 0),
}


@settings(max_examples=40, deadline=None)
@given(segments, st.sampled_from([60.0, 50.0, 120.0]))
def test_invariants_over_made_up_encode_times(
    plan: list[tuple[float, str]], configured: float
) -> None:
    """Never below 30 or above the configured rate; never two changes closer than the
    window, never back up sooner than the hold; down when the encoder cannot keep up;
    back after a clean stretch; no change in a stretch between the two thresholds."""
    scale = 60.0 / configured  # the same shares of the period at any configured rate
    run = Run(FrameRateRule(configured))
    for seconds, kind in plan:
        work, skip = KIND[kind]
        start, before = run.now, len(run.changes or [])
        run.feed(seconds, None if work is None else work * scale, skip)
        assert run.rule.target in (fr.FLOOR_FPS, configured)
        changes = run.changes or []
        whole = seconds >= fr.WINDOW_S + 2 * fr.JUDGE_S
        if kind in ("slow", "skipping") and whole:
            assert run.rule.target == fr.FLOOR_FPS, (kind, seconds, changes)
        if kind == "fast" and seconds >= fr.WINDOW_S + fr.MAX_UP_HOLD_S + 2 * fr.JUDGE_S:
            assert run.rule.target == configured
        if kind in ("mid", "idle"):
            # between the thresholds, or nobody watching: only the window's older frames
            # can move it
            late = [t for t, _ in changes[before:] if t > start + fr.WINDOW_S + fr.JUDGE_S]
            assert late == []
    changes = run.changes or []
    last_t, last_to = 0.0, configured
    for t, to in changes:
        assert to != last_to  # each change is a change
        if last_t:
            assert t - last_t >= fr.WINDOW_S
        if to == configured:
            assert t - last_t >= fr.UP_HOLD_S
        last_t, last_to = t, to


class _Camera:
    name, width, height, fps = "fake", 8, 8, 60.0


def test_the_encode_loop_passes_over_every_other_frame_at_30_and_counts_gaps_as_skipped() -> None:
    from telerobot.drivers.clock import MonotonicClock
    from telerobot.server.media.encoding import Encoding
    from telerobot.server.media.pipeline import VideoSettings

    enc = Encoding(_Camera(), VideoSettings(fps=60.0), MonotonicClock())  # type: ignore[arg-type]
    img = np.zeros((8, 16, 3), np.uint8)
    frames = [StereoFrame(i, 100 + i / 60, img) for i in range(1, 9)]
    assert [enc._skipped(f) for f in frames[:3]] == [0, 0, 0]
    assert enc._skipped(frames[5]) == 2  # seq 3 → 6
    late = StereoFrame(7, frames[5].time + 4 / 60, img)  # the camera fell behind
    assert enc._skipped(late) == 3
    enc.frame_rate.target = 30.0
    due = []
    for f in frames:
        if enc._due(f):
            enc._encoded_at = f.time
            due.append(f.seq)
    assert due == [1, 3, 5, 7]
    assert enc.fps == 30 and enc.frame_rate.configured == 60
    _Camera.fps = 25.0  # a device that grants less than asked
    try:
        assert enc.fps == 25 and "the camera delivers 25 fps" in enc.fps_why
    finally:
        _Camera.fps = 60.0


def test_the_first_seconds_after_encoding_starts_are_not_judged() -> None:
    run = Run(FrameRateRule(60.0))
    run.rule.start(0.0)
    run.feed(fr.START_S - 0.2, SLOW, skip_every=2)  # a first key frame, a handshake
    run.feed(fr.WINDOW_S + 2, FAST)
    assert run.rule.target == 60 and run.changes == []
