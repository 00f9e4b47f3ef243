"""Liveness and version."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter
from pydantic import BaseModel

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str
    version: str


def _version() -> str:
    try:
        return version("telerobot")
    except PackageNotFoundError:
        return "unknown"


@router.get("/health")
async def health() -> Health:
    return Health(status="ok", version=_version())
