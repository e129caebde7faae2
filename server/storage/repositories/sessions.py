"""Session records, and the batches a contributing session keeps for the map builder."""

from __future__ import annotations

from sqlalchemy import select, update
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import SessionContribution, SessionRecord, utcnow


async def create_session_record(s: AsyncSession, record: SessionRecord) -> None:
    s.add(record)
    await s.flush()


async def get_session_record(s: AsyncSession, session_id: str) -> SessionRecord | None:
    return await s.get(SessionRecord, session_id)


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
