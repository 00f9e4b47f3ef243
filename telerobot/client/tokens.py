"""Tokens on the client side, never shown: every token the client and the LeRobot plugins
hold is a ``pydantic.SecretStr``, whose ``repr`` and ``str`` are ``'**********'``, so
no repr of a client or a config, no log line and no error carries one. The value is
read only where it goes on the wire (``bearer``, the priority channel's HELLO)."""

from __future__ import annotations

from pydantic import SecretStr


def secret(token: str | SecretStr | None) -> SecretStr:
    """``token`` held as a ``SecretStr`` (None: the empty one, no token)."""
    if isinstance(token, SecretStr):
        return token
    return SecretStr(token or "")


def bearer(token: SecretStr) -> dict[str, str]:
    """The ``Authorization`` header carrying ``token`` (none without a token)."""
    value = token.get_secret_value()
    return {"Authorization": f"Bearer {value}"} if value else {}
