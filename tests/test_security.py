from __future__ import annotations

import ssl
import stat
from pathlib import Path

import httpx
import pytest
from cryptography import x509

from telerobot.server.security import ensure_certificate, operator_token, origin_allowed
from telerobot.server.settings import Settings
from tests.support.servers import telerobot


def test_token_is_generated_once_kept_private_and_reused(tmp_path: Path) -> None:
    settings = Settings(state_dir=tmp_path)
    token, new = operator_token(settings)
    assert new and len(token) == 32
    path = tmp_path / "operator-token"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    again, new_again = operator_token(settings)
    assert (again, new_again) == (token, False)


def test_configured_token_wins(tmp_path: Path) -> None:
    token, new = operator_token(Settings(state_dir=tmp_path, operator_token="x" * 20))
    assert (token, new) == ("x" * 20, False)
    assert not (tmp_path / "operator-token").exists()


@pytest.mark.parametrize(
    ("origin", "host", "allowed", "ok"),
    [
        (None, "localhost:8000", [], True),  # not a browser
        ("http://localhost:8000", "localhost:8000", [], True),
        ("https://192.168.1.5:8443", "192.168.1.5:8443", [], True),
        ("https://evil.example", "localhost:8000", [], False),
        ("http://localhost:9999", "localhost:8000", [], False),
        (
            "http://localhost:5173",
            "localhost:8000",
            ["http://localhost:5173"],
            True,
        ),  # a dev server
    ],
)
def test_origin_check(origin: str | None, host: str, allowed: list[str], ok: bool) -> None:
    assert origin_allowed(origin, host, allowed) is ok


def test_certificate_is_made_per_installation_and_reused(tmp_path: Path) -> None:
    settings = Settings(state_dir=tmp_path)
    cert_path, key_path = ensure_certificate(settings)
    assert stat.S_IMODE(key_path.stat().st_mode) == 0o600
    cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in san.get_values_for_type(x509.DNSName)
    assert "127.0.0.1" in [str(ip) for ip in san.get_values_for_type(x509.IPAddress)]
    first = cert_path.read_bytes()
    assert ensure_certificate(settings)[0].read_bytes() == first  # not remade


def test_serve_tls_speaks_https_with_that_certificate(tmp_path: Path) -> None:
    with telerobot(
        "serve",
        "--tls",
        "--http-port",
        "0",
        "--state-dir",
        str(tmp_path),
        wait_for=r"(https://localhost:\d+/)",
    ) as (_, m):
        ctx = ssl.create_default_context(cafile=str(tmp_path / "tls" / "cert.pem"))
        r = httpx.get(m.group(1) + "api/v1/health", verify=ctx)
        assert r.status_code == 200 and r.json()["status"] == "ok"


def test_serve_prints_a_new_token_once(tmp_path: Path) -> None:
    pattern = r"Operator token \(shown this once, kept in (\S+)\): (\w+)"
    with telerobot("serve", "--http-port", "0", "--state-dir", str(tmp_path), wait_for=pattern) as (
        _,
        m,
    ):
        assert Path(m.group(1)).read_text().strip() == m.group(2)
    with telerobot(
        "serve", "--http-port", "0", "--state-dir", str(tmp_path), wait_for=r"running on"
    ) as (p, _):
        pass
    assert p.stdout is not None
    rest = p.stdout.read() if p.poll() is not None else ""
    assert "Operator token" not in rest
