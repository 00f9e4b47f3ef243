"""Policy tokens: issued, listed and revoked by an operator (docs/lerobot.md, "Policy
tokens"). A policy token can only drive, and only while a person lets it
(telerobot.server.control.policy_tokens)."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field, field_validator

from telerobot.protocol.names import MAX_NAME, RULE, name_problem
from telerobot.server.api.deps import DecisionDep, HubDep, OperatorDep
from telerobot.server.api.requests import StrictRequest
from telerobot.server.control.policy_tokens import PolicyToken

router = APIRouter(tags=["control"])


class IssueRequest(StrictRequest):
    name: str = Field(max_length=MAX_NAME, description=f"what the policy is ({RULE})")

    @field_validator("name")
    @classmethod
    def _plain_name(cls, name: str) -> str:
        problem = name_problem(name.strip())
        if problem:
            raise ValueError(problem)
        return name.strip()


class PolicyTokenView(BaseModel):
    id: str = Field(description="revoke it by this (DELETE /policy-tokens/{id})")
    name: str
    created: float = Field(description="Unix time")


class IssuedPolicyToken(PolicyTokenView):
    token: str = Field(
        description="the secret, shown this once: give it to the policy (--robot.policy_token,"
        " or TELEROBOT_POLICY_TOKEN); only its digest is kept"
    )


class RevokedPolicyToken(PolicyTokenView):
    disconnected: int = Field(description="clients that had joined with it, now gone")


def _view(token: PolicyToken) -> PolicyTokenView:
    return PolicyTokenView(id=token.id, name=token.name, created=token.created)


@router.post("/policy-tokens", status_code=201)
async def issue(body: IssueRequest, decision: DecisionDep, _op: OperatorDep) -> IssuedPolicyToken:
    """A new policy token (the operator token): it joins only as a policy, drives only
    while a person lets it, and reads; it cannot reset the e-stop, pause, resume, take
    control from anyone, change settings or delete recordings."""
    token, secret = decision.clients.policy_tokens.issue(body.name)
    return IssuedPolicyToken(id=token.id, name=token.name, created=token.created, token=secret)


@router.get("/policy-tokens")
async def listed(decision: DecisionDep, _op: OperatorDep) -> list[PolicyTokenView]:
    """The issued policy tokens (never their secrets)."""
    return [_view(t) for t in decision.clients.policy_tokens.list()]


@router.delete("/policy-tokens/{token_id}")
async def revoke(
    token_id: str, decision: DecisionDep, hub: HubDep, _op: OperatorDep
) -> RevokedPolicyToken:
    """Revoke a policy token: it joins no more, and every client that joined with it is
    gone at once (its lease lapses, the arm stops, its connection closes)."""
    token = next((t for t in decision.clients.policy_tokens.list() if t.id == token_id), None)
    gone = await decision.revoke_policy_token(token_id)
    for client_id in gone:
        hub.supersede(client_id)
    assert token is not None  # revoke_policy_token raised otherwise
    return RevokedPolicyToken(**_view(token).model_dump(), disconnected=len(gone))
