"""The base of every request body: a JSON ``true`` is not taken for 1 where a number
is expected (pydantic's lax mode would). Everything else stays as pydantic reads
JSON: numbers for floats, strings for enums, arrays for tuples."""

from __future__ import annotations

import types
import typing
from typing import Any

from pydantic import BaseModel, model_validator


def _takes_numbers(annotation: Any) -> bool:
    if annotation is bool:
        return False
    if annotation in (int, float):
        return True
    return any(_takes_numbers(a) for a in typing.get_args(annotation))


def _has_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    if isinstance(value, list | tuple):
        return any(_has_bool(v) for v in value)
    return False


class StrictRequest(BaseModel):
    @model_validator(mode="before")
    @classmethod
    def _no_booleans_for_numbers(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for name, info in cls.model_fields.items():
                annotation = info.annotation
                takes_bool = annotation is bool or (
                    isinstance(annotation, types.UnionType) and bool in typing.get_args(annotation)
                )
                if (
                    not takes_bool
                    and _takes_numbers(annotation)
                    and _has_bool(data.get(info.alias or name))
                ):
                    raise ValueError(f"{name}: a number is expected, not true or false")
        return data
