"""The plugins' tokens on LeRobot's command lines: each config's token is a
``pydantic.SecretStr``, which LeRobot's parser (draccus) learns here to read from
``--robot.token=…`` and never to write out. So the token is in no config's
repr, in none of the configs LeRobot's tools log at start (``pformat(asdict(cfg))``)
and in no error that quotes a config (LeRobot's "Error creating robot with config …").

Used by the plugins' config modules only (they import LeRobot, hence draccus); this
package itself needs neither."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from typing import Any

from pydantic import SecretStr

from telerobot.client.tokens import secret


def given_or(token: SecretStr | str | None, default: Callable[[], str | None]) -> SecretStr:
    """A config's token after parsing: the one given, or where it is empty (none given, or
    a config LeRobot wrote out, which keeps none) ``default()``'s."""
    given = secret(token)
    return given if given.get_secret_value() else secret(default())


def _decode(raw: Any, _path: Sequence[str]) -> SecretStr:
    return SecretStr("" if raw is None else str(raw))


def _encode(_token: SecretStr, _declared: Any = None) -> str:
    return ""  # a config written out (draccus.dump) keeps no token (given_or: the default's)


def teach_draccus() -> None:
    """Let draccus read a ``SecretStr`` from a command line or a config file, and write
    none (its own registry, draccus's documented way; registering again is harmless)."""
    draccus = importlib.import_module("draccus")  # (LeRobot's: not this package's dependency)
    draccus.decode.register(SecretStr, _decode)
    draccus.encode.register(SecretStr, _encode)
