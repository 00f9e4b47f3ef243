"""What a new user tripped over on the operator page, in Debian's Chromium against real
servers: Escape with the help open closes it and does not latch the e-stop (the E-STOP
button works over it); a server restarted with another model is drawn as its own arm
(labels, ghost, AR ball), a stale CONTROL LOST alert goes, and Run is disabled while
the server is away; every joint fits the Robot panel; an empty message list is one
muted line, not an empty box; the calibration page fits the window and shows the live
images before freezing; Enter VR without a headset says what is needed; the page names
itself, and every page says who has control by name."""

from __future__ import annotations

import time
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser, Page

from tests.support import TOKEN
from tests.support.browser import (
    ENV,
    NO_VIDEO,
    assert_ball_on_the_tool,
    open_page,
    take_control,
    wait,
)
from tests.support.servers import free_port, serving

pytestmark = pytest.mark.browser
# Nothing here but the calibration page needs the picture: the machine's CPU for the rest.
SERVER_ENV = NO_VIDEO
SO101 = {"TELEROBOT_ROBOT_MODEL": "so101", "TELEROBOT_HOME_POSE": "ready"}
AUTH = {"Authorization": f"Bearer {TOKEN}"}

HELP_OPEN = "!document.getElementById('help').hidden"
HELP_CLOSED = "document.getElementById('help').hidden"
BADGE = "document.getElementById('status').textContent"
ESTOP = "(window.telerobot.state.flags & 4) !== 0"

# Whether every cell of the joints table lies inside the aside's visible width, and
# the aside needs no sideways scrolling (the PUMA's sixth joint was cut off, and all but
# three of the SO-101's).
JOINTS_FIT = """() => {
  const aside = document.querySelector('aside').getBoundingClientRect();
  const cells = [...document.querySelectorAll('#joints th, #joints td')];
  const inside = cells.every((c) => {
    const r = c.getBoundingClientRect();
    return r.width > 0 && r.left >= aside.left - 0.5 && r.right <= aside.right + 0.5;
  });
  const a = document.querySelector('aside');
  return { cells: cells.length, inside, scrolls: a.scrollWidth > a.clientWidth + 1 };
}"""


def estop_latched(server: str) -> bool:
    return bool(httpx.get(server + "api/v1/safety").json()["estop"])


def joint_names(page: Page) -> list[str]:
    return list(page.locator("#joints th").all_inner_texts())


def assert_joints_fit(page: Page, n: int) -> None:
    fit: dict[str, Any] = page.evaluate(JOINTS_FIT)
    assert fit == {"cells": 2 * n, "inside": True, "scrolls": False}, fit


def record_an_episode(server: str) -> None:
    """A recording with one episode, through REST: the Tasks panel then offers Run."""
    rest = httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=30)
    assert rest.post("recordings", json={"name": "page-fixes"}).status_code == 200
    assert rest.post("recordings/active/episodes", json={"task": "stay"}).status_code == 200
    time.sleep(0.3)  # some states in it (not a condition)
    assert rest.post("recordings/active/episodes/end", json={"success": True}).status_code == 200
    assert rest.post("recordings/active/stop").status_code == 200


def test_escape_closes_the_help_without_the_estop_and_the_estop_button_works_over_it(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, video=False)
    take_control(page)
    page.keyboard.press("?")
    wait(page, HELP_OPEN)
    page.keyboard.press("Escape")  # closes the help, and only that
    wait(page, HELP_CLOSED)
    page.wait_for_timeout(500)  # time for an e-stop to have reached the server
    assert not estop_latched(server)
    assert page.evaluate("(window.telerobot.state.flags & 1) !== 0")  # control kept

    # With the help open, the E-STOP button is on top (the overlay does not cover it)…
    page.keyboard.press("?")
    wait(page, HELP_OPEN)
    top = page.evaluate(
        """() => { const r = document.getElementById('estop').getBoundingClientRect();
        const el = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
        return el && el.closest('#estop') ? 'estop' : (el ? el.id || el.className : null); }"""
    )
    assert top == "estop", top
    page.click("#estop", timeout=5_000)  # …and works
    wait(page, ESTOP)
    assert estop_latched(server)
    page.click("#reset")
    wait(page, f"!({ESTOP})")
    page.keyboard.press("Escape")
    wait(page, HELP_CLOSED)
    page.keyboard.press("Escape")  # nothing open: the e-stop key
    wait(page, ESTOP)
    page.click("#reset")
    wait(page, f"!({ESTOP})")
    page.click("#release")
    assert errors == []
    page.close()


