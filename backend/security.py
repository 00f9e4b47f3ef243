"""The operator token, WebSocket Origin checks and the per-installation TLS certificate.

Everything secret lives in the state directory (``$XDG_CONFIG_HOME/telerobot`` or
``~/.config/telerobot``, or ``state_dir``), outside the repository and the package,
with owner-only permissions.
"""

from __future__ import annotations

import contextlib
import datetime
import ipaddress
import logging
import os
import re
import secrets
import socket
from pathlib import Path
from urllib.parse import urlsplit

from telerobot.server.settings import Settings


def state_dir(settings: Settings) -> Path:
    if settings.state_dir is not None:
        return settings.state_dir
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "telerobot"


def write_private(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def operator_token(settings: Settings) -> tuple[str, bool]:
    """The configured token, or the one stored at first start; True when it was just made."""
    if settings.operator_token:
        return settings.operator_token.get_secret_value(), False
    path = state_dir(settings) / "operator-token"
    if path.is_file():
        token = path.read_text().strip()
        if len(token) >= 16:
            return token, False
    token = secrets.token_hex(16)
    write_private(path, token.encode() + b"\n")
    return token, True


def policy_tokens_path(settings: Settings) -> Path | None:
    """Where the issued policy tokens' digests are kept between starts: beside the operator
    token when the server keeps it (none when the token is configured and no state folder
    is: a test's or a configured server's tokens live as long as it runs)."""
    if settings.operator_token and settings.state_dir is None:
        return None
    return state_dir(settings) / "policy-tokens.json"


def token_matches(candidate: str | None, token: str) -> bool:
    """A token or secret check in constant time: the operator token, a peer's secret, a
    session's resume key (every place that checks one)."""
    return candidate is not None and secrets.compare_digest(candidate.encode(), token.encode())


def bearer(authorization: str | None) -> str | None:
    """The token of an ``Authorization: Bearer …`` header, if it is one."""
    if authorization and authorization.lower().startswith("bearer "):
        return authorization[7:].strip()
    return None


def origin_allowed(origin: str | None, host: str | None, allowed: list[str]) -> bool:
    """A browser may open /ws only from a page of this server (or a listed origin).
    Clients that send no Origin (scripts, the master-arm bridge) are not browsers."""
    if origin is None:
        return True
    if origin in allowed:
        return True
    netloc = urlsplit(origin).netloc
    return bool(host) and netloc == host


def allowed_host_names(settings: Settings, certificate: Path | None = None) -> set[str]:
    """The names a request's ``Host`` may carry: the configured host, loopback, this
    machine's names and addresses (when listening on all of them), ``allowed_hosts``
    and the names in the TLS certificate."""
    names = {"localhost", "127.0.0.1", "::1", settings.host.lower()}
    names.update(h.lower() for h in settings.allowed_hosts)
    if settings.host in ("0.0.0.0", "::", ""):
        names.update(a.split("%")[0].lower() for a in _local_addresses())
        hostname = socket.gethostname().lower()
        names.update({hostname, f"{hostname}.local"})
        with contextlib.suppress(OSError):
            names.add(socket.getfqdn().lower())
    if certificate is not None and certificate.is_file():
        names.update(certificate_names(certificate))
    names.discard("")
    return names


def certificate_names(path: Path) -> set[str]:
    from cryptography import x509

    cert = x509.load_pem_x509_certificate(path.read_bytes())
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return set()
    return {n.lower() for n in san.get_values_for_type(x509.DNSName)} | {
        str(a) for a in san.get_values_for_type(x509.IPAddress)
    }


_TOKEN_IN_QUERY = re.compile(r"((?:^|[?&;])(?:token|access_token)=)[^&\s\"']*", re.IGNORECASE)


def redact_query_tokens(text: str) -> str:
    """``/?token=abc&x=1`` → ``/?token=[redacted]&x=1``."""
    return _TOKEN_IN_QUERY.sub(r"\1[redacted]", text)


class RedactTokens(logging.Filter):
    """Keeps the operator token out of the logs: uvicorn logs each request's path with
    its query string (the page may be opened with ``?token=``)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple) and record.args:
            record.args = tuple(
                redact_query_tokens(a) if isinstance(a, str) else a for a in record.args
            )
        if isinstance(record.msg, str) and "token=" in record.msg.lower():
            record.msg = redact_query_tokens(record.msg)
        return True


def redact_server_logs() -> None:
    for name in ("uvicorn.access", "uvicorn.error", "uvicorn"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())


def _local_addresses() -> set[str]:
    addresses = {"127.0.0.1", "::1"}
    try:
        for info in socket.getaddrinfo(socket.gethostname(), None):
            addresses.add(str(info[4][0]))
    except OSError:
        pass
    return addresses


def ensure_certificate(settings: Settings) -> tuple[Path, Path]:
    """A self-signed certificate for this installation, made on first use."""
    directory = state_dir(settings) / "tls"
    cert_path, key_path = directory / "cert.pem", directory / "key.pem"
    if cert_path.is_file() and key_path.is_file():
        return cert_path, key_path
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    hostname = socket.gethostname()
    names: list[x509.GeneralName] = [x509.DNSName("localhost"), x509.DNSName(hostname)]
    for a in sorted(_local_addresses()):
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(a.split("%")[0])))
        except ValueError:
            continue
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"Telerobot on {hostname}")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=825))
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    write_private(
        key_path,
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        ),
    )
    write_private(cert_path, cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path
