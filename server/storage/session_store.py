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

- ``redis_session_store.RedisSessionStore`` (production): one hash per session at
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
- ``memory_session_store.MemorySessionStore`` (embedded mode, tests): a dict in the event
  loop's thread.

Pub/sub is fire-and-forget in both: a subscriber sees the messages published after its
subscription went live, none from before, and nothing is replayed after a reconnect.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Sequence
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass
from typing import Protocol


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


def ttl_ms(ttl_s: int) -> int:
    """The expiry in whole milliseconds; a non-positive TTL is a caller bug, not a delete."""
    if ttl_s <= 0:
        raise ValueError(f"ttl_s must be positive, got {ttl_s}")
    return int(ttl_s * 1000)


def write_payload(state: bytes | None, entry: bytes | None) -> bytes:
    """What a write stores: a snapshot or a log entry, exactly one of them."""
    if state is not None and entry is None:
        return bytes(state)
    if entry is not None and state is None:
        return bytes(entry)
    raise ValueError("a write stores a snapshot or a log entry, exactly one of them")


def kept_fixes(track: Sequence[bytes], track_len: int) -> list[bytes]:
    """What of ``track`` can stay on a track of ``track_len`` entries."""
    return [bytes(b) for b in track[-track_len:]] if track_len > 0 else []


async def key_ids(messages: AsyncIterator[bytes]) -> AsyncIterator[str]:
    """The API key ids of the revoked channel's messages."""
    async for message in messages:
        yield message.decode()
