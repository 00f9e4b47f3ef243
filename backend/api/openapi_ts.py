"""The REST API's TypeScript types for the web client (docs/architecture.md, rule 5): the
server's OpenAPI schema, taken from ``create_app`` without running a server, turned
into web/src/api/schema.d.ts by the npm package ``openapi-typescript`` (a devDependency
of web/). A test (tests/test_web_types.py) fails when the committed file differs.

    python -m telerobot.server.api.openapi_ts             # regenerate web/src/api/schema.d.ts
    python -m telerobot.server.api.openapi_ts --schema    # print the OpenAPI schema (JSON)
    python -m telerobot.server.api.openapi_ts --out FILE  # write the TypeScript elsewhere
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

WEB = Path(__file__).resolve().parents[2] / "web"
TARGET = WEB / "src" / "api" / "schema.d.ts"
GENERATOR = WEB / "node_modules" / ".bin" / "openapi-typescript"


def openapi_schema() -> dict[str, Any]:
    """The schema the server publishes at /openapi.json. Nothing is opened: the
    devices start in the app's lifespan, which this never enters."""
    from telerobot.server.app import create_app
    from telerobot.server.settings import Settings

    # Any valid token (so none is read or made on disk); a loopback host (so no name
    # lookups). Neither changes the routes or their models.
    settings = Settings(operator_token="x" * 20, host="127.0.0.1", tls=False)
    schema: dict[str, Any] = create_app(settings).openapi()
    return schema


def generate(out: Path, generator: Path = GENERATOR) -> None:
    """Write the TypeScript types of the current schema to ``out``."""
    if not generator.exists():
        raise FileNotFoundError(
            f"{generator} is missing: run `npm install` in web/ (`make test` does)"
        )
    with tempfile.TemporaryDirectory() as tmp:
        schema = Path(tmp) / "openapi.json"
        schema.write_text(json.dumps(openapi_schema(), indent=1))
        subprocess.run(
            [str(generator), str(schema), "--output", str(out.resolve())],
            cwd=WEB,
            check=True,
            stdout=subprocess.DEVNULL,
        )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m telerobot.server.api.openapi_ts", description=__doc__
    )
    parser.add_argument("--schema", action="store_true", help="print the OpenAPI schema")
    parser.add_argument("--out", type=Path, default=TARGET, help=f"default: {TARGET}")
    args = parser.parse_args(argv)
    if args.schema:
        json.dump(openapi_schema(), sys.stdout, indent=1)
        print()
        return
    generate(args.out)


if __name__ == "__main__":
    main()
