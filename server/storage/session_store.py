"""Per-session state store: one versioned record per session plus a live pub/sub channel.

A record is immutable ``meta`` (written once at create), a ``state`` blob (a snapshot),
the ``log`` of entries written since that snapshot, and a ``version`` that starts at 1 and
grows by one per successful :meth:`SessionStore.compare_and_set`. A write either replaces
the snapshot (and empties the log) or appends one entry to the log: the caller decides
what a snapshot and an entry hold (``services.batches``: the whole session state, and a
batch with its answer), so a write sends a few kilobytes at most, not the state.
Writers read, compute, then compare-and-set on the version they read, so two replicas
working on one session never overwrite each other: the loser re-reads and retries.
Every record expires after ``ttl_s`` seconds without a successful write. A write may
also take a token from the session's own rate-limit bucket, kept in the record: when
the bucket is empty the write is refused (:class:`BucketEmpty`) and nothing changes, so
the rate limit costs no round trip of its own. Beside it, each
session keeps its *track*: the newest fixes it made (at most the ``track_len`` a write
asks for), pushed by the same :meth:`SessionStore.compare_and_set` that writes the state
and expiring with it.

Two implementations behind one :class:`SessionStore` protocol:

- :class:`RedisSessionStore` (production): one hash per session at
  ``{prefix}:sess:{<session_id>}:state:v1`` with fields ``ver``, ``meta``, ``state``, its
  log, the list ``{prefix}:sess:{<session_id>}:log:v1``, and a capped list
  ``{prefix}:sess:{<session_id>}:track:v1`` of its newest fixes, written by Lua scripts so
  check, write, log, track and expiry happen atomically; live messages on
  the sharded pub/sub channel ``{prefix}:sess:{<session_id>}:live:v1`` (``SPUBLISH`` /
  ``SSUBSCRIBE``, Redis 7). The braces are a Redis Cluster hash tag: the keys and the
  channel of one session live in one slot, so the same code runs on one Redis or on a
  Redis Cluster (``redis+cluster://host:port``: any node of the cluster), where a
  session's messages stay on the shard that owns it. The ids of API keys that stopped
  working go on one more sharded channel, ``{prefix}:keys:revoked:v1``, which every api
  replica holding a socket of a key listens to.
- :class:`MemorySessionStore` (embedded mode, tests): a dict in the event loop's thread.

Pub/sub is fire-and-forget in both: a subscriber sees the messages published after its
subscription went live, none from before, and nothing is replayed after a reconnect.
"""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol, cast

import anyio
from redis.asyncio import Redis
from redis.asyncio.client import PubSub
from redis.asyncio.cluster import RedisCluster
from redis.asyncio.connection import AbstractConnection

from server.storage.redis_client import CONNECT_TIMEOUT_S, redis_client, register_script

SUBSCRIBE_TIMEOUT_S = 5.0  # how long subscribe() waits for Redis to confirm
MEMORY_QUEUE_SIZE = 1024  # messages a slow in-memory subscriber may fall behind by
MEMORY_SWEEP_INTERVAL_S = 60.0  # how often the in-memory store drops expired records
MEMORY_REVOKED_CHANNEL = "keys:revoked"  # no session id (32 hex digits) looks like it


class SessionExists(Exception):
    """:meth:`SessionStore.create` was called for a session id that is already present."""


class BucketEmpty(Exception):
    """:meth:`SessionStore.compare_and_set` found the session's bucket empty: nothing was
    written; a token is back in ``wait_s`` seconds."""

    def __init__(self, wait_s: float) -> None:
        super().__init__(f"the session's bucket is empty for {wait_s:.3f} s")
        self.wait_s = wait_s


@dataclass(frozen=True, slots=True)
class Allowance:
    """A token bucket: ``burst`` tokens at most, refilled at ``per_s`` a second."""

    per_s: float
    burst: int


