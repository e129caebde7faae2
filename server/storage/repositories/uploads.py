"""Uploads: the rows the upload pipeline settles."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import Upload
from server.storage.repositories.pages import Key, Page, keyset_page


async def create_upload(s: AsyncSession, **fields: Any) -> Upload:
    row = Upload(**fields)
    s.add(row)
    await s.flush()
    return row


async def get_upload(s: AsyncSession, upload_id: str) -> Upload | None:
    return await s.get(Upload, upload_id)


async def upload_page(
    s: AsyncSession,
    site_id: str | None,
    status: str | None,
    after: Key | None,
    limit: int,
) -> Page[Upload]:
    """Uploads newest first (of one site, in one status, when given)."""
    stmt = select(Upload)
    if site_id is not None:
        stmt = stmt.where(Upload.site_id == site_id)
    if status is not None:
        stmt = stmt.where(Upload.status == status)
    return await keyset_page(s, stmt, (Upload.created_at, Upload.id), after, limit, descending=True)


async def find_upload_by_key(s: AsyncSession, key: str) -> Upload | None:
    return (await s.scalars(select(Upload).where(Upload.idempotency_key == key))).one_or_none()


async def lock_upload(s: AsyncSession, upload_id: str) -> Upload | None:
    """The upload row, locked until the transaction ends (one worker settles it)."""
    stmt = select(Upload).where(Upload.id == upload_id).with_for_update()
    return (await s.scalars(stmt)).one_or_none()


async def upload_ids(
    s: AsyncSession, statuses: Sequence[str], untouched_since: datetime
) -> list[str]:
    """Uploads in one of ``statuses`` whose row has not changed since the given time."""
    stmt = (
        select(Upload.id)
        .where(Upload.status.in_(statuses), Upload.updated_at <= untouched_since)
        .order_by(Upload.created_at)
    )
    return list((await s.scalars(stmt)).all())
