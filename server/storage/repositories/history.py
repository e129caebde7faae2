"""Sessions' history: the fixes of each applied batch (``SessionFixes``), written in bulk,
read back in seq order, deleted by age."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime
from typing import Any

from sqlalchemy import Table, delete, select
from sqlalchemy.dialects.postgresql import insert as postgresql_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import SessionFixes

KEY = ("session_id", "seq")


async def keep_fixes(s: AsyncSession, rows: Sequence[Mapping[str, Any]]) -> None:
    """Insert rows of ``session_fixes`` (column name -> value) in one statement run over
    all of them; a row whose (session_id, seq) is there already is left as it is."""
    if not rows:
        return
    dialect = s.get_bind().dialect.name
    insert = postgresql_insert if dialect == "postgresql" else sqlite_insert
    table = SessionFixes.__table__
    assert isinstance(table, Table)
    # Core, not the ORM's bulk insert: one executemany of a plain INSERT ... ON CONFLICT
    await s.execute(insert(table).on_conflict_do_nothing(index_elements=KEY), list(rows))


async def fixes_after(
    s: AsyncSession, session_id: str, after_seq: int, limit: int
) -> list[tuple[int, bytes]]:
    """(seq, fixes) of the session's first ``limit`` batches past ``after_seq``, in seq
    order; ``fixes`` is the batch's JSON array of fixes."""
    stmt = (
        select(SessionFixes.seq, SessionFixes.fixes)
        .where(SessionFixes.session_id == session_id, SessionFixes.seq > after_seq)
        .order_by(SessionFixes.seq)
        .limit(limit)
    )
    return [(seq, fixes) for seq, fixes in (await s.execute(stmt)).all()]


async def delete_fixes(s: AsyncSession, made_before: datetime | None) -> int:
    """Delete the batches written before ``made_before`` (None: all of them); how many."""
    stmt = delete(SessionFixes).execution_options(synchronize_session=False)
    if made_before is not None:
        stmt = stmt.where(SessionFixes.created_at < made_before)
    gone = await s.execute(stmt)
    return int(gone.rowcount or 0)  # type: ignore[attr-defined]
