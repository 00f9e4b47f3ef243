"""Who imports whom: the client side of the protocol (the master-arm bridge, run on the
operator's machine) imports the protocol, never the server (docs/architecture.md, rule 16)."""

from __future__ import annotations

import subprocess
import sys

SERVER_ONLY = (
    "fastapi",
    "pinocchio",
    "backend.control",
    "backend.realtime.priority",
    "backend.app",
)


def test_the_master_bridge_imports_the_protocol_not_the_server() -> None:
    probe = (
        "import sys, backend.master.cli, backend.master.link, backend.master.bridge\n"
        f"print(sorted(n for n in sys.modules if n.startswith({SERVER_ONLY!r})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"


def test_the_server_and_the_bridge_share_one_framing() -> None:
    from backend.master import link
    from backend.realtime import messages as m
    from backend.realtime import priority

    assert priority.LENGTH is m.LENGTH and priority.frame is m.frame
    assert "LENGTH" not in vars(link)  # it uses the protocol's, not a copy
