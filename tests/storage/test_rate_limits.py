"""Token buckets in Redis (``server.storage.rate_limits``): a "not empty" heard from Redis
holds in the process that heard it for ``PEEK_FRESH_S``, unless that process takes from
the bucket, and what a process ``spend``s is taken from Redis every ``SPEND_FLUSH_S``;
two limiters stand for two api processes on one Redis."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator

import pytest

from server.storage import rate_limits
from server.storage.rate_limits import RedisRateLimiter, make_rate_limiter
from tests.support.stores import REDIS_URL, redis_or_skip

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


async def test_what_two_processes_spend_is_taken_from_the_shared_bucket(
    two: tuple[RedisRateLimiter, RedisRateLimiter], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(rate_limits, "SPEND_FLUSH_S", 0.1)
    a, b = two
    name = f"test:{uuid.uuid4().hex}"
    per_s, burst = 0.01, 4  # four calls, then one every 100 s
    # each lets calls through from what it knows until it flushes: six, two past empty
    assert [a.spend(name, per_s, burst) for _ in range(3)] == [None] * 3
    await asyncio.sleep(0.3)  # a took 3 of 4: not empty
    assert [b.spend(name, per_s, burst) for _ in range(3)] == [None] * 3
    await asyncio.sleep(0.3)  # b took 3 more: two short, and paid back before a token is back
    wait = b.spend(name, per_s, burst)
    assert wait is not None
    assert 290 < wait <= 300
    assert a.spend(name, per_s, burst) is None  # a goes by what it heard, and counts the call
    await asyncio.sleep(0.3)
    wait = a.spend(name, per_s, burst)
    assert wait is not None
    assert 390 < wait <= 400
    assert await b.take(name, per_s, burst) is not None  # the shared bucket says so too


async def test_a_flush_that_fails_lets_the_calls_through(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(rate_limits, "SPEND_FLUSH_S", 0.05)
    limiter = make_rate_limiter("redis://127.0.0.1:1/0", connect_timeout_s=0.5)
    try:
        assert limiter.spend("test:nowhere", 1.0, 1) is None
        await asyncio.sleep(0.8)
        assert limiter.spend("test:nowhere", 1.0, 1) is None  # still nothing heard
        assert "could not count" in caplog.text
    finally:
        await limiter.close()
