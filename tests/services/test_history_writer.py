"""The history's writer: the batch path only appends; a flush writes everything in one
transaction, keeps what a failed one could not write (within its bound), and the last
flush comes when it is closed."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import anyio
import pytest
from fastapi import FastAPI
from sqlalchemy.ext.asyncio import AsyncSession

from server.services.history_writer import HistoryWriter
from server.services.runtime import Runtime
from server.storage.repositories import history as repo

T0 = 1_700_000_000_000


def fixes(*times: int) -> list[dict[str, Any]]:
    return [{"t": t} for t in times]


@asynccontextmanager
async def unavailable() -> AsyncIterator[AsyncSession]:
    raise ConnectionError("SQL is down")
    yield  # pragma: no cover


async def test_a_failed_flush_keeps_its_rows_within_the_bound() -> None:
    writer = HistoryWriter(max_rows=3)
    writer.record("s" * 32, 1, "site", fixes(T0), b"[]")
    writer.record("s" * 32, 2, "site", [], b"[]")  # a batch without fixes: nothing to keep
    assert writer.pending == 1
    with pytest.raises(ConnectionError):
        await writer.flush(unavailable)
    assert writer.pending == 1
    for seq in (3, 4, 5):
        writer.record("s" * 32, seq, "site", fixes(T0 + seq), b"[]")
    with pytest.raises(ConnectionError):
        await writer.flush(unavailable)
    assert (writer.pending, writer.dropped) == (3, 1)  # the oldest went


def test_a_disabled_writer_keeps_nothing() -> None:
    writer = HistoryWriter(enabled=False)
    writer.record("s" * 32, 1, "site", fixes(T0), b"[]")
    assert writer.pending == 0


async def test_closing_flushes_what_waits_and_run_returns(app: FastAPI) -> None:
    rt: Runtime = app.state.runtime
    writer = HistoryWriter()
    session_id = "c" * 32
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.run, rt.transaction)
        writer.record(session_id, 1, "site", fixes(T0 + 5, T0), b'[{"t":1},{"t":2}]')
        writer.close()
    assert writer.pending == 0
    async with rt.read() as s:
        assert await repo.fixes_after(s, session_id, 0, 10) == [(1, b'[{"t":1},{"t":2}]')]
