"""The session store in Redis or a Redis Cluster (production): ``session_store`` says what
it keeps, under which keys, and what it promises."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator, Awaitable, Sequence
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from typing import Any, cast

import anyio
from redis.asyncio import Redis
from redis.asyncio.client import PubSub
from redis.asyncio.cluster import RedisCluster
from redis.asyncio.connection import AbstractConnection

from server.storage.redis_client import CONNECT_TIMEOUT_S, register_script
from server.storage.session_store import (
    Allowance,
    BucketEmpty,
    SessionExists,
    StoredSession,
    kept_fixes,
    key_ids,
    ttl_ms,
    write_payload,
)

SUBSCRIBE_TIMEOUT_S = 5.0  # how long subscribe() waits for Redis to confirm


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
            args=[meta, state, ttl_ms(ttl_s), version],
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
        written = write_payload(state, entry)
        channel = self.live_channel(session_id) if publish is not None else ""
        args: list[Any] = [expected_version, written, ttl_ms(ttl_s), max(track_len, 0)]
        args += [channel, publish or b""]
        args += [allowance.per_s, allowance.burst] if allowance is not None else [0, 0]
        args += ["snapshot" if state is not None else "entry", *kept_fixes(track, track_len)]
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
            yield key_ids(messages)

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
