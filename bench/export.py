"""``export_s_per_min``: how long the LeRobot export takes per recorded minute
(issue 14 part 4). A recording is built the way the server writes one (tests/recordings:
state 50 Hz, force 1 kHz, commands, two episodes covering most of it, side-by-side
H.264 at 30 fps, two 640×480 cameras), then exported; the figure is the export's wall
time divided by the recording's length in minutes (the median of ``repeats``).

    python -m bench.export --json
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path
from typing import Any

from backend.recording.lerobot import export_lerobot
from bench.common import emit, machine, parser
from bench.recordings import Episode, build


def measure(
    duration_s: float = 20.0, width: int = 1280, height: int = 480, repeats: int = 3
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench-export-") as tmp:
        d = Path(tmp)
        episodes = [
            Episode(0.5, duration_s / 2 - 0.5, "pick"),
            Episode(duration_s / 2, duration_s - 0.5, "place"),
        ]
        built = build(
            d / "rec.mcap",
            duration=duration_s,
            episodes=episodes,
            video_fps=30,
            width=width,
            height=height,
        )
        runs = []
        frames = 0
        codec = None
        for i in range(repeats):
            summary = export_lerobot(built.path, d / f"ds{i}")
            runs.append(summary.export_s)
            frames, codec = summary.frames, summary.video_codec
        per_min = statistics.median(runs) / (duration_s / 60.0)
    return {
        "export_s_per_min": per_min,
        "export_recorded_s": duration_s,
        "export_frames": frames,
        "export_video": f"{codec} {width // 2}x{height} x2 @30fps",
        "machine": machine(),
    }


def main() -> None:
    args = parser(__doc__ or "").parse_args()
    emit(measure(), args.json)


if __name__ == "__main__":
    main()
