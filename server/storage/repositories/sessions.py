"""Session records, and the batches a contributing session keeps for the map builder."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import func, or_, select, update
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import SessionContribution, SessionRecord, utcnow
from server.storage.repositories.pages import Key, Page, keyset_page


async def create_session_record(s: AsyncSession, record: SessionRecord) -> None:
    s.add(record)
    await s.flush()


async def get_session_record(s: AsyncSession, session_id: str) -> SessionRecord | None:
    return await s.get(SessionRecord, session_id)


def _active(since: datetime) -> Any:
    return (SessionRecord.ended_at.is_(None)) & (SessionRecord.last_active_at >= since)


async def session_page(
    s: AsyncSession,
    site_id: str | None,
    active_since: datetime,
    active: bool | None,
    after: Key | None,
    limit: int,
) -> Page[SessionRecord]:
    """Session rows newest first (of one site, when given); with ``active``, only those
    that are (True) or are not (False) active: not ended and active since
    ``active_since``."""
    stmt = select(SessionRecord)
    if site_id is not None:
        stmt = stmt.where(SessionRecord.site_id == site_id)
    if active is True:
        stmt = stmt.where(_active(active_since))
    elif active is False:
        stmt = stmt.where(
            or_(SessionRecord.ended_at.is_not(None), SessionRecord.last_active_at < active_since)
        )
    columns = (SessionRecord.created_at, SessionRecord.id)
    return await keyset_page(s, stmt, columns, after, limit, descending=True)


async def active_sessions(
    s: AsyncSession, site_id: str, since: datetime, limit: int
) -> tuple[int, list[str]]:
    """How many of the site's sessions are active (not ended, active since ``since``),
    and the ids of the newest ``limit`` of them."""
    where = (SessionRecord.site_id == site_id) & _active(since)
    n = await s.scalar(select(func.count()).select_from(SessionRecord).where(where))
    stmt = (
        select(SessionRecord.id)
        .where(where)
        .order_by(SessionRecord.created_at.desc(), SessionRecord.id.desc())
        .limit(limit)
    )
    return int(n or 0), list((await s.scalars(stmt)).all())


async def set_session_epoch(s: AsyncSession, session_id: str, epoch: str) -> None:
    """The session lives in this epoch now, and was active just now."""
    await s.execute(
        update(SessionRecord)
        .where(SessionRecord.id == session_id)
        .values(epoch=epoch, last_active_at=utcnow())
    )


async def touch_session_record(s: AsyncSession, session_id: str) -> None:
    await s.execute(
        update(SessionRecord).where(SessionRecord.id == session_id).values(last_active_at=utcnow())
    )


async def end_session_record(s: AsyncSession, session_id: str) -> None:
    await s.execute(
        update(SessionRecord).where(SessionRecord.id == session_id).values(ended_at=utcnow())
    )


async def keep_session_batch(s: AsyncSession, session_id: str, seq: int, payload: bytes) -> None:
    """Keep a contributing session's batch (once per seq: a retry finds it there)."""
    exists = await s.get(SessionContribution, (session_id, seq))
    if exists is None:
        s.add(SessionContribution(session_id=session_id, seq=seq, payload=payload))
        await s.flush()


async def take_session_batches(s: AsyncSession, session_id: str) -> list[bytes]:
    """A session's kept batches in seq order, removed from the table."""
    stmt = (
        select(SessionContribution)
        .where(SessionContribution.session_id == session_id)
        .order_by(SessionContribution.seq)
    )
    rows = list((await s.scalars(stmt)).all())
    for row in rows:
        await s.delete(row)
    return [row.payload for row in rows]
