"""Traffic classes for the server's sockets: forces and commands ahead of video.

Two marks per socket: DSCP in the IP header (EF for forces, CS1 "lower effort" for
video), which DiffServ-aware routers and shaped links honour, and SO_PRIORITY (6 and
1), which Linux's own queues use on the way out. Where a platform lacks an option the
mark is skipped: the traffic still flows, only without the preference.
"""

from __future__ import annotations

import contextlib
import logging
import socket
from typing import Any

log = logging.getLogger(__name__)

DSCP_EF = 46 << 2  # Expedited Forwarding, in the TOS / traffic-class byte
DSCP_CS1 = 8 << 2  # lower effort
SO_PRIORITY_HIGH = 6  # TC_PRIO_INTERACTIVE: band 0 of the default queue
SO_PRIORITY_LOW = 1  # TC_PRIO_FILLER: the last band


def _mark(sock: Any, tos: int, priority: int) -> None:
    """``sock``: a socket, or anything with ``family`` and ``setsockopt`` (uvloop's
    ``PseudoSocket``, what its transports give)."""
    with contextlib.suppress(OSError, AttributeError):
        if sock.family == socket.AF_INET6:
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_TCLASS, tos)
        else:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_TOS, tos)
    # After IP_TOS, which would otherwise set the priority from the TOS bits.
    with contextlib.suppress(OSError, AttributeError):
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_PRIORITY, priority)


def mark_high_priority(sock: Any) -> None:
    _mark(sock, DSCP_EF, SO_PRIORITY_HIGH)


def mark_low_priority(sock: Any) -> None:
    _mark(sock, DSCP_CS1, SO_PRIORITY_LOW)
