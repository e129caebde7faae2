"""The long-lived resources every service works with, built once per process."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field

import anyio
from sqlalchemy.ext.asyncio import AsyncEngine, AsyncSession, async_sessionmaker

from server.config import Settings
from server.services.errors import Conflict
from server.services.history_writer import HistoryWriter
from server.services.maps import MapCache
from server.services.revocations import KeyWatches
from server.services.session_cache import AnySessionCache, SessionCache
from server.storage import db
from server.storage.memory_session_store import MemorySessionStore
from server.storage.rate_limits import RateLimiter, make_rate_limiter
from server.storage.redis_client import redis_client
from server.storage.redis_session_store import RedisSessionStore
from server.storage.session_store import SessionStore
from server.storage.upload_queue import UploadQueue, make_upload_queue


@dataclass
class Runtime:
    settings: Settings
    engine: AsyncEngine
    sql: async_sessionmaker[AsyncSession]
    store: SessionStore
    maps: MapCache
    uploads: UploadQueue
    limits: RateLimiter

    # SQLite allows one writer; an embedded process takes turns rather than failing
    sqlite_lock: anyio.Lock | None = None
    # turns for applying batches (Settings.batch_concurrency; services.batches)
    batch_gate: anyio.Semaphore = field(default_factory=lambda: anyio.Semaphore(1))
    # decoded session records this process last wrote or read (services.session_cache)
    states: AnySessionCache = field(default_factory=lambda: SessionCache(0))
    # the live sockets opened with API keys, closed when their key stops working
    key_watches: KeyWatches = field(default_factory=KeyWatches)
    # applied batches' fixes on their way to SQL (services.history_writer): the app installs
    # one that keeps them and runs its flushes (``writing_history``); by default none are
    # kept (a runtime whose writer nobody runs would hold them for ever)
    history: HistoryWriter = field(default_factory=lambda: HistoryWriter(enabled=False))

    @asynccontextmanager
    async def read(self) -> AsyncIterator[AsyncSession]:
        """A SQL session for reading only: it takes no writer's turn (SQLite), so it can
        be opened while the same request holds a transaction; nothing it does is kept."""
        async with self.sql() as session:
            try:
                yield session
            finally:
                await session.rollback()

    @asynccontextmanager
    async def transaction(self) -> AsyncIterator[AsyncSession]:
        """A SQL session that commits on success and rolls back on error; a write that
        collides with an existing row is a Conflict."""
        async with contextlib.AsyncExitStack() as stack:
            if self.sqlite_lock is not None:
                await stack.enter_async_context(self.sqlite_lock)
            try:
                async with db.transaction(self.sql) as session:
                    yield session
            except db.Duplicate as exc:
                raise Conflict(
                    "this conflicts with existing data (or a concurrent request); "
                    "read it back and retry"
                ) from exc


@asynccontextmanager
async def open_runtime(settings: Settings) -> AsyncIterator[Runtime]:
    engine = db.create_engine(settings.resolved_database_url)
    store = make_session_store(settings.redis_url)
    uploads = make_upload_queue(settings.redis_url, settings.upload_visibility_s)
    limits = make_rate_limiter(settings.redis_url)
    key_watches = KeyWatches()
    try:
        yield Runtime(
            settings=settings,
            engine=engine,
            sql=db.session_factory(engine),
            store=store,
            maps=MapCache(settings.map_cache_size),
            uploads=uploads,
            limits=limits,
            sqlite_lock=anyio.Lock() if engine.dialect.name == "sqlite" else None,
            batch_gate=anyio.Semaphore(settings.batch_concurrency),
            states=SessionCache(settings.session_cache_size),
            key_watches=key_watches,
        )
    finally:
        await key_watches.close()
        await limits.close()
        await uploads.close()
        await store.close()
        await engine.dispose()


@asynccontextmanager
async def writing_history(rt: Runtime) -> AsyncIterator[None]:
    """Keep the applied batches' fixes (unless ``history_retention_days`` is 0), written
    to SQL about every second and once more when the block ends (what runs an api
    process; ``open_runtime`` alone, as the commands use it, keeps no history)."""
    if rt.settings.history_retention_days == 0:
        yield
        return
    rt.history = HistoryWriter(enabled=True)
    async with anyio.create_task_group() as tasks:
        tasks.start_soon(rt.history.run, rt.transaction)
        try:
            yield
        finally:
            rt.history.close()


async def check_ready(rt: Runtime) -> None:
    """Raise when the database or the session store does not answer."""
    await db.ping(rt.engine)
    await rt.store.ping()


def make_session_store(redis_url: str | None) -> SessionStore:
    """Redis when a URL is given (production shape; ``redis_client``: one server or a
    cluster), otherwise in memory (embedded)."""
    if not redis_url:
        return MemorySessionStore()
    return RedisSessionStore(redis_client(redis_url))
