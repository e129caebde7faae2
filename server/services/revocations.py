"""Telling every replica that an API key stopped working, and ending what it keeps open.

A revoked or rotated key fails every later request at once (each one authenticates in
SQL), but a live socket authenticates once, when it opens. So:

- once the transaction that revokes or rotates a key has committed, :func:`announce`
  publishes the key's id on the session store's channel of revoked keys
  (``SessionStore.publish_revoked``; Redis, Redis Cluster or in memory);
- each process keeps, per key id, the :class:`Watch` of every socket it holds that was
  opened with that key (:func:`watch`, in :class:`KeyWatches`), and while it holds any
  listens to that channel; a message makes it look the key up in SQL and set the
  ``revoked`` event of each watch whose secret no longer works (a rotated key's new
  secret does: a socket opened with it stays);
- pub/sub is fire-and-forget: a message sent while a process's subscription was down is
  lost, and a publish may fail after the commit. So a process also looks up every key it
  watches each time its subscription (re)starts, and every ``SWEEP_S`` seconds: the net
  for what the channel cannot tell (a connection that died without an error, a key
  revoked by a process without the session store, a site deleted with its keys).
  One indexed read per process per ``SWEEP_S``, and only while it holds sockets of keys.

The configured admin key (``INDOORPOS_ADMIN_KEY``, key id None) cannot be revoked: it is
not watched. Nor are session tokens: an ended session closes its sockets itself.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
from collections.abc import AsyncIterator, Iterable
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from dataclasses import dataclass, field
from typing import Protocol

import anyio
from sqlalchemy.ext.asyncio import AsyncSession

from server.config import Settings
from server.services import auth, telemetry
from server.storage.models import ApiKey
from server.storage.repositories import api_keys as key_repo
from server.storage.session_store import SessionStore

SWEEP_S = 5.0  # how often a process looks up the keys it watches, whatever the channel says
RETRY_S = (0.5, 10.0)  # first and longest wait before subscribing again after a failure
STOP_WAIT_S = 5.0  # how long the last watch to leave waits for the listener to stop
logger = logging.getLogger(__name__)


class WatchingRuntime(Protocol):
    """What watching keys needs of the process's runtime (``runtime.Runtime``, which holds
    this module's ``KeyWatches``): SQL sessions, the session store (its key channel), the
    settings and the watches."""

    settings: Settings
    store: SessionStore
    key_watches: KeyWatches

    def read(self) -> AbstractAsyncContextManager[AsyncSession]: ...
    def transaction(self) -> AbstractAsyncContextManager[AsyncSession]: ...


@dataclass(eq=False)
class Watch:
    """One socket's key: its id and the digest of the secret it was opened with."""

    key_id: str
    key_hash: str
    revoked: anyio.Event = field(default_factory=anyio.Event)