def test_every_joint_fits_the_robot_panel(browser: Browser, server: str) -> None:
    page, errors = open_page(browser, server, video=False)
    wait(page, "document.querySelectorAll('#joints th').length === 6")
    assert_joints_fit(page, 6)
    assert errors == []
    page.close()


# The message list as drawn: its box, its border's colour, what its ::before says.
# (``clear``: emptied first, in the same task: no message can come in between.)
MESSAGES_LOOK = """(clear) => { const el = document.getElementById('messages');
  if (clear) el.replaceChildren();
  const r = el.getBoundingClientRect(); const s = getComputedStyle(el);
  return { top: r.top, height: r.height, width: r.width, border: s.borderTopColor,
           placeholder: getComputedStyle(el, '::before').content, text: el.innerText,
           lines: el.querySelectorAll('li').length }; }"""
TRANSPARENT = "rgba(0, 0, 0, 0)"


def test_an_empty_message_list_is_one_muted_line_not_an_empty_box(
    browser: Browser, server: str
) -> None:
    """Before its first line the list draws no empty bordered box
    (7.5 lines high) but one muted line saying so; it stays laid out, in view at the
    aside's top (test_web_panels' message log needs it there before its first line,
    which hiding it broke), and takes its box when a line comes."""
    page, errors = open_page(browser, server, video=False)
    empty: dict[str, Any] = page.evaluate(MESSAGES_LOOK, True)
    assert empty["lines"] == 0 and empty["text"] == "", empty  # (the note is no message)
    assert 0 < empty["height"] < 30 and empty["width"] > 0, empty  # one line, not 7.5
    assert 0 <= empty["top"] < 900, empty  # in view
    assert empty["border"] == TRANSPARENT, empty  # no box drawn
    assert "No messages yet" in empty["placeholder"], empty

    page.click("#xr")  # a line: Enter VR without a headset says what is needed
    wait(page, "document.querySelectorAll('#messages li').length > 0")
    full: dict[str, Any] = page.evaluate(MESSAGES_LOOK, False)
    assert full["height"] > 80 and full["border"] != TRANSPARENT, full  # the log's box
    assert full["placeholder"] in ("none", "normal"), full
    # Still in view (not asserted in place: what sits above it, the status lines, may
    # change height meanwhile; a run saw it 32 px higher once a line came).
    assert 0 <= full["top"] < 900, full
    assert [e for e in errors if "Uncaught" in e] == [], errors
    page.close()


def controller(server: str) -> object:
    return httpx.get(server + "api/v1/safety").json()["controller"]


def test_the_page_names_itself_and_others_see_who_has_control_by_name(
    browser: Browser, server: str
) -> None:
    """Operators were "ws 127.0.0.1:51186" everywhere. The page names
    itself ("browser on <platform>" until a name is typed in the Driving panel, kept in
    the browser, used from the next connection); who has control is that name for the
    server and on every other page's header; a name the server would refuse is not kept."""
    page, errors = open_page(browser, server, video=False)
    default = page.input_value("#operator-name")
    assert default.startswith("browser on ") and len(default) <= 64, default
    take_control(page)
    assert controller(server) == default
    page.click("#release")
    wait(page, "(window.telerobot.state.flags & 1) === 0")

    name = page.locator("#operator-name")
    name.fill("  Ana at the bench ")
    name.dispatch_event("change")
    wait(page, "document.getElementById('name-status').textContent.includes('next connection')")
    assert page.evaluate("localStorage.getItem('telerobot.name')") == "Ana at the bench"
    page.reload()  # (the token was kept in the browser at the first welcome)
    page.wait_for_function("window.telerobot && window.telerobot.state", timeout=60_000)
    assert page.input_value("#operator-name") == "Ana at the bench"
    take_control(page)
    assert controller(server) == "Ana at the bench"

    # Another page, an observer, names who has control.
    other, other_errors = open_page(browser, server, token="", video=False)
    wait(
        other,
        "document.getElementById('control-owner').textContent === 'Ana at the bench has control'",
    )
    other.close()

    # A name the server would refuse is not kept, and says why.
    name.fill("Ana (bench); 2")
    name.dispatch_event("change")
    wait(page, "document.getElementById('name-status').classList.contains('error')")
    said = page.locator("#name-status").inner_text()
    assert said.startswith("Not kept: a name is 1–64 characters"), said
    assert page.evaluate("localStorage.getItem('telerobot.name')") == "Ana at the bench"
    page.click("#release")
    wait(page, "(window.telerobot.state.flags & 1) === 0")
    assert not [e for e in errors + other_errors if "Uncaught" in e], (errors, other_errors)
    page.close()


