"""The upload queue contract, run against the in-process queue and a real Redis Stream
(see ``tests.support.stores`` for which Redis)."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import AsyncIterator

import pytest

from server.storage.redis_client import AnyRedis, redis_client
from server.storage.upload_queue import MemoryUploadQueue, RedisUploadQueue, UploadQueue
from tests.support.stores import redis_or_skip

VISIBILITY_S = 0.3


@pytest.fixture(params=["memory", "redis", "cluster"])
async def queue(request: pytest.FixtureRequest) -> AsyncIterator[UploadQueue]:
    if request.param == "memory":
        yield MemoryUploadQueue(VISIBILITY_S)
        return
    client: AnyRedis
    if request.param == "cluster":
        client = redis_client(request.getfixturevalue("redis_cluster_url"))
    else:
        client = await redis_or_skip()
    prefix = f"ips-test-{uuid.uuid4().hex[:8]}"  # this test's stream only
    q = RedisUploadQueue(client, VISIBILITY_S, prefix=prefix)
    try:
        yield q
    finally:
        await client.delete(f"{prefix}:uploads:v1")
        await q.close()


async def test_entries_are_delivered_once_each_in_order(queue: UploadQueue) -> None:
    for i in range(5):
        await queue.publish(f"u{i}")
    first = await queue.read("a", count=3, block_ms=100)
    second = await queue.read("b", count=10, block_ms=100)
    assert [d.upload_id for d in first + second] == [f"u{i}" for i in range(5)]
    assert all(d.times_delivered == 1 for d in first + second)
    for d in first + second:
        await queue.ack(d)
    assert await queue.read("a", count=10, block_ms=50) == []


async def test_an_unacknowledged_entry_is_reclaimed_after_the_timeout(queue: UploadQueue) -> None:
    await queue.publish("u1")
    (taken,) = await queue.read("dies", count=1, block_ms=100)
    # within the visibility timeout nobody else gets it
    assert await queue.read("other", count=1, block_ms=50) == []
    await asyncio.sleep(VISIBILITY_S + 0.1)
    (again,) = await queue.read("other", count=1, block_ms=100)
    assert again.upload_id == "u1"
    assert again.entry_id == taken.entry_id
    assert again.times_delivered == 2
    await queue.ack(again)
    await asyncio.sleep(VISIBILITY_S + 0.1)
    assert await queue.read("third", count=1, block_ms=50) == []


async def test_an_acknowledged_entry_is_never_reclaimed(queue: UploadQueue) -> None:
    await queue.publish("u1")
    await queue.publish("u2")
    a, _ = await queue.read("w", count=2, block_ms=100)
    await queue.ack(a)
    await asyncio.sleep(VISIBILITY_S + 0.1)
    assert [d.upload_id for d in await queue.read("w2", count=5, block_ms=50)] == ["u2"]


async def test_read_waits_for_a_publish(queue: UploadQueue) -> None:
    async def later() -> None:
        await asyncio.sleep(0.1)
        await queue.publish("late")

    task = asyncio.create_task(later())
    start = time.monotonic()
    got = await queue.read("w", count=1, block_ms=2000)
    await task
    assert [d.upload_id for d in got] == ["late"]
    assert time.monotonic() - start < 1.5


async def test_a_redis_that_lost_the_stream_is_recovered_from() -> None:
    """Redis restarted without persistence: the stream and its group are gone. The queue
    makes the group again instead of failing every read (the uploads themselves are found
    in SQL by the worker's rescan)."""
    client = await redis_or_skip()
    prefix = f"ips-test-{uuid.uuid4().hex[:8]}"
    q = RedisUploadQueue(client, VISIBILITY_S, prefix=prefix)
    try:
        await q.publish("u1")
        await client.delete(f"{prefix}:uploads:v1")
        assert await q.read("w", count=1, block_ms=50) == []
        await q.publish("u2")
        assert [d.upload_id for d in await q.read("w", count=1, block_ms=100)] == ["u2"]
    finally:
        await client.delete(f"{prefix}:uploads:v1")
        await q.close()
