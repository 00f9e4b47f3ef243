"""The web client's generated types agree with the server (docs/architecture.md, rule 5): the
binary messages (web/src/transport/messages.ts, from telerobot/protocol/messages.py) and
the REST types (web/src/api/schema.d.ts, from the OpenAPI schema). Each is generated
afresh and compared with the committed file; a renamed message field fails ``tsc``."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from telerobot.drivers.base import RobotStatus
from telerobot.protocol import messages as m
from telerobot.server.api import openapi_ts
from telerobot.server.realtime import typescript

WEB = Path(__file__).resolve().parents[1] / "web"
NODE_MODULES = WEB / "node_modules"
REGENERATE = (
    "run `make types` (or: python -m telerobot.server.realtime.typescript > "
    "web/src/transport/messages.ts; python -m telerobot.server.api.openapi_ts) and commit the result"
)


def test_typescript_messages_are_generated_from_the_python_definitions() -> None:
    assert typescript.TARGET.read_text() == typescript.render(), (
        f"web/src/transport/messages.ts differs from telerobot/protocol/messages.py: {REGENERATE}"
    )


def test_every_message_has_an_interface_in_the_decoded_union() -> None:
    text = typescript.render()
    for msg in m.MESSAGES:
        name = typescript.interface_name(msg)
        assert f'export interface {name} {{\n  readonly type: "{msg.name}";' in text
        assert f"\n  | {name}" in text
        for field in msg.fields:
            assert re.search(rf"^  {field}: (number|Uint8Array);", text, re.M), (msg.name, field)


def test_the_robot_status_list_is_the_drivers_in_the_hubs_order() -> None:
    line = next(x for x in typescript.render().splitlines() if "ROBOT_STATUS =" in x)
    listed = json.loads(line.split("=", 1)[1].removesuffix(" as const;"))
    assert listed == [s.value for s in RobotStatus]


def test_rest_types_are_generated_from_the_openapi_schema(tmp_path: Path) -> None:
    if not openapi_ts.GENERATOR.exists():
        pytest.skip(
            "web/node_modules is missing (no openapi-typescript): the REST types are not "
            "checked; `make test` installs it (cd web && npm install)"
        )
    fresh = tmp_path / "schema.d.ts"
    openapi_ts.generate(fresh)
    assert openapi_ts.TARGET.read_text() == fresh.read_text(), (
        f"web/src/api/schema.d.ts differs from the server's OpenAPI schema: {REGENERATE}"
    )


def test_a_renamed_message_field_fails_the_web_clients_type_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tsc = NODE_MODULES / ".bin" / "tsc"
    if not tsc.exists():
        pytest.skip("web/node_modules is missing (no tsc): `make test` installs it")
    # STATE's tool x renamed on the server: x → px.
    renamed = dataclasses.replace(
        m.STATE, fields=tuple("px" if f == "x" else f for f in m.STATE.fields)
    )
    monkeypatch.setattr(m, "MESSAGES", tuple(renamed if x is m.STATE else x for x in m.MESSAGES))
    copy = tmp_path / "web"
    shutil.copytree(WEB / "src", copy / "src")
    shutil.copy(WEB / "tsconfig.json", copy / "tsconfig.json")
    shutil.copy(WEB / "vite.config.ts", copy / "vite.config.ts")
    (copy / "node_modules").symlink_to(NODE_MODULES)
    (copy / "src" / "transport" / "messages.ts").write_text(typescript.render())
    result = subprocess.run(
        [str(tsc), "--noEmit", "-p", str(copy)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode != 0, "tsc passed with STATE.x renamed to px"
    assert "src/transport/realtime.ts" in result.stdout and "'x'" in result.stdout, result.stdout