def test_enter_vr_without_a_headset_says_what_is_needed(browser: Browser, server: str) -> None:
    page, _ = open_page(browser, server, video=False)  # Chromium here has no XR device
    page.click("#xr")
    wait(page, "document.getElementById('messages').innerText.includes('headset')")
    said = page.locator("#messages").inner_text()
    assert "WebXR emulator" in said, said
    assert "session configuration is not supported" not in said, said
    assert "headset" in (page.locator("#xr").get_attribute("title") or "")
    page.close()


def test_a_server_restarted_with_another_model_is_drawn_as_its_own_arm(
    browser: Browser,
) -> None:
    port = free_port()
    with serving(NO_VIDEO, port=port) as base:
        puma = httpx.get(base + "api/v1/robot/model").json()
        assert puma["model"] == "puma560"
        record_an_episode(base)
        page, errors = open_page(browser, base, video=False)
        wait(page, f"document.querySelectorAll('#joints th').length === {len(puma['joint_names'])}")
        assert joint_names(page) == puma["joint_names"]
        wait(page, "window.telerobot.ghost.pixels[0].length === 8")  # base, 6 joints, tool
        take_control(page)
        wait(page, "!document.getElementById('task-run').disabled")
    # The server is gone: Run (and Approach) cannot start anything.
    wait(page, f"{BADGE} === 'DISCONNECTED'", timeout=20_000)
    wait(page, "document.getElementById('task-run').disabled", timeout=2_000)

    with serving({**NO_VIDEO, **SO101}, port=port) as again:
        assert again == base
        so101 = httpx.get(base + "api/v1/robot/model").json()
        assert so101["model"] == "so101"
        # The page, reconnected, draws the SO-101: its joint names, its ghost (base, the
        # five joints that carry the tool, the tool), the ball on its tool.
        wait(
            page,
            f"document.querySelector('#joints th').textContent === '{so101['joint_names'][0]}'",
            30_000,
        )
        assert joint_names(page) == so101["joint_names"]
        assert_joints_fit(page, 6)
        wait(page, "window.telerobot.ghost.pixels[0].length === 7")
        assert page.evaluate("window.telerobot.ghost.pixels.map((c) => c.length)") == [7, 7]
        assert_ball_on_the_tool(page, base)
        assert "now drives the SO-101" in page.locator("#messages").inner_text()
        take_control(page)  # (the new server's lease: this page held the old one's)
        # Someone else takes it: CONTROL LOST, said over the video…
        r = httpx.post(base + "api/v1/lease", json={"name": "someone", "force": True}, headers=AUTH)
        assert r.status_code == 200, r.text
        wait(
            page,
            "document.getElementById('control-alert-text').textContent.includes('CONTROL LOST')",
        )

    # …and the server restarts with the PUMA again (the reverse): the alert about the
    # ended session goes, and the PUMA is drawn again.
    with serving(NO_VIDEO, port=port):
        wait(
            page,
            f"document.querySelector('#joints th').textContent === '{puma['joint_names'][0]}'",
            30_000,
        )
        assert joint_names(page) == puma["joint_names"]
        wait(page, "window.telerobot.ghost.pixels[0].length === 8")
        assert_ball_on_the_tool(page, base)
        wait(page, "document.getElementById('control-alert').hidden")
        assert "CONTROL LOST" not in page.locator("#stage").inner_text()
    assert not [e for e in errors if "Uncaught" in e], errors
    page.close()


