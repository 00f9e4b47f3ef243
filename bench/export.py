"""``export_s_per_min``: how long the LeRobot export takes per recorded minute, and
``export_peak_mb``: the most memory it held. A recording is built the way the server
writes one (tests/recordings: state 50 Hz, force 1 kHz, commands, two episodes covering
most of it, side-by-side H.264 at 30 fps, two 640×480 cameras), then exported, each time
in a process of its own (as the server runs an export) so that its peak resident size is
the export's alone; the figure is the export's wall time divided by the recording's
length in minutes (the median of ``--repeats``). ``export_stderr_lines`` counts what
the export printed (the encoder's log included): a quiet export prints nothing.

    python -m bench.export --json
    python -m bench.export --duration 60 --repeats 1 --json
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from bench.common import emit, machine, parser
from harness.recordings import Episode, build

# Run in the child: one export, then its figures as one JSON line on stdout.
_CHILD = """
import json, resource, sys
from telerobot.server.recording.lerobot import export_lerobot
s = export_lerobot(sys.argv[1], sys.argv[2])
peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"export_s": s.export_s, "frames": s.frames, "codec": s.video_codec,
                  "fps": s.fps, "peak_mb": peak_kb / 1024}))
"""


def _export_in_child(recording: Path, out: Path) -> tuple[dict[str, Any], int]:
    """One export in a fresh interpreter: its figures and how many lines it wrote to
    stderr."""
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(recording), str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"the export failed:\n{done.stderr[-3000:]}")
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    return figures, len(done.stderr.splitlines())


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
        runs: list[dict[str, Any]] = []
        stderr_lines: list[int] = []
        for i in range(repeats):
            figures, lines = _export_in_child(built.path, d / f"ds{i}")
            runs.append(figures)
            stderr_lines.append(lines)
        per_min = statistics.median(r["export_s"] for r in runs) / (duration_s / 60.0)
        recording_mb = built.path.stat().st_size / 2**20
    return {
        "export_s_per_min": per_min,
        "export_peak_mb": max(r["peak_mb"] for r in runs),
        "export_stderr_lines": max(stderr_lines),
        "export_recorded_s": duration_s,
        "export_recording_mb": recording_mb,
        "export_frames": runs[0]["frames"],
        "export_video": f"{runs[0]['codec']} {width // 2}x{height} x2 @30fps",
        "build_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "machine": machine(),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--duration", type=float, default=20.0, help="the recording's length, s")
    p.add_argument("--repeats", type=int, default=3, help="exports (the median is kept)")
    args = p.parse_args()
    emit(measure(args.duration, repeats=args.repeats), args.json)


if __name__ == "__main__":
    main()
