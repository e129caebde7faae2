"""Token buckets in Redis (``server.storage.rate_limits``): a "not empty" heard from Redis
holds in the process that heard it for ``PEEK_FRESH_S``, unless that process takes from
the bucket; two limiters stand for two api processes on one Redis."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator

import pytest

from server.storage import rate_limits
from server.storage.rate_limits import RedisRateLimiter, make_rate_limiter
from tests.storage.conftest import REDIS_URL, redis_or_skip

PER_S, BURST = 0.001, 1  # one token, back in 1,000 s


@pytest.fixture
async def two() -> AsyncIterator[tuple[RedisRateLimiter, RedisRateLimiter]]:
    await (await redis_or_skip()).aclose()
    a, b = make_rate_limiter(REDIS_URL), make_rate_limiter(REDIS_URL)
    assert isinstance(a, RedisRateLimiter)
    assert isinstance(b, RedisRateLimiter)
    yield a, b
    await a.close()
    await b.close()


async def test_a_bucket_emptied_elsewhere_is_seen_once_the_memo_is_stale(
    two: tuple[RedisRateLimiter, RedisRateLimiter], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(rate_limits, "PEEK_FRESH_S", 0.3)
    a, b = two
    name = f"test:{uuid.uuid4().hex}"
    assert await a.peek(name, PER_S, BURST) is None  # heard: not empty
    assert await b.take(name, PER_S, BURST) is None  # the other process takes the last token
    assert await b.peek(name, PER_S, BURST) is not None
    assert await a.peek(name, PER_S, BURST) is None  # believed a while longer, without asking
    await asyncio.sleep(0.4)
    assert await a.peek(name, PER_S, BURST) is not None


async def test_taking_from_a_bucket_forgets_what_was_heard_of_it(
    two: tuple[RedisRateLimiter, RedisRateLimiter],
) -> None:
    a, _ = two
    name = f"test:{uuid.uuid4().hex}"
    assert await a.peek(name, PER_S, BURST) is None
    assert await a.take(name, PER_S, BURST) is None
    assert await a.peek(name, PER_S, BURST) is not None  # asked again: empty now
