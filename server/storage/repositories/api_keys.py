"""API keys (stored as hashes)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import ApiKey, utcnow
from server.storage.repositories.pages import Key, Page, keyset_page


async def create_api_key(
    s: AsyncSession, name: str, key_hash: str, scopes: str = "admin", site_id: str | None = None
) -> ApiKey:
    key = ApiKey(name=name, key_hash=key_hash, scopes=scopes, site_id=site_id)
    s.add(key)
    await s.flush()
    return key


async def find_api_key(s: AsyncSession, key_hash: str) -> ApiKey | None:
    stmt = select(ApiKey).where(ApiKey.key_hash == key_hash, ApiKey.revoked_at.is_(None))
    return (await s.scalars(stmt)).one_or_none()


async def get_api_key(s: AsyncSession, key_id: str) -> ApiKey | None:
    return await s.get(ApiKey, key_id)


async def list_api_keys(s: AsyncSession, include_revoked: bool = False) -> Sequence[ApiKey]:
    stmt = select(ApiKey).order_by(ApiKey.created_at, ApiKey.id)
    if not include_revoked:
        stmt = stmt.where(ApiKey.revoked_at.is_(None))
    return (await s.scalars(stmt)).all()


async def api_key_page(
    s: AsyncSession, include_revoked: bool, after: Key | None, limit: int
) -> Page[ApiKey]:
    """Keys newest first (live ones only unless ``include_revoked``)."""
    stmt = select(ApiKey)
    if not include_revoked:
        stmt = stmt.where(ApiKey.revoked_at.is_(None))
    return await keyset_page(s, stmt, (ApiKey.created_at, ApiKey.id), after, limit, descending=True)


async def revoke_api_key(s: AsyncSession, key: ApiKey) -> None:
    key.revoked_at = utcnow()
    await s.flush()


async def rotate_api_key(s: AsyncSession, key: ApiKey, key_hash: str) -> None:
    key.key_hash = key_hash
    key.rotated_at = utcnow()
    await s.flush()


async def live_key_hashes(s: AsyncSession, key_ids: Iterable[str]) -> set[tuple[str, str]]:
    """``(id, key_hash)`` of each of ``key_ids`` that is not revoked (nor deleted)."""
    stmt = select(ApiKey.id, ApiKey.key_hash).where(
        ApiKey.id.in_(list(key_ids)), ApiKey.revoked_at.is_(None)
    )
    return {(row.id, row.key_hash) for row in await s.execute(stmt)}
