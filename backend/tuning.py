"""Process settings for the 1 kHz paths, shared by the server and the master-arm
bridge (a leaf module: importing it pulls in neither)."""

from __future__ import annotations

import asyncio
import gc
import sys


def tune_for_realtime() -> None:
    """Settings that keep the 1 kHz paths on time (measured in bench/command_latency):
    uvloop's faster event loop, a shorter GIL switch interval so the sensor thread
    and the event loop hand over quickly, and no collection pauses of objects made
    at start-up."""
    try:
        import uvloop

        asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())
    except ImportError:  # optional: plain asyncio works, a little slower
        pass
    sys.setswitchinterval(0.0005)
    gc.collect()
    gc.freeze()
