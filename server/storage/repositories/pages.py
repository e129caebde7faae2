"""Keyset pagination: a page of rows after a key, in the order of that key.

A list is ordered by a unique key (say ``(created_at, id)``); a page holds the first
``limit`` rows past the last key the previous page ended on. Unlike an offset, a key
stays right while rows are added or removed between two pages, and the database reads
no rows it skips.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from sqlalchemy import ColumnElement, Select, and_, or_
from sqlalchemy.ext.asyncio import AsyncSession
from sqlalchemy.orm import InstrumentedAttribute

T = TypeVar("T")
Key = tuple[Any, ...]


@dataclass(frozen=True)
class Page(Generic[T]):
    rows: list[T]
    next_key: Key | None  # the key of the last row when more rows follow it, else None


def _past(columns: Sequence[InstrumentedAttribute[Any]], key: Key, descending: bool) -> Any:
    """Rows whose key comes after ``key`` in the list's order: the row-value comparison
    ``(a, b) > (x, y)`` written out, which every backend reads the same way."""
    clauses: list[ColumnElement[bool]] = []
    for i, column in enumerate(columns):
        equal = [c == v for c, v in zip(columns[:i], key[:i], strict=True)]
        beyond = column < key[i] if descending else column > key[i]
        clauses.append(and_(*equal, beyond))
    return or_(*clauses)


async def keyset_page(
    s: AsyncSession,
    stmt: Select[tuple[T]],
    columns: Sequence[InstrumentedAttribute[Any]],
    after: Key | None,
    limit: int,
    *,
    descending: bool = False,
) -> Page[T]:
    """The rows of ``stmt`` (one entity per row) ordered by ``columns`` (a unique key;
    newest first with ``descending``), the first ``limit`` of them past ``after``."""
    if after is not None:
        if len(after) != len(columns):
            raise ValueError(f"a key of {len(columns)} values, not {len(after)}")
        stmt = stmt.where(_past(columns, after, descending))
    order = [c.desc() if descending else c.asc() for c in columns]
    rows = list((await s.scalars(stmt.order_by(*order).limit(limit + 1))).all())
    if len(rows) <= limit:
        return Page(rows, None)
    last = rows[limit - 1]
    return Page(rows[:limit], tuple(getattr(last, c.key) for c in columns))
