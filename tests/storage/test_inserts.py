"""Insert-or-ignore over many rows counts the new ones, on SQLite and on PostgreSQL alike,
past SQLite's limit of parameters in one statement."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

from fastapi import FastAPI
from sqlalchemy import delete, func, select

from server.services.runtime import Runtime
from server.storage.inserts import insert_ignoring
from server.storage.models import SessionFixes

KEY = ("session_id", "seq")


def rows(session_id: str, seqs: range, fixes: bytes = b"[]") -> list[dict[str, Any]]:
    made = datetime.now(UTC)
    return [
        {
            "session_id": session_id,
            "seq": seq,
            "site_id": "f" * 32,
            "t_first_ms": 0,
            "t_last_ms": 0,
            "n_fixes": 0,
            "fixes": fixes,
            "created_at": made,
        }
        for seq in seqs
    ]


async def test_the_rows_new_are_counted_and_those_there_are_left(app: FastAPI) -> None:
    rt: Runtime = app.state.runtime
    sid = uuid.uuid4().hex
    async with rt.transaction() as s:
        assert await insert_ignoring(s, SessionFixes, [], KEY) == 0
        assert await insert_ignoring(s, SessionFixes, rows(sid, range(1, 3), b"[1]"), KEY) == 2
    async with rt.transaction() as s:
        # 2 is there; 3 comes twice: the first is kept
        again = rows(sid, range(2, 4), b"[2]") + rows(sid, range(3, 4), b"[3]")
        assert await insert_ignoring(s, SessionFixes, again, KEY) == 1
    async with rt.read() as s:
        kept = select(SessionFixes.seq, SessionFixes.fixes).where(SessionFixes.session_id == sid)
        assert [tuple(row) for row in await s.execute(kept.order_by(SessionFixes.seq))] == [
            (1, b"[1]"),
            (2, b"[1]"),
            (3, b"[2]"),
        ]


async def test_more_parameters_than_one_sqlite_statement_takes(app: FastAPI) -> None:
    rt: Runtime = app.state.runtime
    sid = uuid.uuid4().hex
    many = rows(sid, range(1, 5001))  # 8 columns: 40,000 parameters, SQLite takes 32,766
    try:
        async with rt.transaction() as s:
            assert await insert_ignoring(s, SessionFixes, many, KEY) == 5000
        async with rt.transaction() as s:
            assert await insert_ignoring(s, SessionFixes, many[-10:], KEY) == 0
        async with rt.read() as s:
            n = select(func.count()).where(SessionFixes.session_id == sid)
            assert await s.scalar(n) == 5000
    finally:
        async with rt.transaction() as s:
            await s.execute(delete(SessionFixes).where(SessionFixes.session_id == sid))