class KeyWatches:
    """The watches of one process (``Runtime.key_watches``) and the task that serves them: it
    runs while there is any watch (subscribed to the channel, and sweeping)."""

    def __init__(self) -> None:
        self._by_key: dict[str, set[Watch]] = {}
        self._listener: asyncio.Task[None] | None = None

    @asynccontextmanager
    async def holding(self, rt: WatchingRuntime, watch: Watch) -> AsyncIterator[None]:
        """Hold ``watch`` within the block. The channel need not be subscribed yet: the
        listener looks up every held key once its subscription is live, so a key revoked
        before then is found too (after then, the message tells)."""
        self._by_key.setdefault(watch.key_id, set()).add(watch)
        try:
            if self._listener is None:
                # a context of its own: not the log context of the socket that started it
                self._listener = asyncio.create_task(
                    self._listen(rt), name="key-watches", context=contextvars.Context()
                )
            yield
        finally:
            held = self._by_key.get(watch.key_id, set())
            held.discard(watch)
            if not held:
                self._by_key.pop(watch.key_id, None)
            if not self._by_key:
                with anyio.CancelScope(shield=True):
                    await self.close()

    async def close(self) -> None:
        """Stop the listener (a new watch starts another)."""
        listener, self._listener = self._listener, None
        if listener is not None:
            listener.cancel()
            await asyncio.wait([listener], timeout=STOP_WAIT_S)

    async def check(self, rt: WatchingRuntime, watches: Iterable[Watch]) -> None:
        """Set ``revoked`` on each of ``watches`` whose secret no longer works. A failed
        read is logged: the next sweep reads again."""
        pending = [w for w in watches if not w.revoked.is_set()]
        if not pending:
            return
        try:
            async with rt.read() as s:
                live = await key_repo.live_key_hashes(s, {w.key_id for w in pending})
        except Exception as exc:
            telemetry.count_store_error(exc)
            logger.warning("could not look up the keys of live sockets", exc_info=True)
            return
        for w in pending:
            if (w.key_id, w.key_hash) not in live:
                w.revoked.set()

    def _all(self) -> list[Watch]:
        return [w for held in self._by_key.values() for w in held]

    async def _listen(self, rt: WatchingRuntime) -> None:
        async with anyio.create_task_group() as tg:
            tg.start_soon(self._sweep, rt)
            await self._follow(rt)

    async def _sweep(self, rt: WatchingRuntime) -> None:
        while True:
            await anyio.sleep(SWEEP_S)
            await self.check(rt, self._all())

    async def _follow(self, rt: WatchingRuntime) -> None:
        wait_s = RETRY_S[0]
        while True:
            try:
                async with rt.store.subscribe_revoked() as key_ids:
                    wait_s = RETRY_S[0]
                    await self.check(rt, self._all())  # what was sent before we listened
                    async for key_id in key_ids:
                        await self.check(rt, list(self._by_key.get(key_id, ())))
            except Exception as exc:  # Redis unreachable, a dropped connection
                telemetry.count_store_error(exc)
                logger.warning(
                    "the channel of revoked keys is down (%s); again in %.1f s, and the "
                    "keys of live sockets are looked up every %.0f s",
                    exc,
                    wait_s,
                    SWEEP_S,
                )
            await anyio.sleep(wait_s)
            wait_s = min(2 * wait_s, RETRY_S[1])


@asynccontextmanager
async def watch(rt: WatchingRuntime, secret: str) -> AsyncIterator[anyio.Event]:
    """Within the block, an event set once the API key ``secret`` stops working (revoked
    or rotated, through any replica), never for the configured admin key. ``secret`` is a
    key that was let in just before: if it was revoked since, the event is set at once
    (looked up again once the watch is held, so no revocation falls in between)."""
    async with rt.read() as s:
        principal = await auth.authenticate(s, rt.settings, secret)
    if principal is None or principal.key_id is None:
        stopped = anyio.Event()
        if principal is None:
            stopped.set()
        yield stopped
        return
    held = Watch(principal.key_id, auth.digest(secret))
    async with rt.key_watches.holding(rt, held):
        await rt.key_watches.check(rt, [held])
        yield held.revoked


async def announce(rt: WatchingRuntime, key_id: str) -> None:
    """Tell every replica that key ``key_id`` stopped working; call it after the commit.
    A failed publish is logged, not raised: the key is revoked either way, and the sweeps
    close within ``SWEEP_S`` what the message would have."""
    try:
        await rt.store.publish_revoked(key_id)
    except Exception as exc:
        telemetry.count_store_error(exc)
        logger.warning("could not announce that key %s stopped working", key_id, exc_info=True)


async def revoke_key(rt: WatchingRuntime, key_id: str) -> ApiKey:
    """Revoke a key (``auth.revoke_key``), then close the sockets it opened."""
    async with rt.transaction() as s:
        row = await auth.revoke_key(s, key_id)
    await announce(rt, key_id)
    return row


async def rotate_key(rt: WatchingRuntime, key_id: str) -> tuple[ApiKey, str]:
    """Give a key a new secret (``auth.rotate_key``), then close the sockets its old
    secret opened."""
    async with rt.transaction() as s:
        found = await auth.rotate_key(s, key_id)
    await announce(rt, key_id)
    return found
