"""The runtime's wiring: which session store a process gets."""

from __future__ import annotations

import pytest
import redis.exceptions

from server.services.runtime import make_session_store
from server.storage.memory_session_store import MemorySessionStore
from server.storage.redis_session_store import RedisSessionStore


async def test_unreachable_redis_fails_ping() -> None:
    store = make_session_store("redis://127.0.0.1:1/0")
    assert isinstance(store, RedisSessionStore)
    try:
        with pytest.raises(redis.exceptions.ConnectionError):
            await store.ping()
    finally:
        await store.close()


async def test_make_session_store_without_url_is_in_memory() -> None:
    store = make_session_store(None)
    assert isinstance(store, MemorySessionStore)
    await store.close()
