"""The session store in memory (embedded mode, tests): ``session_store`` says what it
keeps and promises."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import AsyncIterator, Callable, Sequence
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from dataclasses import dataclass, field

from server.storage.session_store import (
    Allowance,
    BucketEmpty,
    SessionExists,
    StoredSession,
    kept_fixes,
    key_ids,
    ttl_ms,
    write_payload,
)

MEMORY_QUEUE_SIZE = 1024  # messages a slow in-memory subscriber may fall behind by
MEMORY_SWEEP_INTERVAL_S = 60.0  # how often the in-memory store drops expired records
MEMORY_REVOKED_CHANNEL = "keys:revoked"  # no session id (32 hex digits) looks like it


@dataclass(slots=True)
class _Record:
    version: int
    meta: bytes
    state: bytes
    expires_at: float
    track: list[bytes] = field(default_factory=list)
    log: list[bytes] = field(default_factory=list)
    tokens: float | None = None  # the session's bucket (None: full, never taken from)
    tokens_at: float = 0.0


class _QueueMessages:
    """Iterator over one in-memory subscriber's queue; ends once the subscription closed."""

    def __init__(self, queue: asyncio.Queue[bytes]) -> None:
        self.queue = queue
        self.closed = False

    def __aiter__(self) -> _QueueMessages:
        return self

    async def __anext__(self) -> bytes:
        if self.closed:
            raise StopAsyncIteration
        return await self.queue.get()


class MemorySessionStore:
    """Sessions in a dict, for one process (embedded mode and tests).

    Every operation runs without an ``await`` between its read and its write, so it is
    atomic within the event loop. Expiry is checked on access against ``clock`` (default
    :func:`time.monotonic`); expired records are also swept out every
    ``MEMORY_SWEEP_INTERVAL_S`` so abandoned sessions do not pile up.

    Each subscriber has its own bounded queue of ``queue_size`` messages. A subscriber that
    falls that far behind loses its *oldest* queued messages: publishers never block and
    never fail because of a slow reader.
    """

    def __init__(
        self,
        *,
        queue_size: int = MEMORY_QUEUE_SIZE,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size must be at least 1, got {queue_size}")
        self._queue_size = queue_size
        self._clock = clock
        self._records: dict[str, _Record] = {}
        self._subscribers: dict[str, set[asyncio.Queue[bytes]]] = {}  # by channel
        self._next_sweep = clock() + MEMORY_SWEEP_INTERVAL_S
        self._epoch = uuid.uuid4().hex  # a new process starts with a new, empty dict

    def _live(self, session_id: str) -> _Record | None:
        now = self._clock()
        if now >= self._next_sweep:
            self._records = {k: r for k, r in self._records.items() if r.expires_at > now}
            self._next_sweep = now + MEMORY_SWEEP_INTERVAL_S
        record = self._records.get(session_id)
        if record is not None and record.expires_at <= now:
            del self._records[session_id]
            return None
        return record

    async def create(
        self, session_id: str, meta: bytes, state: bytes, ttl_s: int, version: int = 1
    ) -> None:
        ttl_ms(ttl_s)
        if self._live(session_id) is not None:
            raise SessionExists(session_id)
        self._records[session_id] = _Record(
            version, bytes(meta), bytes(state), self._clock() + ttl_s
        )

    async def get(self, session_id: str) -> StoredSession | None:
        record = self._live(session_id)
        if record is None:
            return None
        return StoredSession(record.version, record.meta, record.state, tuple(record.log))

    async def get_changed(self, session_id: str, known_version: int) -> StoredSession | int | None:
        record = self._live(session_id)
        if record is None:
            return None
        if record.version == known_version:
            return known_version
        return StoredSession(record.version, record.meta, record.state, tuple(record.log))

    async def compare_and_set(
        self,
        session_id: str,
        expected_version: int,
        state: bytes | None,
        ttl_s: int,
        publish: bytes | None = None,
        track: Sequence[bytes] = (),
        track_len: int = 0,
        allowance: Allowance | None = None,
        entry: bytes | None = None,
    ) -> bool:
        ttl_ms(ttl_s)
        written = write_payload(state, entry)
        record = self._live(session_id)
        if record is None or record.version != expected_version:
            return False
        if allowance is not None:
            self._take(record, allowance)
        if state is not None:
            record.state, record.log = written, []
        else:
            record.log.append(written)
        record.version += 1
        record.expires_at = self._clock() + ttl_s
        if kept := kept_fixes(track, track_len):
            record.track.extend(kept)
            del record.track[:-track_len]
        if publish is not None:
            await self.publish(session_id, publish)
        return True

    def _take(self, record: _Record, allowance: Allowance) -> None:
        now = self._clock()
        held = allowance.burst if record.tokens is None else record.tokens
        tokens = min(allowance.burst, held + max(0.0, now - record.tokens_at) * allowance.per_s)
        if tokens < 1:
            raise BucketEmpty((1 - tokens) / allowance.per_s)
        record.tokens, record.tokens_at = tokens - 1, now

    async def track(self, session_id: str, limit: int) -> list[bytes]:
        record = self._live(session_id)
        return record.track[-limit:] if record is not None and limit > 0 else []

    async def delete(self, session_id: str) -> bool:
        existed = self._live(session_id) is not None
        self._records.pop(session_id, None)
        return existed

    async def publish(self, session_id: str, message: bytes) -> None:
        message = bytes(message)
        for queue in self._subscribers.get(session_id, ()):
            if queue.full():
                queue.get_nowait()  # drop the oldest rather than block the publisher
            queue.put_nowait(message)

    @asynccontextmanager
    async def _subscription(self, channel: str) -> AsyncIterator[_QueueMessages]:
        queue: asyncio.Queue[bytes] = asyncio.Queue(self._queue_size)
        subscribers = self._subscribers.setdefault(channel, set())
        subscribers.add(queue)
        messages = _QueueMessages(queue)
        try:
            yield messages
        finally:
            messages.closed = True
            subscribers.discard(queue)
            if not subscribers:
                self._subscribers.pop(channel, None)

    def subscribe(self, session_id: str) -> AbstractAsyncContextManager[AsyncIterator[bytes]]:
        return self._subscription(session_id)

    async def publish_revoked(self, key_id: str) -> None:
        await self.publish(MEMORY_REVOKED_CHANNEL, key_id.encode())

    @asynccontextmanager
    async def _revoked(self) -> AsyncIterator[AsyncIterator[str]]:
        async with self._subscription(MEMORY_REVOKED_CHANNEL) as messages:
            yield key_ids(messages)

    def subscribe_revoked(self) -> AbstractAsyncContextManager[AsyncIterator[str]]:
        return self._revoked()

    async def epoch(self) -> str:
        return self._epoch

    async def ping(self) -> None:
        return None

    async def close(self) -> None:
        self._records.clear()
