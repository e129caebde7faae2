"""The body of every refusal."""

from __future__ import annotations

from pydantic import Field

from server.api.schemas.common import Strict


class ErrorItem(Strict):
    loc: list[str | int] = Field(description="the field, as a path into the request")
    msg: str
    type: str | None = None


class ErrorOut(Strict):
    """Every refusal: what is wrong with which field (``message`` is ``field: text``)."""

    detail: list[ErrorItem]
    message: str
