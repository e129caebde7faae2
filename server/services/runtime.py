"""The long-lived resources every service works with, built once per process."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from sqlalchemy.ext.asyncio import AsyncEngine, AsyncSession, async_sessionmaker

from server.config import Settings
from server.services.maps import MapCache
from server.storage import db
from server.storage.session_store import SessionStore, make_session_store


@dataclass
class Runtime:
    settings: Settings
    engine: AsyncEngine
    sql: async_sessionmaker[AsyncSession]
    store: SessionStore
    maps: MapCache

    @asynccontextmanager
    async def transaction(self) -> AsyncIterator[AsyncSession]:
        """A SQL session that commits on success and rolls back on error."""
        async with self.sql() as session, session.begin():
            yield session


@asynccontextmanager
async def open_runtime(settings: Settings) -> AsyncIterator[Runtime]:
    engine = db.create_engine(settings.resolved_database_url)
    store = make_session_store(settings.redis_url)
    try:
        yield Runtime(
            settings=settings,
            engine=engine,
            sql=db.session_factory(engine),
            store=store,
            maps=MapCache(settings.map_cache_size),
        )
    finally:
        await store.close()
        await engine.dispose()


async def check_ready(rt: Runtime) -> None:
    """Raise when the database or the session store does not answer."""
    await db.ping(rt.engine)
    await rt.store.ping()