@dataclass(frozen=True, slots=True)
class StoredSession:
    version: int  # 1 after create, +1 per successful compare_and_set
    meta: bytes  # written once at create, never changed
    state: bytes  # the snapshot, written at version - len(log)
    log: tuple[bytes, ...] = ()  # the entries written since, oldest first


class SessionStore(Protocol):
    async def create(
        self, session_id: str, meta: bytes, state: bytes, ttl_s: int, version: int = 1
    ) -> None:
        """Store a new record at ``version`` (1 for a new session; a rebuilt one starts
        past any version it had, so no cached copy of it can pass for current); raise
        :class:`SessionExists` if present."""
        ...

    async def get(self, session_id: str) -> StoredSession | None:
        """The record (its snapshot and log), or ``None`` if it never existed, expired or
        was deleted."""
        ...

    async def get_changed(self, session_id: str, known_version: int) -> StoredSession | int | None:
        """Like :meth:`get`, but when the record is still at ``known_version`` only that
        version comes back (an ``int``): meta and state, which the caller holds, are not
        sent again."""
        ...

    async def compare_and_set(
        self,
        session_id: str,
        expected_version: int,
        state: bytes | None,
        ttl_s: int,
        publish: bytes | None = None,
        track: Sequence[bytes] = (),
        track_len: int = 0,
        allowance: Allowance | None = None,
        entry: bytes | None = None,
    ) -> bool:
        """Atomically: if the record exists at ``expected_version`` (and, with
        ``allowance``, the session's bucket of that allowance holds a token, which is
        taken; else :class:`BucketEmpty`), store ``state`` as the snapshot and empty the
        log, or, with ``state`` None, append ``entry`` to the log; bump the version, reset
        the expiry (of the record, its log and its track) to ``ttl_s``, append ``track``
        (fixes, oldest first) to the session's track keeping its newest ``track_len``
        entries (none with 0), send ``publish`` (when given) to the session's subscribers
        as :meth:`publish` would, and return ``True``; otherwise change nothing, send
        nothing and return ``False``."""
        ...

    async def track(self, session_id: str, limit: int) -> list[bytes]:
        """The newest ``limit`` (>= 1) entries of the session's track, oldest first;
        empty when the session has none or is gone."""
        ...

    async def delete(self, session_id: str) -> bool:
        """Remove the record and its track; ``True`` if the record existed."""
        ...

    async def publish(self, session_id: str, message: bytes) -> None:
        """Send ``message`` to every current subscriber of the session."""
        ...

    def subscribe(self, session_id: str) -> AbstractAsyncContextManager[AsyncIterator[bytes]]:
        """``async with store.subscribe(sid) as messages: async for m in messages: ...``

        The subscription is live when ``__aenter__`` returns: nothing published after
        that is missed. Leaving the block unsubscribes; the iterator then ends."""
        ...

    async def publish_revoked(self, key_id: str) -> None:
        """Tell every subscriber of :meth:`subscribe_revoked`, in every process sharing
        the store, that API key ``key_id`` stopped working (revoked or rotated)."""
        ...

    def subscribe_revoked(self) -> AbstractAsyncContextManager[AsyncIterator[str]]:
        """``async with store.subscribe_revoked() as key_ids: async for key_id in key_ids:``
        the ids :meth:`publish_revoked` sends, live when ``__aenter__`` returns. The
        iterator raises (a :class:`ConnectionError` or a Redis error) when the
        subscription broke, even if it came back by itself: what was sent meanwhile is
        lost. Subscribe again, and look for what was missed."""
        ...

    async def epoch(self) -> str:
        """An id of the store's contents: it changes when the store lost what it held
        (a Redis restarted without its data, an embedded process restarted), and only
        then. A record missing at the epoch it was made in expired or was deleted."""
        ...

    async def ping(self) -> None:
        """Raise if the backend does not answer."""
        ...

    async def close(self) -> None:
        """Release connections; the store is not used afterwards."""
        ...


def _ttl_ms(ttl_s: int) -> int:
    """The expiry in whole milliseconds; a non-positive TTL is a caller bug, not a delete."""
    if ttl_s <= 0:
        raise ValueError(f"ttl_s must be positive, got {ttl_s}")
    return int(ttl_s * 1000)


