"""The master-arm bridge survives a server restart: it lets the device go when the
priority channel closes and connects again by itself, with a doubling backoff, to the
new server on the same address (real processes, real sockets)."""

from __future__ import annotations

import contextlib
import socket
import threading
import time

import numpy as np
import pytest

from telerobot.client.master.bridge import Backoff, BridgeSettings, MasterBridge
from telerobot.client.master.cli import open_link
from telerobot.drivers.base import FloatArray
from telerobot.drivers.master.sim import SimMaster
from tests.support import TOKEN, until
from tests.support.servers import free_port, serving


def test_the_backoff_doubles_to_its_limit_and_starts_again_after_a_success() -> None:
    b = Backoff(0.5, 8.0)
    assert [b.next() for _ in range(7)] == [0.5, 1.0, 2.0, 4.0, 8.0, 8.0, 8.0]
    b.reset()
    assert b.next() == 0.5


ENV = {
    "TELEROBOT_OPERATOR_TOKEN": TOKEN,
    "TELEROBOT_HOME_POSE": "qn",
    "TELEROBOT_PRIORITY_PORT": "0",
}


def still(t: float) -> tuple[FloatArray, bool]:
    return np.zeros(3), False


def test_the_bridge_reconnects_after_the_server_restarts() -> None:
    port = free_port()  # the same port again after the restart
    with contextlib.ExitStack() as server:
        base = server.enter_context(serving(ENV, port=port))
        device = SimMaster(still)
        bridge = MasterBridge(
            device,
            open_link(base, TOKEN),
            BridgeSettings(),
            reconnect=lambda: open_link(base, TOKEN),
            backoff=Backoff(0.2, 1.0),
        )
        bridge.start(take_control=False)
        try:
            until(lambda: bridge.states_received > 10, timeout=10)
            first_link = bridge.link
            server.close()  # the server process ends
            until(lambda: not bridge.connected, timeout=10)
            assert bridge.link is first_link and bridge.reconnects == 0
            assert np.all(device.rendered == 0)  # the device was let go
            time.sleep(1.5)  # it keeps trying while nothing listens, and does not give up
            assert not bridge.connected and bridge._worker.running
            server.enter_context(serving(ENV, port=port))
            until(lambda: bridge.connected, timeout=15)
            assert bridge.reconnects == 1 and bridge.link is not first_link
            states = bridge.states_received
            until(lambda: bridge.states_received > states + 10, timeout=10)  # state flows again
            assert bridge.last_error is None
        finally:
            bridge.stop()
            bridge.link.close()


def test_the_links_socket_is_made_blocking_before_its_reader_starts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A socket's mode switched while its reader thread was in recv() could make that
    # recv() fail with EAGAIN (Python sets the socket's mode, then, without the GIL, the
    # descriptor's): a busy machine's run took that for a lost channel and reconnected a
    # live link. The link's socket is never switched while its reader runs.
    switched: list[tuple[socket.socket, bool]] = []
    settimeout = socket.socket.settimeout

    def watched(sock: socket.socket, value: float | None) -> None:
        reading = any(t.name == "priority-link" and t.is_alive() for t in threading.enumerate())
        switched.append((sock, reading))
        settimeout(sock, value)

    monkeypatch.setattr(socket.socket, "settimeout", watched)
    with serving(ENV) as base:
        link = open_link(base, TOKEN)
        try:
            until(lambda: link.received > 10, timeout=10)
            assert link.sock.gettimeout() is None  # blocking
        finally:
            link.close()
    ours = [reading for sock, reading in switched if sock is link.sock]
    assert ours and not any(ours), ours
