"""The queue of uploads waiting for the worker: at-least-once delivery with reclaim.

An entry carries only an upload id; the upload row in SQL is the source of truth (its
status, its attempts), so an entry may be delivered more than once and the worker makes
processing idempotent. Semantics shared by both implementations:

- ``publish`` appends an entry.
- ``read`` hands a consumer up to ``count`` entries: first entries delivered to some
  consumer but not acknowledged for longer than the visibility timeout (that consumer is
  presumed dead; the entry is *reclaimed*), then new ones, waiting up to ``block_ms``
  when there are none. Each :class:`Delivery` says how often its entry has been handed
  out.
- ``ack`` removes an entry for good; call it only after the SQL commit that settled the
  upload.

Two implementations behind the :class:`UploadQueue` protocol:

- :class:`RedisUploadQueue` (production): a Redis Stream ``{prefix}:uploads:v1`` with the
  consumer group ``workers``; ``XREADGROUP`` for new entries, ``XAUTOCLAIM`` for stalled
  ones (idle longer than the visibility timeout), ``XACK`` + ``XDEL`` to settle. Entries
  survive a worker crash in Redis' pending entries list.
- :class:`MemoryUploadQueue` (embedded mode): the same rules over dicts in the event loop.
  It lives as long as the process; on start the worker re-publishes every upload left
  ``queued`` or ``processing`` in SQL, which is what makes a restart lose nothing.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Protocol

import anyio
from redis.exceptions import ResponseError

from server.storage.redis_client import AnyRedis, redis_client

GROUP = "workers"


@dataclass(frozen=True, slots=True)
class Delivery:
    entry_id: str
    upload_id: str
    times_delivered: int  # 1 on the first delivery


class UploadQueue(Protocol):
    async def publish(self, upload_id: str) -> None: ...

    async def read(self, consumer: str, count: int, block_ms: int) -> list[Delivery]: ...

    async def ack(self, delivery: Delivery) -> None: ...

    async def ping(self) -> None: ...

    async def close(self) -> None: ...


class MemoryUploadQueue:
    """In-process queue with the semantics of the module docstring."""

    def __init__(self, visibility_timeout_s: float) -> None:
        self._visibility_s = visibility_timeout_s
        self._next_id = 0
        self._new: OrderedDict[str, str] = OrderedDict()  # entry id -> upload id
        # entry id -> (upload id, deadline, times delivered)
        self._pending: dict[str, tuple[str, float, int]] = {}
        self._arrived = anyio.Event()

    async def publish(self, upload_id: str) -> None:
        self._next_id += 1
        self._new[f"{self._next_id}-0"] = upload_id
        self._arrived.set()

    async def read(
        self,
        consumer: str,  # noqa: ARG002 - one process: its consumers share one pending list
        count: int,
        block_ms: int,
    ) -> list[Delivery]:
        out = self._take(count)
        if not out and block_ms > 0:
            self._arrived = anyio.Event()
            with anyio.move_on_after(block_ms / 1000):
                await self._arrived.wait()
            out = self._take(count)
        return out

    def _take(self, count: int) -> list[Delivery]:
        now = time.monotonic()
        out: list[Delivery] = []
        for entry_id, (upload_id, deadline, times) in list(self._pending.items()):
            if len(out) == count:
                return out
            if deadline <= now:
                self._pending[entry_id] = (upload_id, now + self._visibility_s, times + 1)
                out.append(Delivery(entry_id, upload_id, times + 1))
        while self._new and len(out) < count:
            entry_id, upload_id = self._new.popitem(last=False)
            self._pending[entry_id] = (upload_id, now + self._visibility_s, 1)
            out.append(Delivery(entry_id, upload_id, 1))
        return out

    async def ack(self, delivery: Delivery) -> None:
        self._pending.pop(delivery.entry_id, None)

    async def ping(self) -> None:
        return None

    async def close(self) -> None:
        return None


class RedisUploadQueue:
    """A Redis Stream with one consumer group (module docstring)."""

    def __init__(self, client: AnyRedis, visibility_timeout_s: float, prefix: str = "ips") -> None:
        self._redis = client
        self._visibility_ms = int(visibility_timeout_s * 1000)
        self._key = f"{prefix}:uploads:v1"
        self._group_ready = False
        self._cursor = "0-0"

    async def _ensure_group(self) -> None:
        if self._group_ready:
            return
        try:
            await self._redis.xgroup_create(self._key, GROUP, id="0", mkstream=True)
        except ResponseError as exc:
            if "BUSYGROUP" not in str(exc):
                raise
        self._group_ready = True

    async def publish(self, upload_id: str) -> None:
        await self._ensure_group()
        # no MAXLEN: settled entries are deleted, so trimming could only drop live ones
        await self._redis.xadd(self._key, {"upload_id": upload_id})

    async def read(self, consumer: str, count: int, block_ms: int) -> list[Delivery]:
        await self._ensure_group()
        try:
            return await self._read(consumer, count, block_ms)
        except ResponseError as exc:
            if "NOGROUP" not in str(exc):
                raise
            # Redis lost the stream (a restart without persistence): make the group again;
            # the uploads it held are found by the worker's rescan of SQL
            self._group_ready = False
            await self._ensure_group()
            return []

    async def _read(self, consumer: str, count: int, block_ms: int) -> list[Delivery]:
        # XAUTOCLAIM scans a bounded part of the pending list per call: go on from where
        # the last call stopped, so stalled entries behind busy ones are reached too
        cursor, claimed, _ = await self._redis.xautoclaim(
            self._key, GROUP, consumer, self._visibility_ms, self._cursor, count=count
        )
        self._cursor = _text(cursor)
        out = await self._with_counts(claimed)
        if len(out) < count:
            streams = await self._redis.xreadgroup(
                GROUP,
                consumer,
                {self._key: ">"},
                count=count - len(out),
                block=block_ms if not out and block_ms > 0 else None,
            )
            for _, entries in streams or []:
                out += [
                    Delivery(_text(entry_id), _text(fields[b"upload_id"]), 1)
                    for entry_id, fields in entries
                    if fields
                ]
        return out

    async def _with_counts(self, claimed: list[Any]) -> list[Delivery]:
        """Deliveries for reclaimed entries, with how often each was handed out."""
        out = []
        for entry_id, fields in claimed:
            if not fields:  # deleted from the stream while pending: nothing to deliver
                await self._redis.xack(self._key, GROUP, entry_id)
                continue
            info = await self._redis.xpending_range(
                self._key, GROUP, min=entry_id, max=entry_id, count=1
            )
            times = int(info[0]["times_delivered"]) if info else 1
            out.append(Delivery(_text(entry_id), _text(fields[b"upload_id"]), times))
        return out

    async def ack(self, delivery: Delivery) -> None:
        async with self._redis.pipeline(transaction=True) as pipe:
            pipe.xack(self._key, GROUP, delivery.entry_id)
            pipe.xdel(self._key, delivery.entry_id)
            await pipe.execute()

    async def ping(self) -> None:
        await self._redis.ping()

    async def close(self) -> None:
        await self._redis.aclose()


def _text(value: bytes | str) -> str:
    return value.decode() if isinstance(value, bytes) else value


def make_upload_queue(redis_url: str | None, visibility_timeout_s: float) -> UploadQueue:
    """Redis when a URL is configured, else the in-process queue."""
    if not redis_url:
        return MemoryUploadQueue(visibility_timeout_s)
    return RedisUploadQueue(redis_client(redis_url), visibility_timeout_s)