def _written(state: bytes | None, entry: bytes | None) -> bytes:
    """What a write stores: a snapshot or a log entry, exactly one of them."""
    if state is not None and entry is None:
        return bytes(state)
    if entry is not None and state is None:
        return bytes(entry)
    raise ValueError("a write stores a snapshot or a log entry, exactly one of them")


def _kept(track: Sequence[bytes], track_len: int) -> list[bytes]:
    """What of ``track`` can stay on a track of ``track_len`` entries."""
    return [bytes(b) for b in track[-track_len:]] if track_len > 0 else []


# --- in memory ------------------------------------------------------------------------------


@dataclass(slots=True)
class _Record:
    version: int
    meta: bytes
    state: bytes
    expires_at: float
    track: list[bytes] = field(default_factory=list)
    log: list[bytes] = field(default_factory=list)
    tokens: float | None = None  # the session's bucket (None: full, never taken from)
    tokens_at: float = 0.0


async def _key_ids(messages: AsyncIterator[bytes]) -> AsyncIterator[str]:
    async for message in messages:
        yield message.decode()


class _QueueMessages:
    """Iterator over one in-memory subscriber's queue; ends once the subscription closed."""

    def __init__(self, queue: asyncio.Queue[bytes]) -> None:
        self.queue = queue
        self.closed = False

    def __aiter__(self) -> _QueueMessages:
        return self

    async def __anext__(self) -> bytes:
        if self.closed:
            raise StopAsyncIteration
        return await self.queue.get()


