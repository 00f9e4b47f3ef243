"""bench.wan's Chromium figures on made-up requestVideoFrameCallback records (no browser,
no link): the page's clock mapped onto the monotonic one, capture → shown from each
shown frame's own timecode, the freezes over the shown times, the row's keys."""

from __future__ import annotations

from typing import Any

import pytest

from bench.wan import (
    chromium_figures,
    command_figures,
    cpu_share,
    page_origin,
    presented_counts,
    shown_frames,
    video_figures,
    webrtc_freezes,
)
from telerobot.drivers.camera import timecode

ORIGIN = 1000.0  # the page's performance.now() zero on the monotonic clock (s)


def record(shown: float, age: float | None, **extra: Any) -> dict[str, Any]:
    """One callback: the frame expected on screen at ``shown`` (monotonic s), its picture
    captured ``age`` s before (None: the code could not be read), the callback 16 ms
    before the expected display."""
    page_ms = (shown - ORIGIN) * 1000
    code = None if age is None else timecode.encode_time(shown - age)
    rec = {"now": page_ms - 16, "expected": page_ms, "presented": page_ms - 12, "code": code}
    return {**rec, **extra}


def test_the_tightest_clock_read_maps_the_page_clock() -> None:
    samples = [
        (10.0, 5_000.0, 10.050),  # read in 50 ms: its middle is 25 ms off
        (11.0, 6_000.5, 11.001),  # read in 1 ms
        (12.0, 6_990.0, 12.020),
    ]
    assert page_origin(samples) == pytest.approx(11.0005 - 6.0005)


def test_capture_to_shown_is_the_shown_time_less_the_frames_own_capture_time() -> None:
    records = [record(1010.0, 0.120), record(1010.033, 0.0801), record(1010.066, None)]
    frames = shown_frames(records, ORIGIN)
    assert [t for t, _ in frames] == pytest.approx([1010.0, 1010.033, 1010.066])
    assert frames[0][1] == pytest.approx(0.120, abs=1e-4)  # the timecode's 0.1 ms units
    assert frames[1][1] == pytest.approx(0.0801, abs=1e-4)
    assert frames[2][1] is None


def test_without_expected_display_time_the_presentation_time_is_taken() -> None:
    rec = record(1010.0, 0.1)
    del rec["expected"]
    ((shown, age),) = shown_frames([rec], ORIGIN)
    assert shown == pytest.approx(1009.988)
    assert age == pytest.approx(0.088, abs=1e-4)


def test_a_misread_code_is_no_latency() -> None:
    # A code 10 s behind (or "ahead": the wrap puts it minutes behind) is a misread.
    behind = record(1010.0, 10.0)
    ahead = {**record(1010.0, 0.1), "code": timecode.encode_time(1010.5)}
    assert [age for _, age in shown_frames([behind, ahead], ORIGIN)] == [None, None]


def test_the_timecode_wrap_is_crossed() -> None:
    wrap_s = timecode.WRAP * timecode.UNIT  # ~430 s
    shown = wrap_s * 3 + 0.05  # just after a wrap; captured 0.1 s before, before it
    origin = shown - 10.0
    rec = {"now": 9_984.0, "expected": 10_000.0, "code": timecode.encode_time(shown - 0.1)}
    ((_, age),) = shown_frames([rec], origin)
    assert age == pytest.approx(0.1, abs=1e-4)


def command_run(kept: bool) -> dict[str, Any]:
    return {
        "sent": {"1": 1010.0},
        "acks": {"1": [1010.01, 0, 1010.02]},
        "errors": {},
        "control": [[1009.0, True]] if kept else [[1009.0, True], [1012.0, False]],
        "safety": {},
        "synced_clock_flag": True,
        "ping_rtt_ms": 1.0,
    }


def test_the_chromium_row_has_the_issues_keys_and_the_freezes_of_the_shown_frames() -> None:
    # 30 fps shown from 1010 to 1014 s but for one 400 ms hole at 1011.5; 100 ms old.
    times = [1010.0 + i / 30 for i in range(120)]
    times = [t for t in times if not 1011.5 < t < 1011.9]
    records = [
        record(t, 0.1, count=i, receive=(t - 0.05 - ORIGIN) * 1000) for i, t in enumerate(times)
    ]
    out: dict[str, Any] = {
        "rvfc": records,
        "clock": [(ORIGIN + 5.0, 5_000.0, ORIGIN + 5.0)],
        "glass": [[(t - ORIGIN) * 1000, 60.0] for t in times],
        "lease": {"samples": 40, "held": 0},
        "page_operator": True,
        "page_clock_offset_s": ORIGIN + 0.002,
        "cpu": {"cores": 0.8, "by_kind": {"gpu-process": 0.6, "renderer": 0.2}},
        "bytes_at": [],
        "packets": [],
        "polls": [],
        "status": {},
    }
    segments = [(1010.0, 1012.0), (1012.5, 1014.0)]
    seen = {**out, "frames": shown_frames(records, page_origin(out["clock"]))}
    row = {
        **video_figures(seen, segments, 1012.2),
        **command_figures(command_run(True), segments, 1012.0, 1012.2),
    }
    early = video_figures(seen, segments[:1], 1012.2)
    c = chromium_figures(out, row, early, segments)
    assert {"frozen_share", "longest_freeze_ms", "capture_to_shown_ms", "fps", "lease_kept"} <= set(
        c
    )
    assert set(c["capture_to_shown_ms"]) == {"p50", "p99"}
    assert c["capture_to_shown_ms"]["p50"] == pytest.approx(100.0, abs=0.1)
    # The hole: frames shown at 1011.5 and 1011.9 (a 400 ms gap), in 3.5 s of steady time.
    assert c["longest_freeze_ms"] == pytest.approx(400.0, abs=0.1)
    assert c["frozen_share"] == pytest.approx(0.4 / 3.5, abs=1e-4)
    assert c["fps"] == pytest.approx(
        (len(times) - sum(1 for t in times if 1012.0 < t < 1012.5)) / 3.5, abs=0.5
    )
    assert c["lease_kept"] is True and c["page_held_lease"] is False
    assert c["decoded_latency_ms"]["p50"] == pytest.approx(60.0)
    assert c["receive_to_shown_ms"]["p50"] == pytest.approx(50.0, abs=0.1)
    # The callback ran 16 ms before the expected display: 84 ms after the capture.
    assert c["capture_to_callback_ms"]["p50"] == pytest.approx(84.0, abs=0.1)
    assert c["expected_display_after_callback_ms"]["p50"] == pytest.approx(16.0)
    assert c["page_clock_offset_error_ms"] == pytest.approx(2.0)
    # presentedFrames counts every frame here: none missed by the callbacks.
    assert c["callbacks_missed"] == 0
    lost = command_figures(command_run(False), segments, 1012.0, 1012.2)
    assert lost["lease_kept"] is False


