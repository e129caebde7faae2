"""Errors a service raises; the API maps each to one HTTP status."""

from __future__ import annotations


class ServiceError(Exception):
    status = 400

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field


class NotFound(ServiceError):
    status = 404


def not_found(kind: str, thing_id: str) -> NotFound:
    """The answer for a ``kind`` (site, building, floor, upload) of this id that does not
    exist, or that belongs to a site the key is not for: the two look the same."""
    return NotFound(f"{kind} {thing_id} not found", field=f"{kind}_id")


class Conflict(ServiceError):
    status = 409


class Unauthorized(ServiceError):
    status = 401


class Forbidden(ServiceError):
    status = 403


class Invalid(ServiceError):
    """Input that parsed but makes no sense here (an unknown floor level, an unknown engine)."""

    status = 422


class TooLarge(ServiceError):
    status = 413


class TooMany(ServiceError):
    """A rate limit was reached; ``retry_after_s`` says when to try again."""

    status = 429

    def __init__(self, message: str, retry_after_s: int, field: str | None = None) -> None:
        super().__init__(message, field)
        self.retry_after_s = retry_after_s
