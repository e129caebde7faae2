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

:meth:`RateLimiter.spend` is :meth:`RateLimiter.take` without a round trip of its own,
for a bucket many calls share (a client address's batches): the process counts the
calls it let through and takes them from Redis together every ``SPEND_FLUSH_S`` (all
the buckets of a flush in one pipeline). A bucket may go below empty by what the
replicas let through before they heard it was empty; it then stays empty longer, by as
much, so over a minute the allowance holds. Between flushes a process answers from
what it last heard.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import OrderedDict
from typing import Protocol

from redis.asyncio import Redis

from server.storage.redis_client import AnyRedis, redis_client, register_script

logger = logging.getLogger(__name__)
KEY_PREFIX = "ips:rl:"
MEMORY_MAX_BUCKETS = 100_000  # past this, the least recently used bucket is forgotten
PEEK_FRESH_S = 1.0  # how long a bucket Redis said was not empty is taken as still not
PEEK_MEMO_MAX = 100_000  # past this many remembered buckets, all are forgotten
SPEND_FLUSH_S = 2.0  # how often a process takes what it spent from the shared buckets

# ARGV[3] = 0: take a token if there is one, else the wait until there is; n > 0: take n
# tokens that calls already spent (``spend``), the bucket going below empty (down to -burst)
# if they were not all there, and answer the wait until a token is back ('0': there is one)
_TAKE_LUA = """
local rate = tonumber(ARGV[1])
local burst = tonumber(ARGV[2])
local spent = tonumber(ARGV[3])
local clock = redis.call('TIME')
local now = tonumber(clock[1]) + tonumber(clock[2]) / 1000000
local held = redis.call('HMGET', KEYS[1], 'tokens', 'ts')
local tokens = tonumber(held[1]) or burst
local ts = tonumber(held[2]) or now
tokens = math.min(burst, tokens + math.max(0, now - ts) * rate)
local wait = 0
if spent > 0 then
  tokens = math.max(tokens - spent, -burst)
  if tokens < 1 then wait = (1 - tokens) / rate end
elseif tokens >= 1 then
  tokens = tokens - 1
else
  wait = (1 - tokens) / rate
end
redis.call('HSET', KEYS[1], 'tokens', tostring(tokens), 'ts', tostring(now))
redis.call('EXPIRE', KEYS[1], math.ceil((2 * burst) / rate) + 1)
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


class EmptyBuckets:
    """Buckets this process heard are empty, and until when (nothing is held past that,
    and at most ``PEEK_MEMO_MAX`` buckets)."""

    def __init__(self) -> None:
        self._until: dict[str, float] = {}

    def note(self, name: str, wait_s: float) -> None:
        if len(self._until) >= PEEK_MEMO_MAX:
            self._until.clear()
        self._until[name] = time.monotonic() + wait_s

    def wait(self, name: str) -> float | None:
        """Seconds until the bucket holds a token again, as last heard; None if it does."""
        until = self._until.get(name)
        if until is None:
            return None
        left = until - time.monotonic()
        if left > 0:
            return left
        del self._until[name]
        return None


class RateLimiter(Protocol):
    empty: EmptyBuckets  # what this process heard of buckets it does not take from itself

    async def take(self, name: str, per_s: float, burst: int) -> float | None: ...

    def spend(self, name: str, per_s: float, burst: int) -> float | None:
        """Like :meth:`take`, from what this process knows (module docstring): the wait
        when the bucket is empty as last heard, else None (the call is counted)."""
        ...

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
        self.empty = EmptyBuckets()

    def spend(self, name: str, per_s: float, burst: int) -> float | None:
        now = time.monotonic()
        tokens, ts = self._buckets.pop(name, (float(burst), now))
        tokens = min(float(burst), tokens + (now - ts) * per_s)
        wait = None if tokens >= 1.0 else (1.0 - tokens) / per_s
        self._buckets[name] = (tokens - 1.0 if wait is None else tokens, now)
        while len(self._buckets) > self._max:
            self._buckets.popitem(last=False)
        return wait

    async def take(self, name: str, per_s: float, burst: int) -> float | None:
        return self.spend(name, per_s, burst)

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
        # spend(): calls let through since the last flush, per bucket (count, rate,
        # burst), and the buckets last heard empty, until when
        self._spent: dict[str, tuple[int, float, int]] = {}
        self.empty = EmptyBuckets()
        self._flush: asyncio.Task[None] | None = None

    async def take(self, name: str, per_s: float, burst: int) -> float | None:
        self._not_empty.pop(name, None)
        wait = float(await self._take(keys=[KEY_PREFIX + name], args=[per_s, burst, 0]))
        return None if wait <= 0 else wait

    def spend(self, name: str, per_s: float, burst: int) -> float | None:
        wait = self.empty.wait(name)
        if wait is not None:
            return wait
        count = self._spent.get(name, (0, per_s, burst))[0]
        self._spent[name] = (count + 1, per_s, burst)
        if self._flush is None or self._flush.done():  # done: its loop went away unflushed
            self._flush = asyncio.get_running_loop().create_task(self._flush_later())
        return None

    async def _flush_later(self) -> None:
        await asyncio.sleep(SPEND_FLUSH_S)
        self._flush = None
        await self._flush_now()

    async def _flush_now(self) -> None:
        spent, self._spent = self._spent, {}
        if not spent:
            return
        try:
            waits = await self._take_all(spent)
        except Exception:  # the calls went through; their count is lost, not the service
            logger.warning("could not count %d buckets' calls in Redis", len(spent), exc_info=True)
            return
        for name, wait in zip(spent, waits, strict=True):
            if float(wait) > 0:
                self.empty.note(name, float(wait))

    async def _take_all(self, spent: dict[str, tuple[int, float, int]]) -> list[str]:
        """Take each bucket's count from Redis: in one pipeline on one server; on a
        cluster, one call per bucket, all at once."""
        calls = [
            ([KEY_PREFIX + name], [per_s, burst, n]) for name, (n, per_s, burst) in spent.items()
        ]
        if isinstance(self._client, Redis):
            async with self._client.pipeline(transaction=False) as pipe:
                for keys, args in calls:
                    await self._take(keys=keys, args=args, client=pipe)
                return list(await pipe.execute())
        return list(
            await asyncio.gather(*(self._take(keys=keys, args=args) for keys, args in calls))
        )

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
        if self._flush is not None:
            self._flush.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._flush
        await self._flush_now()  # what was spent since the last flush still counts
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