def test_cpu_share_counts_each_process_since_the_first_snapshot() -> None:
    before = {1: ("browser", 10.0), 2: ("gpu-process", 100.0), 4: ("playwright-driver", 1.0)}
    after = {
        1: ("browser", 11.0),
        2: ("gpu-process", 106.0),
        3: ("utility", 0.5),  # started since
        4: ("playwright-driver", 2.0),  # not Chromium's
    }
    share = cpu_share(before, after, wall_s=10.0)
    assert share["cores"] == pytest.approx(0.75)
    assert share["by_kind"] == pytest.approx(
        {"browser": 0.1, "gpu-process": 0.6, "utility": 0.05, "playwright-driver": 0.1}
    )


def test_presented_frames_count_on_across_a_new_stream() -> None:
    # presentedFrames 10, 12 (one frame no callback saw), then a new stream: 1, 2.
    records = [record(1010.0 + i * 0.1, 0.1, count=n) for i, n in enumerate([10, 12, 1, 2])]
    counts = presented_counts(records, ORIGIN, [(1010.0, 1011.0)])
    assert counts == {"fps_presented": pytest.approx(2 + 1 + 1), "callbacks_missed": 1}


def test_a_frame_is_not_shown_before_its_callback_ran() -> None:
    # A starved compositor's expectedDisplayTime 5 ms before the callback's own time.
    rec = {**record(1010.0, 0.1), "now": 10_005.0}
    ((shown, age),) = shown_frames([rec], ORIGIN)
    assert shown == pytest.approx(1010.005)
    assert age == pytest.approx(0.105, abs=1e-4)


def test_webrtc_freezes_count_one_peers_samples_inside_the_steady_run() -> None:
    # origin 0: page ms = s × 1000; steady (1, 5) and (7, 9): the outage between
    samples = [
        [1000, "a", 0, 0.0, 0],
        [2000, "a", 1, 0.3, 20],  # 0.3 s frozen in this second
        [3000, "a", 1, 0.3, 50],
        [4000, "b", 0, 0.0, 10],  # a new peer: this pair is left out
        [5000, "b", 0, 0.0, 40],
        [6000, "b", 2, 1.0, 50],  # across the outage: left out
        [7000, "b", 2, 1.0, 60],
        [8000, "b", 2, 1.0, 90],
    ]
    out = webrtc_freezes(samples, 0.0, [(1.0, 5.0), (7.0, 9.0)])
    assert out["seconds"] == 4.0 and out["freezes"] == 1
    assert out["frozen_share"] == 0.3 / 4.0
    assert out["fps_decoded"] == (20 + 30 + 30 + 30) / 4.0
    assert webrtc_freezes([], 0.0, [(1.0, 5.0)])["frozen_share"] is None


def test_webrtc_freezes_add_up_the_links_counters_over_the_same_pairs() -> None:
    def more(lost: int, fec: int, delay: float, emitted: int) -> dict[str, float | None]:
        return {
            "packetsLost": lost,
            "fecPacketsReceived": fec,
            "nackCount": None,  # not reported: left out
            "jitterBufferDelay": delay,
            "jitterBufferEmittedCount": emitted,
        }

    samples = [
        [1000, "a", 0, 0.0, 0, more(0, 0, 0.0, 0)],
        [2000, "a", 0, 0.0, 30, more(5, 40, 3.0, 30)],  # 100 ms a frame
        [3000, "b", 0, 0.0, 0, more(0, 0, 0.0, 0)],  # a new peer: left out
        [4000, "b", 0, 0.0, 30, more(1, 10, 6.0, 30)],  # 200 ms a frame
    ]
    out = webrtc_freezes(samples, 0.0, [(0.0, 5.0)])
    assert out["counters"]["packetsLost"] == 6 and out["counters"]["fecPacketsReceived"] == 50
    assert "nackCount" not in out["counters"]
    assert out["jitter_buffer_ms"] == pytest.approx(150.0)
    assert out["jitter_buffer_target_ms"] is None
