"""What the DecisionServer refuses, as errors that say why (each with its wire code and
HTTP status: telerobot/server/errors.py). Nothing moved when one is raised."""

from __future__ import annotations

from telerobot.drivers.base import InvalidCommand, TelerobotError


class NotAllowed(TelerobotError):
    """The client may not do this (observer, or someone else holds the lease)."""

    code = "not_allowed"
    http_status = 403


class SafetyStop(TelerobotError):
    """Motion is stopped by the e-stop or the force limit; nothing moved."""

    code = "safety_stop"
    http_status = 409


class LimitExceeded(InvalidCommand):
    """The command would break a safety limit (workspace, step, singularity); nothing moved."""

    code = "limit_exceeded"


class StillMoving(TelerobotError):
    """A scripted move did not end within the time its caller would wait; it goes on."""

    code = "still_moving"
    http_status = 504
