"""The lease across a real dropped link (issue 15 part 3): the server in one network
namespace, an operator's client in another, the link between them cut by the shared
emulator (bench/netem.py). The client holds control with heartbeats on the `wan`
profile; a 1 s drop keeps control once the link is back (with the arm halted on the
silence), a 3 s one loses it with the dead-man's reason. (1 s, not the 1.5 s the
issue names: see the comment at the drop — TCP's retransmission backoff can stretch a
1.5 s cut to 3 s of silence.) Skipped, with the kernel's reason, where network
namespaces are refused."""

from __future__ import annotations

import json
import secrets
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bench.common import serve_for_bench
from bench.netem import NetemPair, emulator_available

ROOT = Path(__file__).resolve().parents[1]

# The operator's client, run inside the client namespace: it takes control and beats
# every 50 ms (the page's worker does the same); on "check" from the test it says what
# the server's /safety says and whether its STATE flags showed the arm HALTED.
CLIENT = textwrap.dedent(
    """
    import asyncio, json, sys
    import httpx
    from backend.realtime import messages as m
    from bench.wsclient import RealtimeClient

    base, token = sys.argv[1], sys.argv[2]

    async def main():
        client = await RealtimeClient.connect(base.replace("http", "ws") + "ws", token)
        await client.ws.send(m.encode(m.LEASE, client.next_seq(), m.LeaseAction.TAKE))
        await client.expect(m.ACK)
        seen = {"halted": False}

        async def beat():
            while True:
                try:
                    await client.ws.send(m.encode(m.HEARTBEAT, client.next_seq(), 0.0))
                except Exception:
                    return
                await asyncio.sleep(0.05)

        async def listen():
            async for data in client.ws:
                if data[0] == m.STATE.type_id:
                    if int(m.decode(data)[1]["flags"]) & m.StateFlags.HALTED:
                        seen["halted"] = True

        tasks = [asyncio.create_task(beat()), asyncio.create_task(listen())]
        print("ready", flush=True)
        loop = asyncio.get_running_loop()
        while (line := await loop.run_in_executor(None, sys.stdin.readline)).strip():
            await asyncio.sleep(0.6)  # the link is back: let a few beats through
            async with httpx.AsyncClient(timeout=10) as http:
                safety = (await http.get(base + "api/v1/safety")).json()
            print(json.dumps({**seen, "controller": safety["controller"],
                              "note": safety["lease_note"]}), flush=True)
            seen["halted"] = False
        for t in tasks:
            t.cancel()

    asyncio.run(main())
    """
)


def test_a_short_drop_keeps_the_lease_and_a_long_one_loses_it() -> None:
    why = emulator_available()
    if why is not None:
        pytest.skip(f"no link emulator here: {why}")
    token = secrets.token_hex(16)
    env = {"TELEROBOT_VIDEO": "false", "TELEROBOT_OPERATOR_TOKEN": token}
    with (
        NetemPair("wan") as pair,
        serve_for_bench("--host", pair.server_addr, env=env, prefix=pair.server_prefix) as (
            _,
            base,
        ),
    ):
        client = subprocess.Popen(
            [*pair.client_prefix, sys.executable, "-c", CLIENT, base, token],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, cwd=ROOT,
        )  # fmt: skip
        try:
            assert client.stdout is not None and client.stdin is not None
            assert client.stdout.readline().strip() == "ready", client.stderr.read()

            def check() -> dict[str, object]:
                client.stdin.write("check\n")  # type: ignore[union-attr]
                client.stdin.flush()  # type: ignore[union-attr]
                line = client.stdout.readline()  # type: ignore[union-attr]
                assert line, client.stderr.read()  # type: ignore[union-attr]
                return json.loads(line)  # type: ignore[no-any-return]

            # Shorter than the 2 s grace, and short enough that TCP's own recovery fits
            # in it: segments lost in a cut are resent with exponential backoff (RTO
            # ≥ 200 ms: at 0.2, 0.6, 1.4, 3.0 s after the first loss), so after a 1.5 s
            # cut the heartbeats may only get through at 3.0 s, past the grace — the
            # lease was lost in 2 of 7 runs of a 1.5 s cut (a finding of issue 15).
            pair.link_down(1.0)
            short = check()
            assert short["controller"] is not None, short  # control kept
            # …while the arm was halted on the silence (the first states after the
            # link is back still say so, before the client's beats reach the server)
            assert short["halted"] is True, short
            pair.link_down(3.0)  # longer than the grace
            long = check()
            assert long["controller"] is None, long  # control lost, and why
            assert "dead-man" in str(long["note"]), long
        finally:
            if client.stdin:
                client.stdin.close()
            client.kill()
            client.wait(10)
