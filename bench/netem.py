"""What each of the link emulator's profiles really does, measured (the emulator, its
profiles and its two backends: harness/netem.py).

    python -m bench.netem [--json] [--profile wifi --profile mobile] [--probes 300]
                          [--backend auto|netem|forwarder]

For each profile, in one pair of namespaces: UDP probes spaced wider than the jitter
from the client's namespace to an echo in the server's (real sockets): round-trip and
one-way delays, loss each way, reordering; where the profile limits the rate, a UDP
stream offered at 1.5 × that rate (``rate_frame_mbit`` counts the Ethernet frame, as
netem does; ``rate_payload_mbit`` the UDP payload).
"""

from __future__ import annotations

import json
import sys
from typing import Any

from bench.common import emit, machine, parser
from harness.netem import (
    PROFILES,
    NetemPair,
    emulator_available,
    measure_link,
    measure_rate,
    probe_interval_s,
)


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--profile", action="append", choices=sorted(PROFILES), help="repeatable")
    p.add_argument("--probes", type=int, default=300)
    p.add_argument("--backend", choices=["auto", "netem", "forwarder"], default="auto")
    args = p.parse_args()
    if (why := emulator_available()) is not None:
        print(f"no link emulator here: {why}", file=sys.stderr)
        if args.json:
            print(json.dumps({"skipped": why, "machine": machine()}))
        return
    figures: dict[str, Any] = {}
    with NetemPair(backend=args.backend) as pair:
        for name in args.profile or list(PROFILES):
            profile = PROFILES[name]
            pair.apply(profile)
            link = measure_link(pair, probes=args.probes, interval_s=probe_interval_s(profile))
            row: dict[str, Any] = {"backend": pair.backend or "none", **link.figures()}
            if profile.rate_mbit:
                rate = measure_rate(pair, offered_mbit=1.5 * profile.rate_mbit)
                row["rate_frame_mbit"] = rate.frame_mbit
                row["rate_payload_mbit"] = rate.received_mbit
            print(f"-- {name}: {profile}")
            emit(row, False)
            figures[name] = row
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
