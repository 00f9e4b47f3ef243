"""bench.wan's command figures on a made-up run: the client-side ages (ACK's server
time − send time) beside the server's own age at execution (GET /safety?client=),
and the goal on the server's."""

from __future__ import annotations

from typing import Any

from bench.wan import command_figures, goals


def run(server_age: dict[str, Any] | None) -> dict[str, Any]:
    """Three commands sent at 10.00, 10.02, 10.04 s: ACKed 40 ms, 251 ms (the driver's
    call returned late) and never (refused as stale)."""
    safety: dict[str, Any] = {"stale_commands_dropped": 1, "controller": "bench"}
    if server_age is not None:
        safety["executed_age_ms_client"] = server_age
    return {
        "sent": {"1": 10.0, "2": 10.02, "3": 10.04},
        "acks": {"1": [10.04, 0, 10.1], "2": [10.271, 0, 10.3]},
        "errors": {"3": [9, "stale command: sent 300 ms ago", 10.4]},
        "control": [[9.9, True]],
        "safety": safety,
        "synced_clock_flag": True,
        "ping_rtt_ms": 1.0,
        "resumed": 0,
    }


def figures(out: dict[str, Any]) -> dict[str, Any]:
    return command_figures(out, [(9.95, 11.0)], t_down=20.0, t_up=21.0)


def test_the_client_side_and_the_servers_ages_are_told_apart() -> None:
    server = {"count": 2, "window": 2, "p50": 144.6, "p99": 248.9, "max": 249.1, "over_limit": 0}
    row = figures(run(server))
    # ACKed at 251 ms: stale by the client's reckoning, executed at 249.1 ms by the server's.
    assert row["stale_executed"] == 1 and round(row["oldest_executed_ms"]) == 251
    assert row["executed_age_ms"] == {"p50": 144.6, "p99": 248.9, "max": 249.1}
    assert row["executed_server"] == 2 and row["stale_executed_server"] == 0
    assert row["commands_refused"] == {"stale": 1}
    said = goals("lan", {**row, "link": {"down_p50_ms": 1.0}})
    assert said["no_stale_executed"] is False and said["executed_age_max_le_250ms"] is True


def test_a_command_executed_stale_by_the_servers_clock_fails_the_goal() -> None:
    server = {"count": 2, "window": 2, "p50": 150.0, "p99": 251.0, "max": 251.2, "over_limit": 1}
    row = figures(run(server))
    assert row["stale_executed_server"] == 1
    said = goals("lan", {**row, "link": {"down_p50_ms": 1.0}})
    assert said["executed_age_max_le_250ms"] is False


def test_a_server_without_the_figure_is_said_not_to_meet_the_goal() -> None:
    row = figures(run(None))
    assert row["executed_age_ms"] is None and row["stale_executed_server"] is None
    said = goals("lan", {**row, "link": {"down_p50_ms": 1.0}})
    assert said["executed_age_max_le_250ms"] is False