def test_the_calibration_page_fits_the_window_and_shows_live_images_before_freezing(
    browser: Browser,
) -> None:
    with serving(ENV) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(base + f"calibration.html?token={TOKEN}")
        page.wait_for_function(
            "window.calibration && document.getElementById('video').videoWidth > 0",
            timeout=60_000,
        )
        # The right column in the window (it stuck out past the window's edge), beside
        # the images, and nothing to scroll sideways.
        aside = page.locator("#calib aside").bounding_box()
        assert aside is not None
        assert aside["x"] + aside["width"] <= 1280, aside
        assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
        for cam in ("left", "right"):
            b = page.locator(f"#{cam}").bounding_box()
            assert b is not None and b["x"] + b["width"] <= aside["x"], (cam, b, aside)
        # Before freezing, each image shows the live scene (not a blank box): its pixels
        # vary (the simulated workcell, drawn), and the page is not frozen.
        spread = """(id) => { const c = document.getElementById(id);
          const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
          let lo = 255, hi = 0; for (let i = 0; i < d.length; i += 4 * 97) { lo = Math.min(lo, d[i]); hi = Math.max(hi, d[i]); }
          return hi - lo; }"""
        page.wait_for_function(
            f"(({spread})('left') > 30) && (({spread})('right') > 30)", timeout=20_000
        )
        assert page.evaluate("Object.keys(window.calibration.frozen).length") == 0
        page.click("#freeze")
        assert "Click fiducial 1" in page.locator("#prompt").inner_text()
        assert errors == []
        page.close()


# Each header state as the page shows it (the badges' words and the buttons its wiring
# unhides: web/src/wiring/supervision.ts, ui/status.ts), set on the page's own elements.
HEADER_STATES: dict[str, tuple[str, list[str]]] = {
    "autonomous": ("AUTONOMOUS · act-so101-pick-and-place-policy · 30 Hz", ["pause-policy"]),
    "paused": (
        "PAUSED · act-so101-pick-and-place-policy — press P to let it drive (the"
        " supervisor paused it from the page)",
        ["resume-policy"],
    ),
    "correcting": (
        "CORRECTING · browser on Linux x86_64 (ws 127.0.0.1:51234) drives,"
        " act-so101-pick-and-place-policy waits",
        ["hand-back", "release", "home"],
    ),
    "estop": ("", ["reset", "release", "home"]),
}
HEADER_FIT = """([badge, shown]) => {
  const a = document.getElementById('autonomy');
  a.hidden = badge === ''; a.textContent = badge;
  for (const id of ['pause-policy', 'resume-policy', 'hand-back', 'release', 'reset', 'home'])
    document.getElementById(id).hidden = !shown.includes(id);
  document.getElementById('control-owner').textContent =
    'control: browser on Linux x86_64 (ws 127.0.0.1:51234) (you)';
  const h = document.querySelector('header');
  const box = (e) => e.getBoundingClientRect();
  const kids = [...h.children].filter((e) => !e.hidden && box(e).width > 0);
  return {
    height: box(h).height,
    estop: box(document.getElementById('estop')).height,
    inside: kids.every((e) => box(e).bottom <= box(h).bottom + 0.5 && box(e).right <= innerWidth + 0.5),
    title: a.title,
  };
}"""
TASKS_FIT = """() => {
  const t = document.getElementById('tasks');
  const select = document.getElementById('task-recording');
  select.append(Object.assign(document.createElement('option'), {
    textContent: '20261207-210000-a-rather-long-recording-name-of-a-pick-and-place-session.mcap',
  }));
  select.value = select.options[select.options.length - 1].value;
  const r = t.getBoundingClientRect();
  const cut = [...t.querySelectorAll('*')].filter((e) => e.getBoundingClientRect().right > r.right + 0.5);
  return { right: r.right, width: innerWidth, cut: cut.map((e) => e.id || e.tagName) };
}"""


def test_the_header_is_one_line_and_the_tasks_panel_fits_at_1280_by_800(
    browser: Browser, server: str
) -> None:
    """A new user at 1280×800 saw the header wrap to 2-3 lines in CORRECTING and PAUSED
    ("E-/STOP" split over two) and the Tasks panel cut at its right edge."""
    page, errors = open_page(browser, server, video=False)
    page.set_viewport_size({"width": 1280, "height": 800})
    plain = page.evaluate(HEADER_FIT, ["", []])
    assert plain["inside"], plain
    for mode, (badge, shown) in HEADER_STATES.items():
        fit = page.evaluate(HEADER_FIT, [badge, shown])
        assert fit["height"] <= plain["height"] + 1, (mode, fit, plain)  # one line
        assert fit["estop"] <= plain["estop"] + 1, (mode, fit)  # "E-STOP" whole
        assert fit["inside"], (mode, fit)
        # a badge cut short keeps its whole text in its title
        page.wait_for_function("(t) => document.getElementById('autonomy').title === t", arg=badge)
    tasks = page.evaluate(TASKS_FIT)
    assert tasks["right"] <= tasks["width"] and not tasks["cut"], tasks
    assert not [e for e in errors if "Uncaught" in e], errors
    page.close()
