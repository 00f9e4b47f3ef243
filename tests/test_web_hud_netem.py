"""The connection HUD behind an emulated link (issue 15 part 3): Debian's Chromium runs
in the client namespace of bench.netem's pair, the server in the other, and the link's
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
from playwright.sync_api import Browser, sync_playwright

from bench.browser import ARGS
from bench.common import serve_for_bench
from bench.netem import NetemPair, emulator_available
from tests.test_browser import CHROMIUM
from tests.test_web_hud import HUD, hud_wait, row_is, rows, said
from tests.webpage import ENV, open_page

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def linked() -> Iterator[tuple[NetemPair, str, Browser]]:
    """The pair (on `lan`), the server's URL as the client namespace reaches it, and a
    browser in the client namespace."""
    why = emulator_available()
    if why is not None:
        pytest.skip(f"no link emulator here: {why}")
    with (
        NetemPair("lan") as pair,
        serve_for_bench("--host", pair.server_addr, env=ENV, prefix=pair.server_prefix) as (
            _,
            base,
        ),
        tempfile.TemporaryDirectory() as tmp,
        sync_playwright() as p,
    ):
        browser = p.chromium.launch(
            executable_path=pair.client_executable(str(CHROMIUM), tmp), args=ARGS
        )
        yield pair, base, browser
        browser.close()


def test_the_hud_follows_the_link_green_amber_red_and_back(
    linked: tuple[NetemPair, str, Browser],
) -> None:
    pair, base, browser = linked
    assert base.startswith(
        f"http://{pair.server_addr}:"
    )  # not loopback: the page is behind the link
    page, errors = open_page(browser, base)
    # (The link's rows; the freezes of the page's start-up on this loaded machine may
    # keep the box amber or red for a while, test_web_hud.py covers that row.)
    hud_wait(
        page,
        row_is("rtt", "r.level === 'ok'") + " && " + row_is("loss", "r.level === 'ok'"),
        30_000,
    )

    pair.apply("mobile")  # ~170 ms round trip: over the 100 ms amber line, under 250
    hud_wait(page, row_is("rtt", "r.level === 'amber'"), 20_000)
    text = rows(page)["rtt"]["text"]
    assert text.endswith("(> 100 ms)"), said(page)
    assert all(int(ms) > 100 for ms in re.findall(r"(\d+)(?:\.\d+)? ms", text)[:1]), said(page)

    pair.apply("bad")  # ~320 ms round trip and 5 % loss: red, the round trip among the reasons
    hud_wait(page, f"{HUD}.level === 'red' && " + row_is("rtt", "r.level === 'red'"), 30_000)
    assert "RTT" in page.evaluate(f"{HUD}.reason"), said(page)
    assert page.locator("#hud").get_attribute("class") == "hud-red"

    pair.apply("lan")  # back by itself
    hud_wait(
        page,
        row_is("rtt", "r.level === 'ok'") + " && " + row_is("loss", "r.level === 'ok'"),
        30_000,
    )
    page.close()
    # (Errors the page logged while the link was bad are the page's to explain in its
    # log; none may be an uncaught exception.)
    assert not [e for e in errors if "Uncaught" in e], errors
