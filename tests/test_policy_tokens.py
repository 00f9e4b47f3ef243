"""Policy tokens over REST (backend/api/policy_tokens.py, backend/control/policy_tokens.py):
issued, listed and revoked by an operator; a policy token joins only as a policy, drives
only after a person's go, and can do nothing a person does. The store's limit and its
file (digests only, private)."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from telerobot.server.control.policy_tokens import (
    PREFIX,
    PolicyTokens,
    TooManyPolicyTokens,
)
from tests.support import TOKEN

AUTH = {"Authorization": f"Bearer {TOKEN}"}
MOVE = {"space": "joint", "mode": "incremental", "joints": [0.01, 0, 0, 0, 0, 0]}


def issue(client: TestClient, name: str = "act-policy") -> tuple[str, dict[str, str]]:
    r = client.post("/api/v1/policy-tokens", json={"name": name}, headers=AUTH)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["token"].startswith(PREFIX)
    return body["id"], {"Authorization": f"Bearer {body['token']}"}


def test_a_policy_token_drives_only_after_a_persons_go_and_does_nothing_else(
    client: TestClient,
) -> None:
    ident, policy = issue(client)
    listed = client.get("/api/v1/policy-tokens", headers=AUTH).json()
    assert [t["id"] for t in listed] == [ident] and "token" not in listed[0]
    assert client.get("/api/v1/policy-tokens", headers=policy).status_code == 403

    # As a person: refused. As a policy: it takes control, paused.
    r = client.post("/api/v1/lease", json={"name": "act"}, headers=policy)
    assert r.status_code == 403 and "joins only as a policy" in r.json()["detail"]
    r = client.post("/api/v1/lease", json={"name": "act", "policy": True}, headers=policy)
    assert r.status_code == 200, r.text
    me = {**policy, "X-Client-Id": r.json()["client_id"]}
    assert client.get("/api/v1/autonomy").json()["mode"] == "paused"
    r = client.post("/api/v1/robot/move", json=MOVE, headers=me)
    assert r.status_code == 409 and "resumes you" in r.json()["detail"]

    # What a person does is refused to it, at the edge or by the server.
    for method, path in [
        ("post", "/api/v1/autonomy/resume"),
        ("post", "/api/v1/autonomy/pause"),
        ("post", "/api/v1/safety/reset"),
        ("put", "/api/v1/control"),
        ("post", "/api/v1/recordings"),
        ("delete", "/api/v1/recordings/x.mcap"),
        ("post", "/api/v1/policy-tokens"),
    ]:
        r = client.request(method, path, json={}, headers=me)
        assert r.status_code == 403, (path, r.text)
        assert "policy token cannot do this" in r.json()["detail"], (path, r.text)
    assert client.get("/api/v1/autonomy").json()["mode"] == "paused"

    # A person says go (no lease of their own needed); then it drives.
    r = client.post("/api/v1/autonomy/resume", headers=AUTH)
    assert r.status_code == 200 and r.json()["mode"] == "autonomous", r.text
    r = client.post("/api/v1/robot/move", json=MOVE, headers=me)
    assert r.status_code == 200, r.text

    # Revoked: its client is gone and the token joins no more.
    r = client.delete(f"/api/v1/policy-tokens/{ident}", headers=AUTH)
    assert r.status_code == 200 and r.json()["disconnected"] == 1
    assert client.get("/api/v1/autonomy").json()["mode"] == "off"
    assert client.get("/api/v1/safety").json()["controller"] is None
    r = client.post("/api/v1/lease", json={"name": "act", "policy": True}, headers=policy)
    assert r.status_code == 403
    assert client.delete(f"/api/v1/policy-tokens/{ident}", headers=AUTH).status_code == 404


def test_the_operator_token_as_a_policy_is_refused_naming_the_policy_token(
    client: TestClient,
) -> None:
    r = client.post("/api/v1/lease", json={"name": "act", "policy": True}, headers=AUTH)
    assert r.status_code == 403
    assert "policy token" in r.json()["detail"] and "policy-token new" in r.json()["detail"]


def test_a_policy_token_cannot_use_another_policys_client(client: TestClient) -> None:
    _, first = issue(client, "first")
    _, second = issue(client, "second")
    r = client.post("/api/v1/lease", json={"name": "first", "policy": True}, headers=first)
    me = r.json()["client_id"]
    r = client.post("/api/v1/robot/move", json=MOVE, headers={**second, "X-Client-Id": me})
    assert r.status_code == 403 and "did not join with this policy token" in r.json()["detail"]
    client.delete("/api/v1/lease", headers={**first, "X-Client-Id": me})


def test_the_store_keeps_digests_only_privately_and_has_a_limit(tmp_path: Path) -> None:
    path = tmp_path / "state" / "policy-tokens.json"
    store = PolicyTokens(path, limit=3)
    secrets = [store.issue(f"p{i}")[1] for i in range(3)]
    with pytest.raises(TooManyPolicyTokens, match="revoke one"):
        store.issue("one-too-many")
    text = path.read_text()
    assert not any(s in text for s in secrets)  # only digests
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    again = PolicyTokens(path, limit=3)  # a restart keeps them
    assert again.match(secrets[0]) is not None and again.match("tpol_guess") is None
    assert "digest" not in repr(again.list()[0])
    again.revoke(again.list()[0].id)
    assert PolicyTokens(path).match(secrets[0]) is None
    path.write_text("{not json")
    assert len(PolicyTokens(path)) == 0  # damaged: none valid, said in the log
    assert json.loads(json.dumps([t.as_dict() for t in again.list()]))
