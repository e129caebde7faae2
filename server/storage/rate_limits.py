"""Token buckets shared by every api process: in Redis (production shape) or in memory.

A bucket named ``name`` holds up to ``burst`` tokens and refills at ``per_s`` tokens a
second; :meth:`RateLimiter.take` takes one token and answers None, or, when the bucket is
empty, takes nothing and answers how many seconds until a token is back. Redis keeps a
bucket as a hash (``tokens``, ``ts``) updated by one Lua script on the server's clock, so
replicas share the buckets and their clocks do not matter; an idle bucket expires once
it would be full again.

:meth:`RateLimiter.peek` asks on every request whether the client's address is barred
(``services.limits``), nearly always to hear that it is not. So Redis's "not empty" is
taken as good for ``PEEK_FRESH_S`` in the process that heard it, unless that process
takes from the bucket meanwhile: a bucket emptied through another replica is seen
within that time. This saves a round trip on nearly every request.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from typing import Protocol

from server.storage.redis_client import AnyRedis, redis_client, register_script

KEY_PREFIX = "ips:rl:"
MEMORY_MAX_BUCKETS = 100_000  # past this, the least recently used bucket is forgotten
PEEK_FRESH_S = 1.0  # how long a bucket Redis said was not empty is taken as still not
PEEK_MEMO_MAX = 100_000  # past this many remembered buckets, all are forgotten

_TAKE_LUA = """
local rate = tonumber(ARGV[1])
local burst = tonumber(ARGV[2])
local clock = redis.call('TIME')
local now = tonumber(clock[1]) + tonumber(clock[2]) / 1000000
local held = redis.call('HMGET', KEYS[1], 'tokens', 'ts')
local tokens = tonumber(held[1]) or burst
local ts = tonumber(held[2]) or now
tokens = math.min(burst, tokens + math.max(0, now - ts) * rate)
local wait = 0
if tokens >= 1 then tokens = tokens - 1 else wait = (1 - tokens) / rate end
redis.call('HSET', KEYS[1], 'tokens', tostring(tokens), 'ts', tostring(now))
redis.call('EXPIRE', KEYS[1], math.ceil(burst / rate) + 1)
return tostring(wait)
"""


_PEEK_LUA = """
local rate = tonumber(ARGV[1])
local burst = tonumber(ARGV[2])
local held = redis.call('HMGET', KEYS[1], 'tokens', 'ts')
if not held[1] then return '0' end
local clock = redis.call('TIME')
local now = tonumber(clock[1]) + tonumber(clock[2]) / 1000000
local tokens = math.min(burst, tonumber(held[1]) + math.max(0, now - tonumber(held[2])) * rate)
if tokens >= 1 then return '0' end
return tostring((1 - tokens) / rate)
"""


class RateLimiter(Protocol):
    async def take(self, name: str, per_s: float, burst: int) -> float | None: ...

    async def peek(self, name: str, per_s: float, burst: int) -> float | None:
        """Like :meth:`take` without taking: the wait when the bucket is empty, else None."""
        ...

    async def close(self) -> None: ...


class MemoryRateLimiter:
    """The buckets of one process (embedded mode: there is only one), at most
    ``max_buckets`` of them: past that the least recently used is forgotten (it comes
    back full, which only ever lets a client through sooner)."""

    def __init__(self, max_buckets: int = MEMORY_MAX_BUCKETS) -> None:
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()
        self._max = max_buckets

    async def take(self, name: str, per_s: float, burst: int) -> float | None:
        now = time.monotonic()
        tokens, ts = self._buckets.pop(name, (float(burst), now))
        tokens = min(float(burst), tokens + (now - ts) * per_s)
        wait = None if tokens >= 1.0 else (1.0 - tokens) / per_s
        self._buckets[name] = (tokens - 1.0 if wait is None else tokens, now)
        while len(self._buckets) > self._max:
            self._buckets.popitem(last=False)
        return wait

    async def peek(self, name: str, per_s: float, burst: int) -> float | None:
        if name not in self._buckets:
            return None
        tokens, ts = self._buckets[name]
        tokens = min(float(burst), tokens + (time.monotonic() - ts) * per_s)
        return None if tokens >= 1.0 else (1.0 - tokens) / per_s

    async def close(self) -> None:
        self._buckets.clear()


class RedisRateLimiter:
    def __init__(self, client: AnyRedis) -> None:
        self._client = client
        self._take = register_script(client, _TAKE_LUA)
        self._peek = register_script(client, _PEEK_LUA)
        # buckets Redis said were not empty, and until when that is believed here
        self._not_empty: dict[str, float] = {}

    async def take(self, name: str, per_s: float, burst: int) -> float | None:
        self._not_empty.pop(name, None)
        wait = float(await self._take(keys=[KEY_PREFIX + name], args=[per_s, burst]))
        return None if wait <= 0 else wait

    async def peek(self, name: str, per_s: float, burst: int) -> float | None:
        now = time.monotonic()
        if self._not_empty.get(name, 0.0) > now:
            return None
        wait = float(await self._peek(keys=[KEY_PREFIX + name], args=[per_s, burst]))
        if wait > 0:
            return wait
        if len(self._not_empty) >= PEEK_MEMO_MAX:
            self._not_empty.clear()
        self._not_empty[name] = now + PEEK_FRESH_S
        return None

    async def close(self) -> None:
        await self._client.aclose()


def make_rate_limiter(redis_url: str | None, connect_timeout_s: float = 2.0) -> RateLimiter:
    """Redis when a URL is given, otherwise in memory."""
    if not redis_url:
        return MemoryRateLimiter()
    client = redis_client(redis_url, decode_responses=True, connect_timeout_s=connect_timeout_s)
    return RedisRateLimiter(client)


def retry_after_s(wait_s: float) -> int:
    """A ``Retry-After`` value: whole seconds, at least 1."""
    return max(1, math.ceil(wait_s))
