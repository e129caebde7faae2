"""A real Redis for the store contracts: ``INDOORPOS_REDIS_URL`` (default database 15 on
localhost), skipped when unreachable unless ``INDOORPOS_TEST_REQUIRE_REDIS=1``, which turns
that into a failure. The Redis Cluster is ``tests.support.redis_cluster``'s."""

from __future__ import annotations

import os

import pytest
from redis.asyncio import Redis

REDIS_URL = os.environ.get("INDOORPOS_REDIS_URL") or "redis://127.0.0.1:6379/15"
REQUIRE_REDIS = os.environ.get("INDOORPOS_TEST_REQUIRE_REDIS") == "1"


async def redis_or_skip() -> Redis:
    client: Redis = Redis.from_url(REDIS_URL, decode_responses=False, socket_connect_timeout=2)
    try:
        await client.ping()
    except Exception as exc:
        await client.aclose()
        if REQUIRE_REDIS:
            pytest.fail(f"Redis at {REDIS_URL} is required but does not answer: {exc}")
        pytest.skip(f"Redis at {REDIS_URL} does not answer: {exc}")
    return client
