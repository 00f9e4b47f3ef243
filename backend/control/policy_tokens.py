"""Policy tokens: a credential that can only drive (docs/lerobot.md, "Policy tokens").

A learned policy must not hold the operator token: with it, it could reset the e-stop,
resume itself, take control from a person, change settings or delete recordings. An
operator issues a policy token instead (``POST /api/v1/policy-tokens``, ``telerobot
policy-token new NAME``), named, listed and revocable. It joins only as a policy
(HELLO's ``POLICY`` flag, ``policy: true`` on ``POST /lease``), drives only while the
supervision says AUTONOMOUS (``telerobot.server.control.autonomy``) and reads what
anyone may read; every person's action stays the operator token's.

Only a digest of each token is kept (in memory, and in ``policy-tokens.json`` beside the
operator token when the server has a state folder): a copy of the file drives nothing.
The secret is shown once, when it is issued.
"""

from __future__ import annotations

import hashlib
import json
import logging
import secrets
import time
from dataclasses import dataclass, field
from pathlib import Path

from telerobot.drivers.base import TelerobotError
from telerobot.protocol.names import client_name

log = logging.getLogger(__name__)

PREFIX = "tpol_"  # says what a token is wherever it is pasted (≤ 64 bytes in a HELLO)
SECRET_BYTES = 24
MAX_POLICY_TOKENS = 32  # issued and not revoked, at once
ID_BYTES = 4


class PolicyTokenNotFound(TelerobotError):
    code = "not_found"
    http_status = 404


class TooManyPolicyTokens(TelerobotError):
    code = "too_many"
    http_status = 409


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


@dataclass(frozen=True)
class PolicyToken:
    """One issued token, as listed: never its secret."""

    id: str
    name: str
    created: float  # Unix time
    digest: str = field(repr=False)

    def as_dict(self) -> dict[str, object]:
        return {"id": self.id, "name": self.name, "created": self.created}


class PolicyTokens:
    """The issued tokens. ``path``: where they are kept between starts (None: memory only)."""

    def __init__(self, path: Path | None = None, *, limit: int = MAX_POLICY_TOKENS) -> None:
        self.path = path
        self.limit = limit
        self._tokens: dict[str, PolicyToken] = {}
        if path is not None and path.exists():
            self._load(path)

    def _load(self, path: Path) -> None:
        try:
            rows = json.loads(path.read_text())
            for row in rows[: self.limit]:
                token = PolicyToken(
                    str(row["id"]), str(row["name"]), float(row["created"]), str(row["digest"])
                )
                self._tokens[token.id] = token
        except (OSError, ValueError, KeyError, TypeError) as exc:
            # Refusing every policy is the safe side of a damaged file: said, not fatal.
            log.warning(
                "policy tokens: %s is unreadable (%s); none is valid until issued again", path, exc
            )
            self._tokens.clear()

    def _save(self) -> None:
        if self.path is None:
            return
        rows = [{**t.as_dict(), "digest": t.digest} for t in self._tokens.values()]
        from telerobot.server.security import write_private

        write_private(self.path, json.dumps(rows, indent=1).encode() + b"\n")

    def issue(self, name: str) -> tuple[PolicyToken, str]:
        """A new token named ``name`` (the naming rule of clients): it and its secret."""
        name = client_name(name)
        if len(self._tokens) >= self.limit:
            raise TooManyPolicyTokens(
                f"{self.limit} policy tokens are issued already: revoke one you no longer use"
                " (telerobot policy-token list, then revoke ID)"
            )
        secret = PREFIX + secrets.token_urlsafe(SECRET_BYTES)
        ident = secrets.token_hex(ID_BYTES)
        while ident in self._tokens:
            ident = secrets.token_hex(ID_BYTES)
        token = PolicyToken(ident, name, time.time(), _digest(secret))
        self._tokens[ident] = token
        self._save()
        log.info("policy token %s issued for %r", ident, name)
        return token, secret

    def revoke(self, ident: str) -> PolicyToken:
        token = self._tokens.pop(ident, None)
        if token is None:
            raise PolicyTokenNotFound(
                f"no policy token {ident!r}: GET /api/v1/policy-tokens lists the issued ones"
            )
        self._save()
        log.info("policy token %s (%r) revoked", ident, token.name)
        return token

    def list(self) -> list[PolicyToken]:
        return sorted(self._tokens.values(), key=lambda t: t.created)

    def match(self, candidate: str | None) -> PolicyToken | None:
        """The issued token ``candidate`` is, if any; every entry compared (constant time
        over the table, so a guess learns nothing from the time it takes)."""
        if not candidate or not candidate.startswith(PREFIX):
            return None
        digest = _digest(candidate).encode()
        found = None
        for token in self._tokens.values():
            if secrets.compare_digest(digest, token.digest.encode()):
                found = token
        return found

    def __len__(self) -> int:
        return len(self._tokens)
