"""The connection HUD (web/src/ui/connection-hud.ts) as a browser test reads it: page
expressions over its rows, and its judgment and drawn box read at one instant."""

from __future__ import annotations

from typing import Any

from playwright.sync_api import Page

HUD = "window.telerobot.hud"


def row_is(key: str, condition: str) -> str:
    """A page expression: the HUD's `key` row exists and `condition` holds for it (`r`)."""
    return f"(() => {{ const r = {HUD}.rows.find((x) => x.key === '{key}'); return !!r && ({condition}); }})()"


def said(page: Page) -> str:
    return str(
        page.evaluate(
            f"JSON.stringify({{ level: {HUD}.level, rows: {HUD}.rows, pinned: {HUD}.pinned, figures: {HUD}.figures }})"
        )
    )


# The HUD's judgment and the box on the page, read at one instant (the box is redrawn
# right after each judgment, before any other task runs).
SNAPSHOT = f"""(() => {{
    const h = {HUD}, box = document.getElementById("hud");
    return {{
        level: h.level, reason: h.reason, rows: h.rows, figures: h.figures, pinned: h.pinned,
        cls: box.className, title: box.title,
        heading: box.querySelector(".hud-title")?.textContent,
        lines: [...box.querySelectorAll(".hud-row")].map((l) => ({{
            key: l.dataset.key, cls: l.className, text: l.children[1]?.textContent,
        }})),
    }};
}})()"""


def hud_when(page: Page, condition: str, timeout: float) -> dict[str, Any]:
    """Wait for ``condition`` and return the snapshot taken in the same evaluation as it
    held (the HUD is redrawn every 0.5 s: a second read could see the next judgment)."""
    try:
        handle = page.wait_for_function(
            f"({condition}) && {SNAPSHOT}", timeout=timeout, polling=100
        )
    except Exception:
        raise AssertionError(f"{condition} never held\nthe HUD: {said(page)}") from None
    found: dict[str, Any] = handle.json_value()
    return found


def row_of(d: dict[str, Any], key: str) -> dict[str, Any]:
    return next(r for r in d["rows"] if r["key"] == key)
