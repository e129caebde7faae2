"""Sessions' history: the fixes of each applied batch (``SessionFixes``), written in bulk,
read back in seq order (within a window of fix times, when asked), deleted by age."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import ColumnElement, delete, func, select, tuple_
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.inserts import insert_ignoring
from server.storage.models import SessionFixes

KEY = ("session_id", "seq")


@dataclass(frozen=True, slots=True)
class BatchHead:
    """What a page needs to know of a kept batch before it reads its fixes."""

    seq: int
    n_fixes: int
    t_first_ms: int
    t_last_ms: int
    created_at: datetime


@dataclass(frozen=True, slots=True)
class Window:
    """Fix times wanted, ms since the epoch, both ends included (None: open)."""

    from_ms: int | None = None
    to_ms: int | None = None

    def has(self, t_ms: int) -> bool:
        """Whether time ``t_ms`` lies in the window."""
        return self.holds(t_ms, t_ms)

    def holds(self, first_ms: int, last_ms: int) -> bool:
        """Whether every time from ``first_ms`` to ``last_ms`` lies in the window."""
        return (self.from_ms is None or first_ms >= self.from_ms) and (
            self.to_ms is None or last_ms <= self.to_ms
        )


async def keep_fixes(s: AsyncSession, rows: Sequence[Mapping[str, Any]]) -> int:
    """Insert rows of ``session_fixes`` (column name -> value); a row whose (session_id,
    seq) is there already is left as it is. How many were new."""
    return await insert_ignoring(s, SessionFixes, rows, KEY)


def _batches(session_id: str, after_seq: int, window: Window) -> list[ColumnElement[bool]]:
    """The conditions on the session's batches past ``after_seq`` with a fix in
    ``window``."""
    where = [SessionFixes.session_id == session_id, SessionFixes.seq > after_seq]
    if window.from_ms is not None:
        where.append(SessionFixes.t_last_ms >= window.from_ms)
    if window.to_ms is not None:
        where.append(SessionFixes.t_first_ms <= window.to_ms)
    return where


async def batch_heads(
    s: AsyncSession, session_id: str, after_seq: int, window: Window, limit: int
) -> list[BatchHead]:
    """The session's first ``limit`` batches past ``after_seq`` (with a fix in
    ``window``), in seq order, without their fixes."""
    columns = (
        SessionFixes.seq,
        SessionFixes.n_fixes,
        SessionFixes.t_first_ms,
        SessionFixes.t_last_ms,
        SessionFixes.created_at,
    )
    stmt = select(*columns).where(*_batches(session_id, after_seq, window))
    rows = (await s.execute(stmt.order_by(SessionFixes.seq).limit(limit))).all()
    return [BatchHead(*row) for row in rows]


async def fixes_of(
    s: AsyncSession, session_id: str, after_seq: int, window: Window, limit: int
) -> list[tuple[int, bytes]]:
    """(seq, fixes) of the session's first ``limit`` batches past ``after_seq`` (with a
    fix in ``window``), in seq order; ``fixes`` is the batch's JSON array of fixes."""
    stmt = select(SessionFixes.seq, SessionFixes.fixes).where(
        *_batches(session_id, after_seq, window)
    )
    rows = (await s.execute(stmt.order_by(SessionFixes.seq).limit(limit))).all()
    return [(seq, fixes) for seq, fixes in rows]


async def fixes_between(
    s: AsyncSession, session_id: str, first_seq: int, last_seq: int
) -> list[tuple[int, bytes]]:
    """(seq, fixes) of the session's batches from ``first_seq`` to ``last_seq``, in seq
    order."""
    stmt = (
        select(SessionFixes.seq, SessionFixes.fixes)
        .where(SessionFixes.session_id == session_id)
        .where(SessionFixes.seq >= first_seq, SessionFixes.seq <= last_seq)
        .order_by(SessionFixes.seq)
    )
    return [(seq, fixes) for seq, fixes in (await s.execute(stmt)).all()]


async def seq_before(s: AsyncSession, session_id: str, seq: int, after_seq: int) -> int:
    """The seq of the session's last batch kept before ``seq`` and past ``after_seq``
    (``after_seq`` when none is)."""
    stmt = select(func.max(SessionFixes.seq)).where(
        SessionFixes.session_id == session_id,
        SessionFixes.seq > after_seq,
        SessionFixes.seq < seq,
    )
    found = await s.scalar(stmt)
    return after_seq if found is None else int(found)


async def count_fixes(s: AsyncSession, session_id: str, window: Window) -> int:
    """The fixes of the session's batches with a fix in ``window`` (those of the batches
    across its ends all counted)."""
    stmt = select(func.sum(SessionFixes.n_fixes)).where(*_batches(session_id, 0, window))
    return int(await s.scalar(stmt) or 0)


async def delete_fixes(s: AsyncSession, made_before: datetime | None, limit: int) -> int:
    """Delete at most ``limit`` of the batches written before ``made_before`` (None: of
    all of them), the oldest first; how many."""
    oldest = select(SessionFixes.session_id, SessionFixes.seq)
    if made_before is not None:
        oldest = oldest.where(SessionFixes.created_at < made_before)
    oldest = oldest.order_by(SessionFixes.created_at).limit(limit)
    stmt = (
        delete(SessionFixes)
        .where(tuple_(SessionFixes.session_id, SessionFixes.seq).in_(oldest))
        .execution_options(synchronize_session=False)
    )
    gone = await s.execute(stmt)
    return int(gone.rowcount or 0)  # type: ignore[attr-defined]
