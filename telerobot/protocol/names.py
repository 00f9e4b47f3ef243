"""The names clients give themselves: who has control, as the page's
header, the SAFETY event ("control: NAME (why)"), ``GET /safety``'s ``controller``,
the recording's commands and the log say it. Without one, a connection is named by
its address ("ws 127.0.0.1:51186"), which tells a person nothing.

A page names itself in its ``/ws`` URL (``/ws?name=…``: the HELLO's layout stays as
it is), a script in its lease request (``POST /lease`` ``{"name": …}``). A name is
shown as it is wherever control is listed, so it is bounded and plain: 1–64
characters once trimmed, letters and digits (any script), spaces and ``. , : _ - @ #
+ / '``. Not ``( ) ;`` (the page reads the SAFETY event's "control: NAME (why)"),
no quotes, angle brackets, other punctuation or control characters. The page checks
a name with the same rule (web/src/ui/operator-name.ts) before it uses one.
"""

from __future__ import annotations

from typing import Final

from telerobot.drivers.base import InvalidCommand

MAX_NAME: Final = 64
PUNCTUATION: Final = " .,:_-@#+/'"
RULE: Final = (
    f"1–{MAX_NAME} characters: letters, digits, spaces and . , : _ - @ # + / ' "
    "(no brackets, quotes or control characters)"
)


def name_problem(name: str) -> str:
    """Why ``name`` (trimmed) is not a client's name; "" if it is one. The name itself
    is not repeated (an answer never echoes the input)."""
    if not name:
        return f"a name is {RULE}: this one is empty"
    if len(name) > MAX_NAME:
        return f"a name is {RULE}: this one has {len(name)} characters"
    bad = sorted({c for c in name if not (c.isalnum() or c in PUNCTUATION)})
    if bad:
        shown = ", ".join(f"U+{ord(c):04X}" if not c.isprintable() else repr(c) for c in bad[:5])
        return f"a name is {RULE}: this one has {shown}"
    return ""


def client_name(name: str) -> str:
    """``name`` trimmed, if it is a client's name; else ``InvalidCommand`` saying why."""
    name = name.strip()
    problem = name_problem(name)
    if problem:
        raise InvalidCommand(problem)
    return name
