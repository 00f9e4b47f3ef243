"""Two viewers on two links at once: the server in one network
namespace; one aiortc viewer beside it (a clean link), one in the client namespace
behind the shared emulator's `bad` profile (150 ± 50 ms, 5 % loss, 2 Mbit/s). Each
asks for "auto". The viewer on the bad link is moved to the low layer by what its own
receiver reports (the full layer, at a constant 5 Mbit/s, does not fit the link's 2;
a try to go up again fails and backs off) and gets the smaller picture; the one on the
clean link keeps the full layer all along. Skipped, with the kernel's reason, where
network namespaces are refused."""

from __future__ import annotations

import json
import secrets
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from harness.netem import NetemPair, emulator_available
from harness.servers import serve_for_bench

ROOT = Path(__file__).resolve().parents[1]
SECONDS = 25.0

# One viewer: decodes frames for SECONDS, then prints the picture widths it saw (per
# second) and what the server says of each viewer.
VIEWER = textwrap.dedent(
    """
    import asyncio, json, sys, time
    import httpx
    from harness.aiortc_viewers import open_viewer

    base, seconds, ask = sys.argv[1], float(sys.argv[2]), sys.argv[3] == "ask"

    async def main():
        pc, track = await open_viewer(base)
        start, widths = time.monotonic(), {}
        while (t := time.monotonic() - start) < seconds:
            try:
                frame = await asyncio.wait_for(track.recv(), 5)
            except asyncio.TimeoutError:
                continue
            widths.setdefault(int(t), set()).add(frame.width)
        video = {"stats": {"viewers": None}}
        if ask:  # (over the bad link, a request may not get through the full queue)
            async with httpx.AsyncClient(timeout=10) as http:
                video = (await http.get(base + "api/v1/video")).json()
        await pc.close()
        print(json.dumps({"widths": {k: sorted(v) for k, v in widths.items()},
                          "viewers": video["stats"]["viewers"]}))

    asyncio.run(main())
    """
)


def test_a_viewer_on_a_bad_link_moves_to_the_low_layer_while_a_clean_one_keeps_the_full(
) -> None:  # fmt: skip
    why = emulator_available()
    if why is not None:
        pytest.skip(f"no link emulator here: {why}")
    env = {
        "TELEROBOT_VIDEO": "true",
        # The full layer at a constant 10 Mbit/s does not fit the bad link's 2 Mbit/s,
        # even from an encoder a busy machine holds to a fifth of its frames (a constant
        # bit rate is bits per frame; at 3 and then 5 Mbit/s, with one core busy, the bad
        # viewer was once never moved: at 5 the server sent it 2.2 Mbit/s, the link's
        # own rate, its 5 % random loss the only sign); the low one (1.2 Mbit/s) fits.
        "TELEROBOT_VIDEO_BITRATE": "10000000",
        "TELEROBOT_VIDEO_CBR": "true",
        "TELEROBOT_VIDEO_WIDTH": "640",
        "TELEROBOT_VIDEO_HEIGHT": "360",
        "TELEROBOT_VIDEO_FPS": "20",
        "TELEROBOT_OPERATOR_TOKEN": secrets.token_hex(16),
    }
    with (
        NetemPair("bad") as pair,
        serve_for_bench("--host", pair.server_addr, env=env, prefix=pair.server_prefix) as (
            _,
            base,
        ),
    ):
        viewers = {
            name: subprocess.Popen(
                [*prefix, sys.executable, "-c", VIEWER, base, str(SECONDS), ask],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                cwd=ROOT,
            )
            for name, prefix, ask in (
                ("clean", pair.server_prefix, "ask"),
                ("bad", pair.client_prefix, "-"),
            )
        }
        seen = {}
        for name, proc in viewers.items():
            out, err = proc.communicate(timeout=SECONDS + 60)
            assert proc.returncode == 0, err
            seen[name] = json.loads(out.strip().splitlines()[-1])
    widths = {name: s["widths"] for name, s in seen.items()}
    # The clean viewer: the full picture (2 × 640) every second, from first to last.
    server = seen["clean"]["viewers"]  # asked after the bad one had switched
    assert all(w == [1280] for w in widths["clean"].values()), (widths, server)
    # The bad one: mostly the low picture (2 × 320) once it came (the full one may not
    # have got through at all); a try to go up again (after 8 s clean, then 16 s…) may
    # show the full one for a moment.
    seconds = sorted(widths["bad"], key=int)
    first_low = next((k for k in seconds if 640 in widths["bad"][k]), None)
    assert first_low is not None, ("the bad viewer never got the low picture", widths, server)
    after = [widths["bad"][k] for k in seconds if int(k) > int(first_low)]
    assert sum(w == [640] for w in after) >= 0.6 * len(after), widths
    # The server's side: the clean viewer never moved, the bad one did.
    switches = sorted(v["layer_switches"] for v in server)
    assert switches[0] == 0 and switches[1] >= 1, server
