"""Scoped API keys."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import Field

from server.api.schemas.common import Id, Name, Strict, StrictIn
from server.api.schemas.pages import NextCursor, PageCount

Scope = Literal["admin", "maps:write", "viewer", "device", "contribute"]


class ApiKeyCreate(StrictIn):
    name: Name
    scopes: Annotated[list[Scope], Field(min_length=1, max_length=5)] = Field(
        description="admin: everything; maps:write: plans, surveys, uploads, map versions; "
        "viewer: reading; device: sessions and locate; contribute: sessions whose walk "
        "feeds the maps (with device)"
    )
    site_id: Id | None = Field(None, description="the one site the key is for; none: all")


class ApiKeyRead(Strict):
    id: str
    name: str
    scopes: list[str]
    site_id: str | None
    created_at: datetime
    rotated_at: datetime | None
    revoked_at: datetime | None


class ApiKeyList(Strict):
    items: list[ApiKeyRead]
    count: PageCount
    next_cursor: NextCursor


class ApiKeyCreated(ApiKeyRead):
    key: str = Field(description="the secret: shown this once, only its digest is kept")
