"""The browser tests and the benches read the operator page through its documented test
view only (`window.telerobot`, web/src/wiring/test-view.ts): every name they reach for is
one that file declares, so the page's insides can change without them (issue 52)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEST_VIEW = ROOT / "web" / "src" / "wiring" / "test-view.ts"
READERS = [*ROOT.glob("tests/**/*.py"), *ROOT.glob("bench/*.py"), *ROOT.glob("harness/*.py")]
# `window.telerobot.a.b…`: the first two names are the test view's.
REACH = re.compile(r"window\.telerobot((?:\??\.[A-Za-z_]\w*)+)")
# What the test view declares: a getter, a property or a method, at any depth.
DECLARED = re.compile(r"^\s*(?:get\s+)?([A-Za-z_]\w*)\s*(?:\(|:)", re.M)
# The test view's namespaces, whose names are declared in it; the realtime link's figures
# (`client`) are its `LinkMeta`, the HUD is the page's own `ConnectionHud` (its fields and
# its test seam `pinned` documented there); the rest are values (the state, the balls…).
NAMESPACES = {"view", "video", "glass", "loop", "control", "tasks", "recording"}
LINK_META = ROOT / "web" / "src" / "transport" / "link.ts"
HUD_FIELDS = {"level", "reason", "rows", "figures", "pinned"}


def link_meta() -> set[str]:
    text = LINK_META.read_text()
    body = text[text.index("export interface LinkMeta") :]
    return set(DECLARED.findall(body[: body.index("\n}")]))


def reaches() -> dict[tuple[str, ...], list[str]]:
    found: dict[tuple[str, ...], list[str]] = {}
    for path in READERS:
        if path.name == Path(__file__).name:
            continue
        for m in REACH.finditer(path.read_text()):
            names = tuple(n.lstrip("?.") for n in re.findall(r"\??\.\w+", m.group(1)))
            found.setdefault(names[:2], []).append(str(path.relative_to(ROOT)))
    return found


def test_every_name_the_tests_read_of_the_page_is_in_its_test_view() -> None:
    declared = set(DECLARED.findall(TEST_VIEW.read_text()))
    second = {"client": link_meta(), "hud": HUD_FIELDS} | dict.fromkeys(NAMESPACES, declared)
    undocumented = {
        ".".join(names): sorted(set(where))
        for names, where in reaches().items()
        if names[0] not in declared
        or (len(names) > 1 and names[0] in second and names[1] not in second[names[0]])
    }
    assert undocumented == {}, (
        f"the tests reach past the page's test view (web/src/wiring/test-view.ts): {undocumented}"
    )


def test_the_check_sees_the_tests_reads() -> None:
    # (So an empty scan cannot pass the check above.)
    found = reaches()
    assert ("view", "frames") in found and ("state", "flags") in found and len(found) > 30
