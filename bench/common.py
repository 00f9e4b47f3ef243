"""Shared helpers for the benchmarks: repeated timing with medians, machine info,
and the one JSON line every ``--json`` run ends with. (What the tests use too, such as
starting a server, is in harness/.)"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable, Iterator
from typing import Any

from harness.servers import SERVER_SCHEDULING


def parser(description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    return p


def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        # Who ran it, and what the last server's 1 kHz threads got (realtime or not):
        # figures taken with rights say so (docs/running.md, "Realtime").
        "euid": os.geteuid(),
        **({"server_scheduling": dict(SERVER_SCHEDULING)} if SERVER_SCHEDULING else {}),
    }


def time_per_call_us(fn: Callable[[], object], *, calls: int, repeats: int = 7) -> float:
    """Median over ``repeats`` runs of the mean time per call, in microseconds
    (the machine is shared and noisy: medians, never one timing)."""
    fn()  # warm up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        samples.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(samples)


def emit(figures: dict[str, Any], as_json: bool) -> None:
    width = max(len(k) for k in figures)
    for k, v in figures.items():
        if not isinstance(v, dict):
            print(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    if as_json:
        print(json.dumps(figures))


def arm_names(arms: int) -> list[str]:
    """The benches' names for ``arms`` arms: left and right for two, arm1… else."""
    return ["left", "right"] if arms == 2 else [f"arm{i + 1}" for i in range(arms)]


def arms_env(arms: int, model: str, robot: str = "sim") -> dict[str, str]:
    """The environment of a server driving ``arms`` arms of ``model`` (issue 33):
    ``TELEROBOT_ARMS`` (``left=so101:sim,right=so101:sim``) for two or more, the robot's
    own settings for one; a PUMA at its ``qn`` pose, as the benches' one arm."""
    env = {"TELEROBOT_HOME_POSE": "qn"} if model == "puma560" else {}
    if arms == 1:
        return {**env, "TELEROBOT_ROBOT_MODEL": model, "TELEROBOT_ROBOT": robot}
    spec = ",".join(f"{name}={model}:{robot}" for name in arm_names(arms))
    return {**env, "TELEROBOT_ARMS": spec}


@contextlib.contextmanager
def busy_core(on: bool) -> Iterator[None]:
    """With ``on``, one core kept busy meanwhile (Debian's stress-ng), as a machine that
    is also doing something else: the benches' ``--busy-core``."""
    proc = subprocess.Popen(["stress-ng", "--cpu", "1", "--quiet"]) if on else None
    try:
        yield
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(10)


def percentiles_ms(values_s: list[float]) -> dict[str, float]:
    import numpy as np

    v = np.array(values_s) * 1000.0
    return {
        "p50_ms": float(np.percentile(v, 50)),
        "p99_ms": float(np.percentile(v, 99)),
        "max_ms": float(v.max()),
        "mean_ms": float(v.mean()),
    }


def p50_p99(values_ms: list[float]) -> dict[str, float] | None:
    """``{"p50", "p99"}`` of figures already in ms, rounded to 0.01; None with none."""
    import numpy as np

    if not values_ms:
        return None
    p50, p99 = np.percentile(np.array(values_ms), [50, 99])
    return {"p50": round(float(p50), 2), "p99": round(float(p99), 2)}
