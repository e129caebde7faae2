"""This process's way of keeping sessions' history (``session_fixes``) off the batch path.

A batch that was applied hands its fixes to ``HistoryWriter.record``, which appends them
to a list: no I/O, no await. ``HistoryWriter.run`` (started with the runtime,
``services.runtime.open_runtime``) writes what gathered about every ``FLUSH_S`` seconds,
sooner once ``flush_rows`` batches wait, and once more when it stops: an insert-or-ignore
statement over up to ``flush_rows`` batches a transaction (a batch applied again after its
session was rebuilt keeps the fixes written first for its seq). A reader of the history
flushes this process's rows first (``services.history``), so what a process answered it
also reads back. Measured: ``record`` costs a batch ~5 µs; a flush ~4 ms of CPU plus
~15-20 µs a batch (PostgreSQL or SQLite): about 2 % of a batch's CPU at 40 batches a
second, under 0.5 % at 400.

What a crash can lose: the batches applied by the process in its last flush interval
(about a second; they were answered, published live and kept in the session's track).

While SQL is unavailable a flush fails and keeps its rows; ``run`` then tries again after
``FLUSH_S``, doubling the wait up to ``MAX_BACKOFF_S`` whatever waits (only a flush that
worked lets a full buffer wake it early), and logs the outage once when it starts and once
when it ends. What waits is bounded by ``max_bytes`` of fixes: past it ``record`` drops the
new batch's fixes (counted in ``dropped``, logged when the outage ends), so a long outage
loses the history of its later batches.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import anyio
from sqlalchemy.ext.asyncio import AsyncSession

from server.storage.models import utcnow
from server.storage.repositories import history as repo

log = logging.getLogger(__name__)

FLUSH_S = 1.0
MAX_BACKOFF_S = 16.0  # the longest wait between flushes while SQL fails
FLUSH_ROWS = 500  # batches that make a flush start before its time
MAX_BYTES = 64 * 2**20  # fixes kept while SQL is unavailable (a batch's are 1-20 KB)
CLOSE_TIMEOUT_S = 10.0  # the last flush at shutdown gives up after this long

Transaction = Callable[[], AbstractAsyncContextManager[AsyncSession]]


@dataclass(frozen=True, slots=True)
class _Batch:
    session_id: str
    seq: int
    site_id: str
    t_first_ms: int
    t_last_ms: int
    n_fixes: int
    fixes: bytes  # the batch's answer: a JSON array of FixOut


def _values(row: _Batch, made: datetime) -> dict[str, Any]:
    return {
        "session_id": row.session_id,
        "seq": row.seq,
        "site_id": row.site_id,
        "t_first_ms": row.t_first_ms,
        "t_last_ms": row.t_last_ms,
        "n_fixes": row.n_fixes,
        "fixes": row.fixes,
        "created_at": made,
    }


class HistoryWriter:
    """Buffered, batched writes of applied batches' fixes (module docstring). Disabled
    (``enabled`` False: history kept for no time), ``record`` keeps nothing."""

    def __init__(
        self,
        enabled: bool = True,
        flush_rows: int = FLUSH_ROWS,
        max_bytes: int = MAX_BYTES,
        flush_s: float = FLUSH_S,
    ) -> None:
        self.enabled = enabled
        self.flush_rows = flush_rows
        self.max_bytes = max_bytes
        self.flush_s = flush_s
        self.dropped = 0  # batches lost to a long SQL outage
        self.pending_bytes = 0  # fixes not written yet, those of a flush under way included
        self._rows: list[_Batch] = []
        self._wake: anyio.Event | None = None
        self._lock: anyio.Lock | None = None
        self._closing = False
        self._failing = False  # the last flush of ``run`` failed: no early wake

    def record(
        self,
        session_id: str,
        seq: int,
        site_id: str,
        fixes: Sequence[Mapping[str, Any]],
        body: bytes,
    ) -> None:
        """Keep batch ``seq``'s ``fixes`` (FixOut dicts) and their JSON array ``body`` for
        the next flush; drop them (counted in ``dropped``) when ``max_bytes`` wait."""
        if not self.enabled or not fixes:
            return
        if self.pending_bytes + len(body) > self.max_bytes:
            self.dropped += 1
            return
        times = [f["t"] for f in fixes]
        self._rows.append(
            _Batch(session_id, seq, site_id, min(times), max(times), len(fixes), body)
        )
        self.pending_bytes += len(body)
        if len(self._rows) >= self.flush_rows and self._wake is not None and not self._failing:
            self._wake.set()

    @property
    def pending(self) -> int:
        """Batches waiting for the next flush (not those of a flush under way)."""
        return len(self._rows)

    async def flush(self, transaction: Transaction) -> int:
        """Write what waits, ``flush_rows`` batches a transaction (each takes the event
        loop for ~15 µs a batch, ~4 ms a transaction); how many batches. On failure the
        rows not written wait for the next flush, ahead of those recorded meanwhile, and
        the error is raised."""
        self._lock = self._lock or anyio.Lock()
        async with self._lock:
            rows, self._rows = self._rows, []
            made = utcnow()
            for start in range(0, len(rows), self.flush_rows):
                chunk = rows[start : start + self.flush_rows]
                try:
                    async with transaction() as s:
                        await repo.keep_fixes(s, [_values(r, made) for r in chunk])
                except BaseException:
                    self._rows[:0] = rows[start:]
                    raise
                self.pending_bytes -= sum(len(r.fixes) for r in chunk)
            return len(rows)

    async def run(self, transaction: Transaction) -> None:
        """Flush every ``flush_s`` (sooner when ``flush_rows`` wait; later while SQL
        fails: module docstring) until ``close``; then once more, shielded from
        cancellation for up to ``CLOSE_TIMEOUT_S``."""
        wait_s = self.flush_s
        outage_since = 0.0  # time.monotonic() of the outage's first failure
        dropped_before = self.dropped  # the drops already logged
        try:
            while not self._closing:
                self._wake = anyio.Event()
                with anyio.move_on_after(wait_s):
                    await self._wake.wait()
                if self._closing:
                    break  # the last flush follows
                try:
                    await self.flush(transaction)
                except Exception:
                    if not self._failing:
                        self._failing, outage_since = True, time.monotonic()
                        log.warning(
                            "session history: SQL unavailable; keeping up to %g MB of fixes "
                            "and trying again",
                            self.max_bytes / 2**20,
                            exc_info=True,
                        )
                    wait_s = min(2 * wait_s, MAX_BACKOFF_S)
                    continue
                if self._failing:
                    log.warning(
                        "session history: SQL written to again after %.0f s; %d batches' "
                        "fixes were dropped meanwhile",
                        time.monotonic() - outage_since,
                        self.dropped - dropped_before,
                    )
                elif self.dropped > dropped_before:
                    log.warning(
                        "session history: %d batches' fixes dropped (over %g MB waited)",
                        self.dropped - dropped_before,
                        self.max_bytes / 2**20,
                    )
                dropped_before = self.dropped
                self._failing, wait_s = False, self.flush_s
        finally:
            with anyio.CancelScope(shield=True), anyio.move_on_after(CLOSE_TIMEOUT_S):
                try:
                    await self.flush(transaction)
                except Exception:
                    log.exception(
                        "session history: last flush failed; %d batches lost", self.pending
                    )

    def close(self) -> None:
        """Make ``run`` flush once more and return."""
        self._closing = True
        if self._wake is not None:
            self._wake.set()
