"""The history's writer: the batch path only appends, within a bound in bytes; a flush
writes in chunks of ``flush_rows`` and keeps what it could not write; ``run`` flushes on
its timer, early when enough waits, slowly while SQL fails (logging the outage once), and
once more when it is closed or cancelled."""

from __future__ import annotations

import logging
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import anyio
import pytest
from fastapi import FastAPI
from sqlalchemy.ext.asyncio import AsyncSession

from server.services.history_writer import HistoryWriter, Transaction
from server.services.runtime import Runtime
from server.storage.repositories import history as repo
from server.storage.repositories.history import Window

T0 = 1_700_000_000_000
SITE = "f" * 32


def fixes(*times: int) -> list[dict[str, Any]]:
    return [{"t": t} for t in times]


def body(seq: int) -> bytes:
    return b'[{"t":%d}]' % (T0 + seq)


def new_session() -> str:
    return uuid.uuid4().hex


@pytest.fixture
def rt(app: FastAPI) -> Runtime:
    runtime: Runtime = app.state.runtime
    return runtime


@asynccontextmanager
async def unavailable() -> AsyncIterator[AsyncSession]:
    raise ConnectionError("SQL is down")
    yield  # pragma: no cover


def failing_after(transaction: Transaction, works: int) -> Transaction:
    """``transaction``, which fails from its ``works`` + 1-th opening on."""
    opened = 0

    @asynccontextmanager
    async def flaky() -> AsyncIterator[AsyncSession]:
        nonlocal opened
        opened += 1
        if opened > works:
            raise ConnectionError("SQL is down")
        async with transaction() as s:
            yield s

    return flaky


async def kept(rt: Runtime, session_id: str) -> list[int]:
    """The seqs of the session in SQL, read without flushing anything."""
    async with rt.read() as s:
        return [seq for seq, _ in await repo.fixes_of(s, session_id, 0, Window(), 100)]


async def written(rt: Runtime, session_id: str, seqs: list[int]) -> None:
    """Wait (at most 5 s) until the session's seqs in SQL are ``seqs``."""
    with anyio.fail_after(5.0):
        while True:
            if await kept(rt, session_id) == seqs:
                return
            await anyio.sleep(0.01)


async def test_the_bound_is_in_bytes_and_a_failed_flush_keeps_its_rows() -> None:
    writer = HistoryWriter(max_bytes=3 * len(body(1)))
    writer.record("s" * 32, 1, "site", fixes(T0 + 1), body(1))
    writer.record("s" * 32, 2, "site", [], b"[]")  # a batch without fixes: nothing to keep
    assert (writer.pending, writer.pending_bytes) == (1, len(body(1)))
    with pytest.raises(ConnectionError):
        await writer.flush(unavailable)
    assert (writer.pending, writer.pending_bytes) == (1, len(body(1)))
    for seq in (3, 4, 5):
        writer.record("s" * 32, seq, "site", fixes(T0 + seq), body(seq))
    # the third batch would pass the bound: the newest is dropped, the rows stay in order
    assert (writer.pending, writer.dropped, writer.pending_bytes) == (3, 1, 3 * len(body(1)))
    with pytest.raises(ConnectionError):
        await writer.flush(unavailable)
    assert [row.seq for row in writer._rows] == [1, 3, 4]


def test_a_disabled_writer_keeps_nothing() -> None:
    writer = HistoryWriter(enabled=False)
    writer.record("s" * 32, 1, "site", fixes(T0), b"[]")
    assert writer.pending == 0


async def test_run_flushes_on_its_timer(rt: Runtime) -> None:
    writer = HistoryWriter(flush_s=0.05)
    sid = new_session()
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.run, rt.transaction)
        writer.record(sid, 1, SITE, fixes(T0), body(1))  # far fewer than flush_rows
        await written(rt, sid, [1])
        writer.record(sid, 2, SITE, fixes(T0 + 1), body(2))
        await written(rt, sid, [1, 2])
        writer.close()


async def test_flush_rows_waiting_wake_run_before_its_time(rt: Runtime) -> None:
    writer = HistoryWriter(flush_rows=2, flush_s=60.0)
    sid = new_session()
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.run, rt.transaction)
        await anyio.sleep(0.01)  # run waits
        writer.record(sid, 1, SITE, fixes(T0), body(1))
        await anyio.sleep(0.1)
        assert await kept(rt, sid) == []  # one row waits: no wake
        writer.record(sid, 2, SITE, fixes(T0 + 1), body(2))
        await written(rt, sid, [1, 2])  # long before flush_s
        writer.close()


