"""A driver's own settings, declared once beside it (docs/architecture.md, rule 20).

A driver with settings of its own names a ``DriverSettings`` class in its registry
line (``registry.Entry.settings``): each field is one setting (its type, default,
limits and ``description``), named with the driver's prefix (``so101_port``), set like
every other as ``TELEROBOT_SO101_PORT``, in the TOML file or by a flag. The server's
``Settings`` is composed of its own fields and every registered driver's, so adding a
device with settings edits nothing in the server. The class lives in a module that
imports nothing but pydantic (the server imports every one at start; the driver's SDK
only when chosen), and the driver reads it back with ``of(settings)``. The composition
happens when the server's settings module is first imported, in every process that
imports it (the media worker's too): a driver's entry belongs in ``DRIVERS`` itself,
not added at run time afterwards.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Self

from pydantic import BaseModel, ConfigDict


class DriverSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="ignore")

    @classmethod
    def of(cls, settings: Mapping[str, Any]) -> Self:
        """This driver's settings out of the server's (or any mapping holding them)."""
        return cls.model_validate({k: settings[k] for k in cls.model_fields if k in settings})
