"""Admin routes for API keys: create (the secret shown once), list, revoke, rotate."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Response, status

from server.api.deps import GlobalAdminDep, PageQuery, RuntimeDep, SqlDep, page_query
from server.api.gated_route import GatedRoute
from server.api.schemas.common import ID_PATTERN
from server.api.schemas.keys import ApiKeyCreate, ApiKeyCreated, ApiKeyList, ApiKeyRead
from server.api.schemas.pages import CREATED, encode_cursor
from server.services import auth, revocations
from server.storage.models import ApiKey

router = APIRouter(
    prefix="/v1/keys", tags=["keys"], dependencies=[GlobalAdminDep], route_class=GatedRoute
)
KeyPath = Annotated[str, Path(pattern=ID_PATTERN)]
KeyPage = Annotated[PageQuery, page_query("keys", CREATED)]


def read(row: ApiKey) -> ApiKeyRead:
    return ApiKeyRead(
        id=row.id,
        name=row.name,
        scopes=row.scopes.split(),
        site_id=row.site_id,
        created_at=row.created_at,
        rotated_at=row.rotated_at,
        revoked_at=row.revoked_at,
    )


def created(row: ApiKey, key: str) -> ApiKeyCreated:
    return ApiKeyCreated(**read(row).model_dump(), key=key)


@router.post("", status_code=status.HTTP_201_CREATED)
async def create_key(body: ApiKeyCreate, s: SqlDep) -> ApiKeyCreated:
    row, key = await auth.create_key(s, body.name, body.scopes, body.site_id)
    return created(row, key)


@router.get("")
async def list_keys(
    s: SqlDep,
    page: KeyPage,
    include_revoked: Annotated[bool, Query(description="revoked keys too")] = False,
) -> ApiKeyList:
    """Keys newest first (never their secrets)."""
    found = await auth.key_page(s, include_revoked, page.after, page.limit)
    items = [read(row) for row in found.rows]
    cursor = encode_cursor("keys", found.next_key) if found.next_key is not None else None
    return ApiKeyList(items=items, count=len(items), next_cursor=cursor)


@router.delete("/{key_id}", status_code=status.HTTP_204_NO_CONTENT)
async def revoke_key(key_id: KeyPath, rt: RuntimeDep) -> Response:
    """Revoke the key: it stops working at once, and the live sockets it opened are
    closed (code 4401) within a second, on every replica. Its row stays, for the record
    (listed with include_revoked); a revoked key cannot be rotated or revoked again
    (404). The keys of a site also go when the site is deleted."""
    await revocations.revoke_key(rt, key_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/{key_id}:rotate")
async def rotate_key(key_id: KeyPath, rt: RuntimeDep) -> ApiKeyCreated:
    """A new secret for the key (same id, scopes and site); the old one stops working,
    and the live sockets it opened are closed (code 4401) within a second."""
    row, key = await revocations.rotate_key(rt, key_id)
    return created(row, key)