class MemorySessionStore:
    """Sessions in a dict, for one process (embedded mode and tests).

    Every operation runs without an ``await`` between its read and its write, so it is
    atomic within the event loop. Expiry is checked on access against ``clock`` (default
    :func:`time.monotonic`); expired records are also swept out every
    ``MEMORY_SWEEP_INTERVAL_S`` so abandoned sessions do not pile up.

    Each subscriber has its own bounded queue of ``queue_size`` messages. A subscriber that
    falls that far behind loses its *oldest* queued messages: publishers never block and
    never fail because of a slow reader.
    """

    def __init__(
        self,
        *,
        queue_size: int = MEMORY_QUEUE_SIZE,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size must be at least 1, got {queue_size}")
        self._queue_size = queue_size
        self._clock = clock
        self._records: dict[str, _Record] = {}
        self._subscribers: dict[str, set[asyncio.Queue[bytes]]] = {}  # by channel
        self._next_sweep = clock() + MEMORY_SWEEP_INTERVAL_S
        self._epoch = uuid.uuid4().hex  # a new process starts with a new, empty dict

    def _live(self, session_id: str) -> _Record | None:
        now = self._clock()
        if now >= self._next_sweep:
            self._records = {k: r for k, r in self._records.items() if r.expires_at > now}
            self._next_sweep = now + MEMORY_SWEEP_INTERVAL_S
        record = self._records.get(session_id)
        if record is not None and record.expires_at <= now:
            del self._records[session_id]
            return None
        return record

    async def create(
        self, session_id: str, meta: bytes, state: bytes, ttl_s: int, version: int = 1
    ) -> None:
        _ttl_ms(ttl_s)
        if self._live(session_id) is not None:
            raise SessionExists(session_id)
        self._records[session_id] = _Record(
            version, bytes(meta), bytes(state), self._clock() + ttl_s
        )

    async def get(self, session_id: str) -> StoredSession | None:
        record = self._live(session_id)
        if record is None:
            return None
        return StoredSession(record.version, record.meta, record.state, tuple(record.log))

    async def get_changed(self, session_id: str, known_version: int) -> StoredSession | int | None:
        record = self._live(session_id)
        if record is None:
            return None
        if record.version == known_version:
            return known_version
        return StoredSession(record.version, record.meta, record.state, tuple(record.log))

    async def compare_and_set(
        self,
        session_id: str,
        expected_version: int,
        state: bytes | None,
        ttl_s: int,
        publish: bytes | None = None,
        track: Sequence[bytes] = (),
        track_len: int = 0,
        allowance: Allowance | None = None,
        entry: bytes | None = None,
    ) -> bool:
        _ttl_ms(ttl_s)
        written = _written(state, entry)
        record = self._live(session_id)
        if record is None or record.version != expected_version:
            return False
        if allowance is not None:
            self._take(record, allowance)
        if state is not None:
            record.state, record.log = written, []
        else:
            record.log.append(written)
        record.version += 1
        record.expires_at = self._clock() + ttl_s
        if kept := _kept(track, track_len):
            record.track.extend(kept)
            del record.track[:-track_len]
        if publish is not None:
            await self.publish(session_id, publish)
        return True

    def _take(self, record: _Record, allowance: Allowance) -> None:
        now = self._clock()
        held = allowance.burst if record.tokens is None else record.tokens
        tokens = min(allowance.burst, held + max(0.0, now - record.tokens_at) * allowance.per_s)
        if tokens < 1:
            raise BucketEmpty((1 - tokens) / allowance.per_s)
        record.tokens, record.tokens_at = tokens - 1, now

    async def track(self, session_id: str, limit: int) -> list[bytes]:
        record = self._live(session_id)
        return record.track[-limit:] if record is not None and limit > 0 else []

    async def delete(self, session_id: str) -> bool:
        existed = self._live(session_id) is not None
        self._records.pop(session_id, None)
        return existed

    async def publish(self, session_id: str, message: bytes) -> None:
        message = bytes(message)
        for queue in self._subscribers.get(session_id, ()):
            if queue.full():
                queue.get_nowait()  # drop the oldest rather than block the publisher
            queue.put_nowait(message)

    @asynccontextmanager
    async def _subscription(self, channel: str) -> AsyncIterator[_QueueMessages]:
        queue: asyncio.Queue[bytes] = asyncio.Queue(self._queue_size)
        subscribers = self._subscribers.setdefault(channel, set())
        subscribers.add(queue)
        messages = _QueueMessages(queue)
        try:
            yield messages
        finally:
            messages.closed = True
            subscribers.discard(queue)
            if not subscribers:
                self._subscribers.pop(channel, None)

    def subscribe(self, session_id: str) -> AbstractAsyncContextManager[AsyncIterator[bytes]]:
        return self._subscription(session_id)

    async def publish_revoked(self, key_id: str) -> None:
        await self.publish(MEMORY_REVOKED_CHANNEL, key_id.encode())

    @asynccontextmanager
    async def _revoked(self) -> AsyncIterator[AsyncIterator[str]]:
        async with self._subscription(MEMORY_REVOKED_CHANNEL) as messages:
            yield _key_ids(messages)

    def subscribe_revoked(self) -> AbstractAsyncContextManager[AsyncIterator[str]]:
        return self._revoked()

    async def epoch(self) -> str:
        return self._epoch

    async def ping(self) -> None:
        return None

    async def close(self) -> None:
        self._records.clear()


# --- Redis ----------------------------------------------------------------------------------

# KEYS[1] = state key, KEYS[2] = track key, KEYS[3] = log key; ARGV = meta, state, ttl_ms,
# version. Returns 1 if created, 0 if present. A new record starts with an empty track
# and an empty log.
_CREATE_LUA = """
if redis.call('EXISTS', KEYS[1]) == 1 then
  return 0
end
redis.call('HSET', KEYS[1], 'ver', ARGV[4], 'meta', ARGV[1], 'state', ARGV[2])
redis.call('PEXPIRE', KEYS[1], ARGV[3])
redis.call('DEL', KEYS[2], KEYS[3])
return 1
"""

# KEYS[1] = state key, KEYS[2] = track key, KEYS[3] = log key; ARGV = expected version,
# snapshot or log entry, ttl_ms, track length, live channel ('' for none), live message,
# the bucket's refill per second (0: no bucket) and burst, 'snapshot' or 'entry', then the
# fixes to push onto the track (none, or at most track length of them). Returns 1 if
# written, 0 if not at that version, or (a string) the seconds until the session's bucket
# holds a token again.
_CAS_LUA = """
local ver = redis.call('HGET', KEYS[1], 'ver')
if not ver or tonumber(ver) ~= tonumber(ARGV[1]) then
  return 0
end
local rate = tonumber(ARGV[7])
if rate > 0 then
  local burst = tonumber(ARGV[8])
  local clock = redis.call('TIME')
  local now = tonumber(clock[1]) + tonumber(clock[2]) / 1000000
  local held = redis.call('HMGET', KEYS[1], 'rl_tokens', 'rl_ts')
  local tokens = tonumber(held[1]) or burst
  tokens = math.min(burst, tokens + math.max(0, now - (tonumber(held[2]) or now)) * rate)
  if tokens < 1 then
    return tostring((1 - tokens) / rate)
  end
  redis.call('HSET', KEYS[1], 'rl_tokens', tostring(tokens - 1), 'rl_ts', tostring(now))
end
if ARGV[9] == 'snapshot' then
  redis.call('HSET', KEYS[1], 'state', ARGV[2])
  redis.call('DEL', KEYS[3])
else
  redis.call('RPUSH', KEYS[3], ARGV[2])
  redis.call('PEXPIRE', KEYS[3], ARGV[3])
end
redis.call('HINCRBY', KEYS[1], 'ver', 1)
redis.call('PEXPIRE', KEYS[1], ARGV[3])
if #ARGV > 9 then
  redis.call('RPUSH', KEYS[2], unpack(ARGV, 10))
  redis.call('LTRIM', KEYS[2], -tonumber(ARGV[4]), -1)
end
redis.call('PEXPIRE', KEYS[2], ARGV[3])
if ARGV[5] ~= '' then
  redis.call('SPUBLISH', ARGV[5], ARGV[6])
end
return 1
"""


# KEYS[1] = state key, KEYS[2] = log key; ARGV[1] = the version the caller holds (''
# for none). The version alone while it is still that one; else version, meta, snapshot
# and the log's entries
_GET_LUA = """
local ver = redis.call('HGET', KEYS[1], 'ver')
if not ver then
  return false
end
if ARGV[1] ~= '' and tonumber(ver) == tonumber(ARGV[1]) then
  return {ver}
end
local found = redis.call('HMGET', KEYS[1], 'ver', 'meta', 'state')
for _, entry in ipairs(redis.call('LRANGE', KEYS[2], 0, -1)) do
  table.insert(found, entry)
end
return found
"""


class _PubSubMessages:
    """Iterator over the data of the messages of one sharded channel on one pub/sub
    connection.

    redis-py reconnects a dropped connection by itself, but subscribes it again only to
    what it subscribed itself, not to a channel of ``SSUBSCRIBE``: :meth:`resubscribe`,
    which the connection calls on each reconnect, does. Whatever was published while
    the connection was down is lost; with ``strict`` the iterator then raises
    :class:`ConnectionError` (as when the channel's slot moved to another node) for the
    caller to subscribe again and look for what it missed, else it goes on."""

    def __init__(self, pubsub: PubSub, channel: str, *, strict: bool) -> None:
        self.pubsub = pubsub
        self.channel = channel
        self.strict = strict
        self.closed = False

    async def resubscribe(self, connection: AbstractConnection) -> None:
        await connection.send_command("SSUBSCRIBE", self.channel)

    def __aiter__(self) -> _PubSubMessages:
        return self

    async def __anext__(self) -> bytes:
        while not self.closed:
            message = await self.pubsub.get_message(timeout=None)
            if message is None:
                continue
            if message["type"] == "smessage":
                data: bytes = message["data"]
                return data
            if self.strict and message["type"] in ("ssubscribe", "sunsubscribe"):
                # after the first confirmation (read on subscribing): a reconnect, or a
                # slot that moved
                raise ConnectionError(f"the subscription to {self.channel} broke")
        raise StopAsyncIteration


class RedisSessionStore:
    """Sessions in Redis (or Redis Cluster): any api replica can serve any session.

    ``client`` must return bytes (``decode_responses=False``). The store owns the client:
    :meth:`close` closes it. On a cluster, a subscription connects to the node that owns
    its channel's slot (async cluster clients of redis-py have no pub/sub); those
    per-node clients are the store's too.
    """

    def __init__(self, client: Redis | RedisCluster, prefix: str = "ips") -> None:
        self._client = client
        self._nodes: dict[tuple[str, int], Redis] = {}
        self._prefix = prefix
        self._create = register_script(client, _CREATE_LUA)
        self._cas = register_script(client, _CAS_LUA)
        self._get = register_script(client, _GET_LUA)

    def state_key(self, session_id: str) -> str:
        """The hash holding the session's ``ver``, ``meta`` and ``state``."""
        return f"{self._prefix}:sess:{{{session_id}}}:state:v1"

    def log_key(self, session_id: str) -> str:
        """The list of the entries written since the snapshot, oldest first."""
        return f"{self._prefix}:sess:{{{session_id}}}:log:v1"

    def track_key(self, session_id: str) -> str:
        """The list of the session's newest fixes, oldest first."""
        return f"{self._prefix}:sess:{{{session_id}}}:track:v1"

    def live_channel(self, session_id: str) -> str:
        """The pub/sub channel of the session's live messages."""
        return f"{self._prefix}:sess:{{{session_id}}}:live:v1"

    def revoked_channel(self) -> str:
        """The pub/sub channel of the ids of API keys that stopped working."""
        return f"{self._prefix}:keys:revoked:v1"

    async def create(
        self, session_id: str, meta: bytes, state: bytes, ttl_s: int, version: int = 1
    ) -> None:
        created = await self._create(
            keys=[self.state_key(session_id), self.track_key(session_id), self.log_key(session_id)],
            args=[meta, state, _ttl_ms(ttl_s), version],
        )
        if not created:
            raise SessionExists(session_id)

    async def get(self, session_id: str) -> StoredSession | None:
        found = await self._read(session_id, "")
        assert not isinstance(found, int)  # no version given: the whole record or None
        return found

    async def get_changed(self, session_id: str, known_version: int) -> StoredSession | int | None:
        return await self._read(session_id, known_version)

    async def _read(self, session_id: str, known_version: int | str) -> StoredSession | int | None:
        keys = [self.state_key(session_id), self.log_key(session_id)]
        found = await self._get(keys=keys, args=[known_version])
        if not found:
            return None
        if len(found) == 1:
            return int(found[0])
        ver, meta, state, *log = found
        if ver is None or meta is None or state is None:
            return None
        return StoredSession(int(ver), meta, state, tuple(log))

    async def compare_and_set(
        self,
        session_id: str,
        expected_version: int,
        state: bytes | None,
        ttl_s: int,
        publish: bytes | None = None,
        track: Sequence[bytes] = (),
        track_len: int = 0,
        allowance: Allowance | None = None,
        entry: bytes | None = None,
    ) -> bool:
        # bucket, state or log, track and live message in one script: one round trip
        written = _written(state, entry)
        channel = self.live_channel(session_id) if publish is not None else ""
        args: list[Any] = [expected_version, written, _ttl_ms(ttl_s), max(track_len, 0)]
        args += [channel, publish or b""]
        args += [allowance.per_s, allowance.burst] if allowance is not None else [0, 0]
        args += ["snapshot" if state is not None else "entry", *_kept(track, track_len)]
        keys = [self.state_key(session_id), self.track_key(session_id), self.log_key(session_id)]
        written = await self._cas(keys=keys, args=args)
        if isinstance(written, bytes):
            raise BucketEmpty(float(written))
        return bool(written)

    async def track(self, session_id: str, limit: int) -> list[bytes]:
        if limit < 1:
            return []
        found = self._client.lrange(self.track_key(session_id), -limit, -1)
        return list(await cast("Awaitable[list[bytes]]", found))

    async def delete(self, session_id: str) -> bool:
        removed: int = await self._client.delete(self.state_key(session_id))
        await self._client.delete(self.track_key(session_id), self.log_key(session_id))
        return removed > 0

    async def publish(self, session_id: str, message: bytes) -> None:
        channel = self.live_channel(session_id)
        await (await self._owner(channel)).spublish(channel, message)

    async def publish_revoked(self, key_id: str) -> None:
        channel = self.revoked_channel()
        await (await self._owner(channel)).spublish(channel, key_id.encode())

    async def _owner(self, channel: str) -> Redis:
        """A client of the node that serves ``channel`` (the store's own on one Redis)."""
        if isinstance(self._client, Redis):
            return self._client
        await self._client.initialize()
        node = self._client.get_node_from_key(channel)
        if node is None:
            raise ConnectionError(f"no cluster node serves {channel}")
        where = (str(node.host), int(node.port))
        found = self._nodes.get(where)
        if found is None:
            found = Redis(
                host=where[0],
                port=where[1],
                decode_responses=False,
                socket_connect_timeout=CONNECT_TIMEOUT_S,
            )
            self._nodes[where] = found
        return found

    @asynccontextmanager
    async def _subscription(self, channel: str, *, strict: bool) -> AsyncIterator[_PubSubMessages]:
        pubsub = (await self._owner(channel)).pubsub()
        messages = _PubSubMessages(pubsub, channel, strict=strict)
        try:
            await pubsub.execute_command("SSUBSCRIBE", channel)
            connection = pubsub.connection
            assert connection is not None  # execute_command connected it
            connection.register_connect_callback(messages.resubscribe)
            # SSUBSCRIBE is only sent above; the subscription is live once Redis confirms it.
            async with asyncio.timeout(SUBSCRIBE_TIMEOUT_S):
                confirmation: dict[str, Any] | None = None
                while confirmation is None or confirmation["type"] != "ssubscribe":
                    confirmation = await pubsub.get_message(timeout=None)
            yield messages
        finally:
            messages.closed = True
            if pubsub.connection is not None:  # back to the pool: not to subscribe again
                pubsub.connection.deregister_connect_callback(messages.resubscribe)
            # Closing drops the connection, which unsubscribes; shielded so a cancelled
            # reader still gives its connection back to the pool.
            with anyio.CancelScope(shield=True):
                await pubsub.aclose()  # type: ignore[no-untyped-call]  # unannotated in redis-py

    def subscribe(self, session_id: str) -> AbstractAsyncContextManager[AsyncIterator[bytes]]:
        return self._subscription(self.live_channel(session_id), strict=False)

    @asynccontextmanager
    async def _revoked(self) -> AsyncIterator[AsyncIterator[str]]:
        async with self._subscription(self.revoked_channel(), strict=True) as messages:
            yield _key_ids(messages)

    def subscribe_revoked(self) -> AbstractAsyncContextManager[AsyncIterator[str]]:
        return self._revoked()

    def epoch_key(self) -> str:
        """A key set once, never expiring: a Redis that lost its data has none, and the
        next :meth:`epoch` makes a new one."""
        return f"{self._prefix}:epoch:v1"

    async def epoch(self) -> str:
        key = self.epoch_key()
        await self._client.set(key, uuid.uuid4().hex, nx=True)
        found = await self._client.get(key)
        return found.decode() if isinstance(found, bytes) else str(found)

    async def ping(self) -> None:
        await self._client.ping()

    async def close(self) -> None:
        for node in self._nodes.values():
            await node.aclose()
        self._nodes.clear()
        await self._client.aclose()


def make_session_store(redis_url: str | None) -> SessionStore:
    """Redis when a URL is given (production shape; ``redis_client``: one server or a
    cluster), otherwise in memory (embedded)."""
    if not redis_url:
        return MemorySessionStore()
    return RedisSessionStore(redis_client(redis_url))
