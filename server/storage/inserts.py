"""``INSERT ... ON CONFLICT DO NOTHING`` over many rows, on PostgreSQL and SQLite alike.

The rows go as one statement run over a list of parameter sets, which SQLAlchemy pages
into multi-row VALUES within each driver's parameter limit (SQLite's 32,766 cannot be
reached however many rows come). New rows are counted from ``RETURNING`` of the key: the
``rowcount`` of a run over many parameter sets is -1 under asyncpg (the sum of the rows
written under sqlite3 and aiosqlite).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sqlalchemy import Table
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.ext.asyncio import AsyncSession
from sqlalchemy.orm import DeclarativeBase


async def insert_ignoring(
    s: AsyncSession,
    model: type[DeclarativeBase],
    rows: Sequence[Mapping[str, Any]],
    key_columns: Sequence[str],
) -> int:
    """Insert ``rows`` (column name -> value) into ``model``'s table, leaving out each row
    whose ``key_columns`` (a primary key or unique constraint) are there already, or came
    earlier in ``rows``; how many rows were new."""
    if not rows:
        return 0
    table = model.__table__
    assert isinstance(table, Table)
    dialect = s.get_bind().dialect.name
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    stmt = (
        insert(table)
        .on_conflict_do_nothing(index_elements=list(key_columns))
        .returning(*(table.c[name] for name in key_columns))
    )
    result = await s.execute(stmt, list(rows))
    return len(result.all())
