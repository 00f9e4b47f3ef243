"""The low video layer in a real browser (Debian's Chromium) against a real
``telerobot serve``: a page that asks for it (``?layer=low``; the server would choose it
for a poor link) gets a picture half the size each way, the HUD says "low", and the view
stretches it to the camera's own size, so what is drawn over it (the calibration's
pixels: the AR ball, the fiducials) stays where the camera sees it."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page

from telerobot.drivers.camera.sim import FIDUCIAL_COLOURS
from tests.support.browser import (
    open_page,
    read_fresh_view,
    wait,
)
from tests.support.waiting import until

pytestmark = pytest.mark.browser

PIXELS = """(points) => {
  const v = document.getElementById('view'); const c = document.createElement('canvas');
  c.width = v.width; c.height = v.height; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
  const crop = window.telerobot.view.croppedRows;
  return { size: [v.width, v.height], crop, stale: window.telerobot.view.staleMs, rgb: points.map(([x, y]) =>
    Array.from(g.getImageData(Math.round(x), Math.round(y - crop), 1, 1).data).slice(0, 3)) };
}"""


def fiducials_seen(page: Page, server: str) -> tuple[dict[str, object], list[bool]]:
    """Each fiducial, in each eye, where the ground-truth camera projects it in the
    camera's pixels: is the view's pixel there the fiducial's colour?"""
    cell = httpx.get(server + "api/v1/workcell").json()
    world = np.array(httpx.get(server + "api/v1/calibration").json()["fiducials"])
    points, colours = [], []
    for eye, cam in enumerate(cell["cameras"]):
        for xyz, colour in zip(world, FIDUCIAL_COLOURS, strict=False):
            u, v, w = np.array(cam["P"]) @ np.append(xyz, 1.0)
            points.append([u / w + eye * cam["width"], v / w])
            colours.append(colour)
    got = read_fresh_view(page, PIXELS, points)
    return got, [
        max(abs(a - b) for a, b in zip(rgb, colour, strict=True)) <= 60
        for rgb, colour in zip(got["rgb"], colours, strict=True)
    ]


def test_the_low_layer_is_shown_at_the_cameras_size_and_stays_registered(
    browser: Browser, server: str
) -> None:
    status = httpx.get(server + "api/v1/video").json()
    width, height = status["width"], status["height"]
    full, _ = open_page(browser, server)
    low, errors = open_page(browser, server, query="layer=low")
    for page in (full, low):
        page.evaluate("window.telerobot.setMode('side-by-side')")
    wait(low, "window.telerobot.hud.figures && window.telerobot.hud.figures.layer === 'low'")
    assert low.evaluate("window.telerobot.hud.figures.frameSize") == f"{width}×{height // 2}"
    assert low.evaluate("document.querySelector('video').videoWidth") == width  # 2 × half
    # (The full page's figures come with its first statistics: later on a busy machine.)
    # (Waited for as "full" itself: a page re-negotiating under load shows "—" again.)
    wait(full, "window.telerobot.hud.figures && window.telerobot.hud.figures.layer === 'full'")

    # The server sends each page its own layer, from two encoders. (Waited for: on a
    # busy machine a page that found its view stale is re-negotiating its peer for a
    # moment, and the server lists it again once it has.)
    def layers() -> list[str]:
        stats = httpx.get(server + "api/v1/video").json()["stats"]
        return sorted(v["layer"] for v in stats["viewers"])

    # (The operator's page shares the full layer while its link carries it; a busy
    # machine's late RTCP, read as a queue, may give it its own stream for a while.)
    until(
        lambda: layers() in (["full", "low"], ["low", "operator"]),
        30,
        lambda: f"layers {layers()}",
        poll=0.2,
    )
    # Both views are the camera's size, and the fiducials are where the camera sees them
    # in both (the low picture stretched, not drawn in a corner at half size).
    # Read from a frame drawn undimmed: on a loaded machine a page may dim its view as
    # stale (VIDEO STALE) for a moment at any time, which changes every colour; the read
    # says whether the view was stale as it was taken, and a stale read is taken again.
    for name, page in (("full", full), ("low", low)):
        got, hits = fiducials_seen(page, server)
        for _ in range(100):
            if got["stale"] is None and sum(hits) >= len(hits) - 2:
                break
            page.wait_for_timeout(300)
            got, hits = fiducials_seen(page, server)
        assert got["stale"] is None, (name, got)
        assert got["size"] == [2 * width, height - got["crop"]], (name, got)
        assert sum(hits) >= len(hits) - 2, (name, got, hits)  # the arm may hide one per eye
    assert not [e for e in errors if "video" in e.lower()], errors
    full.close()
    low.close()
