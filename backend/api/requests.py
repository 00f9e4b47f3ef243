"""The base of every request body: strict types, so ``true`` is not taken for 1 and
``"0.5"`` not for 0.5 (JSON numbers are still taken for floats)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictRequest(BaseModel):
    model_config = ConfigDict(strict=True)
