"""The connection HUD behind an emulated link: Debian's Chromium runs
in the client namespace of harness.netem's pair, the server in the other, and the link's
profile changes under the open page. On `lan` its link rows (round trip, loss) are
green; on `mobile` (80 ± 30 ms each way) the round trip turns amber and says so; on
`bad` (150 ± 50 ms, 5 % lost, 2 Mbit/s) the box is red with the round trip named as a
reason; back on `lan` the link rows are green again by themselves. Skipped, with the kernel's reason, where network namespaces are
refused."""

from __future__ import annotations

import re
import tempfile
from collections.abc import Iterator

import pytest
from playwright.sync_api import Browser, Playwright

from harness.netem import NetemPair, emulator_available
from tests.support.browser import ENV, chromium, chromium_or_fail, open_page
from tests.support.hud import HUD, hud_when, row_is, row_of
from tests.support.servers import serving

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def linked(playwright: Playwright) -> Iterator[tuple[NetemPair, str, Browser]]:
    """The pair (on `lan`), the server's URL as the client namespace reaches it, and a
    browser in the client namespace."""
    why = emulator_available()
    if why is not None:
        pytest.skip(f"no link emulator here: {why}")
    with (
        NetemPair("lan") as pair,
        serving(ENV, "--host", pair.server_addr, ready=False, prefix=pair.server_prefix) as base,
        tempfile.TemporaryDirectory() as tmp,
        chromium(playwright, pair.client_executable(chromium_or_fail(), tmp)) as browser,
    ):
        yield pair, base, browser


def test_the_hud_follows_the_link_green_amber_red_and_back(
    linked: tuple[NetemPair, str, Browser],
) -> None:
    pair, base, browser = linked
    assert base.startswith(
        f"http://{pair.server_addr}:"
    )  # not loopback: the page is behind the link
    page, errors = open_page(browser, base)
    # Only the link's rows are judged (round trip, loss: the emulated link's figures);
    # the frame rate and the freezes are this machine's CPU's too, and the box's overall
    # level is judged only where a red link row makes it red on any machine. Each check
    # reads the HUD at the instant its wait held (it is redrawn every 0.5 s).
    link_ok = row_is("rtt", "r.level === 'ok'") + " && " + row_is("loss", "r.level === 'ok'")
    hud_when(page, link_ok, 30_000)

    pair.apply("mobile")  # ~170 ms round trip: over the 100 ms amber line, under 250
    d = hud_when(page, row_is("rtt", "r.level === 'amber'"), 20_000)
    text = row_of(d, "rtt")["text"]
    assert text.endswith("(> 100 ms)"), d
    # Judged by the slower of the video's and the ping's round trip: that one is over.
    figures = [float(ms) for ms in re.findall(r"([\d.]+) ms", text)[:-1]]
    assert figures and 100 < max(figures) <= 250, d

    pair.apply("bad")  # ~320 ms round trip and 5 % loss: red, the round trip among the reasons
    d = hud_when(page, f"{HUD}.level === 'red' && " + row_is("rtt", "r.level === 'red'"), 30_000)
    assert "RTT: " in d["reason"], d
    assert d["cls"] == "hud-red", d

    pair.apply("lan")  # back by itself
    hud_when(page, link_ok, 30_000)
    page.close()
    # (Errors the page logged while the link was bad are the page's to explain in its
    # log; none may be an uncaught exception.)
    assert not [e for e in errors if "Uncaught" in e], errors
