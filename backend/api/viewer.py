"""Where the 3D view of the workcell (viser) is served, for the operator page's link."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field

from telerobot.server.api.deps import ViewerDep

router = APIRouter(prefix="/viewer", tags=["viewer"])


class ViewerState(BaseModel):
    port: int | None = Field(description="HTTP port of the 3D view on this host; null: not running")
    error: str | None = None


@router.get("")
async def viewer(viewer: ViewerDep) -> ViewerState:
    view = viewer.view
    return ViewerState(port=None if view is None else view.port, error=viewer.error)