async def test_while_sql_fails_run_waits_and_logs_the_outage_once(
    rt: Runtime, caplog: pytest.LogCaptureFixture
) -> None:
    writer = HistoryWriter(flush_rows=1, max_bytes=5 * len(body(1)), flush_s=0.1)
    sid = new_session()
    down = True
    attempts = 0

    @asynccontextmanager
    async def flaky() -> AsyncIterator[AsyncSession]:
        nonlocal attempts
        attempts += 1
        if down:
            raise ConnectionError("SQL is down")
        async with rt.transaction() as s:
            yield s

    caplog.set_level(logging.WARNING, logger="server.services.history_writer")
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.run, flaky)
        await anyio.sleep(0.01)
        for seq in range(1, 201):  # each one a wake, were SQL up
            writer.record(sid, seq, SITE, fixes(T0 + seq), body(seq))
            await anyio.sleep(0.001)
        # the first record woke it; then 0.2 s, 0.4 s, ... between attempts
        assert 1 <= attempts <= 3, attempts
        assert (writer.pending_bytes, writer.dropped) == (5 * len(body(1)), 195)
        down = False
        await written(rt, sid, [1, 2, 3, 4, 5])
        writer.close()
    messages = [
        r.getMessage() for r in caplog.records if r.name == "server.services.history_writer"
    ]
    assert len(messages) == 2, messages
    assert "SQL unavailable" in messages[0]
    assert "195 batches' fixes were dropped" in messages[1]


async def test_rows_recorded_during_a_flush_wait_for_the_next(rt: Runtime) -> None:
    writer = HistoryWriter()
    sid = new_session()
    inside, release = anyio.Event(), anyio.Event()

    @asynccontextmanager
    async def slow() -> AsyncIterator[AsyncSession]:
        async with rt.transaction() as s:
            inside.set()
            await release.wait()
            yield s

    writer.record(sid, 1, SITE, fixes(T0), body(1))
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.flush, slow)
        await inside.wait()
        writer.record(sid, 2, SITE, fixes(T0 + 1), body(2))
        # the batch being written still counts against the bound
        assert (writer.pending, writer.pending_bytes) == (1, len(body(1)) + len(body(2)))
        release.set()
    assert (writer.pending, writer.pending_bytes) == (1, len(body(2)))
    assert await kept(rt, sid) == [1]
    assert await writer.flush(rt.transaction) == 1
    assert await kept(rt, sid) == [1, 2]
    assert writer.pending_bytes == 0


async def test_a_chunk_that_fails_after_one_was_written_keeps_only_its_rows(
    rt: Runtime,
) -> None:
    writer = HistoryWriter(flush_rows=2)
    sid = new_session()
    for seq in (1, 2, 3):
        writer.record(sid, seq, SITE, fixes(T0 + seq), body(seq))
    with pytest.raises(ConnectionError):
        await writer.flush(failing_after(rt.transaction, works=1))
    assert await kept(rt, sid) == [1, 2]
    assert (writer.pending, writer.pending_bytes) == (1, len(body(3)))
    assert await writer.flush(rt.transaction) == 1
    assert await kept(rt, sid) == [1, 2, 3]


async def test_closing_flushes_what_waits_and_run_returns(rt: Runtime) -> None:
    writer = HistoryWriter(flush_s=60.0)
    sid = new_session()
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.run, rt.transaction)
        writer.record(sid, 1, SITE, fixes(T0 + 5, T0), b'[{"t":1},{"t":2}]')
        writer.close()
    assert writer.pending == 0
    async with rt.read() as s:
        assert await repo.fixes_of(s, sid, 0, Window(), 10) == [(1, b'[{"t":1},{"t":2}]')]
        (head,) = await repo.batch_heads(s, sid, 0, Window(), 10)
    assert (head.n_fixes, head.t_first_ms, head.t_last_ms) == (2, T0, T0 + 5)


async def test_a_cancelled_run_still_makes_its_last_flush(rt: Runtime) -> None:
    writer = HistoryWriter(flush_s=60.0)
    sid = new_session()
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(writer.run, rt.transaction)
        await anyio.sleep(0.01)  # run waits on its timer
        writer.record(sid, 1, SITE, fixes(T0), body(1))
        tasks.cancel_scope.cancel()  # the flush awaits SQL inside the cancelled scope
    assert await kept(rt, sid) == [1]
    assert writer.pending_bytes == 0
