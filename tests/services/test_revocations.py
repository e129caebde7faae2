"""A key that stops working sets the watches of the sockets it opened, in every process
on the same stores (``server.services.revocations``): at once through the store's
channel, and by a lookup when the channel missed it."""

from __future__ import annotations

import asyncio
import dataclasses
import time
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import anyio
import pytest
from fastapi import FastAPI
from redis.asyncio import Redis

from server.services import auth, revocations
from server.services.revocations import KeyWatches
from server.services.runtime import Runtime
from server.storage.redis_session_store import RedisSessionStore
from tests.support.admin_key import ADMIN_KEY
from tests.support.stores import REDIS_URL, redis_or_skip

WITHIN_S = 1.0  # how soon a revocation reaches a watch
QUIET_S = 0.3  # how long a watch that must stay unset is watched
RECONNECT_S = revocations.RETRY_S[0] + 1.5  # the wait, a new subscription and a lookup


def _process(rt: Runtime) -> Runtime:
    """Another api process on the same stores: its own watches."""
    return dataclasses.replace(rt, key_watches=KeyWatches())


@pytest.fixture
def rt(app: FastAPI) -> Runtime:
    runtime: Runtime = app.state.runtime
    return runtime


async def _key(rt: Runtime) -> tuple[str, str]:
    async with rt.transaction() as s:
        row, secret = await auth.create_key(s, "live console", ["viewer"])
    return row.id, secret


async def _set_within(event: anyio.Event, seconds: float = WITHIN_S) -> float:
    """Seconds until ``event`` is set; fails past ``seconds``."""
    start = time.monotonic()
    with anyio.fail_after(seconds):
        await event.wait()
    return time.monotonic() - start


async def _stays_unset(*events: anyio.Event) -> None:
    await anyio.sleep(QUIET_S)
    assert not any(e.is_set() for e in events)


async def test_revoking_reaches_the_watches_of_the_key_in_every_process(rt: Runtime) -> None:
    a, b = _process(rt), _process(rt)
    key_id, secret = await _key(rt)
    _, other = await _key(rt)
    async with (
        revocations.watch(a, secret) as on_a,
        revocations.watch(b, secret) as on_b,
        revocations.watch(b, other) as other_on_b,
        revocations.watch(b, ADMIN_KEY) as admin_on_b,
    ):
        await _stays_unset(on_a, on_b, other_on_b, admin_on_b)
        await revocations.revoke_key(a, key_id)
        await _set_within(on_b)
        await _set_within(on_a)
        await _stays_unset(other_on_b, admin_on_b)  # another key, the configured admin key


async def test_rotating_reaches_the_old_secret_only(rt: Runtime) -> None:
    key_id, old = await _key(rt)
    async with revocations.watch(rt, old) as old_stopped:
        _, new = await revocations.rotate_key(_process(rt), key_id)
        await _set_within(old_stopped)
        async with revocations.watch(rt, new) as new_stopped:
            await revocations.announce(rt, key_id)  # a late message, as from a rotation
            await _stays_unset(new_stopped)


async def test_a_key_revoked_before_its_watch_is_held_is_stopped_at_once(rt: Runtime) -> None:
    key_id, secret = await _key(rt)
    await revocations.revoke_key(rt, key_id)
    async with revocations.watch(rt, secret) as stopped:
        assert stopped.is_set()


async def test_a_key_revoked_between_its_check_and_its_watch_is_stopped(
    rt: Runtime, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The race of a socket: let in, its key revoked in SQL before its watch is held (the
    message lost: nobody listened), then held: the lookup after holding finds it."""
    key_id, secret = await _key(rt)
    holding = KeyWatches.holding

    @asynccontextmanager
    async def revoked_first(
        self: KeyWatches, rt: Runtime, watch: revocations.Watch
    ) -> AsyncIterator[None]:
        async with rt.transaction() as s:
            await auth.revoke_key(s, key_id)
        async with holding(self, rt, watch):
            yield

    monkeypatch.setattr(KeyWatches, "holding", revoked_first)
    async with revocations.watch(rt, secret) as stopped:
        assert stopped.is_set()


async def test_a_revocation_nobody_announced_is_found_by_the_sweep(
    rt: Runtime, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A key revoked in SQL with nothing published (a process without the session store,
    a site deleted with its keys): the periodic lookup closes its sockets."""
    monkeypatch.setattr(revocations, "SWEEP_S", 0.2)
    key_id, secret = await _key(rt)
    async with revocations.watch(rt, secret) as stopped:
        async with rt.transaction() as s:
            await auth.revoke_key(s, key_id)
        await _set_within(stopped, 2.0)


@pytest.fixture
async def named_redis(rt: Runtime) -> AsyncIterator[tuple[Runtime, Redis, str]]:
    """A process whose session store is a Redis of its own connections (named, so a test
    can drop them without touching anyone else's), and a client to drop them with."""
    admin = await redis_or_skip()
    name = f"ips-test-{uuid.uuid4().hex[:8]}"
    store = RedisSessionStore(Redis.from_url(REDIS_URL, client_name=name), prefix=name)
    yield dataclasses.replace(rt, store=store, key_watches=KeyWatches()), admin, name
    await store.close()
    await admin.aclose()


async def _drop_subscriptions(admin: Redis, name: str) -> int:
    """Kill the pub/sub connections named ``name``; how many there were."""
    clients = await admin.client_list(_type="pubsub")
    ids = [c["id"] for c in clients if c.get("name") == name]
    for client_id in ids:
        await admin.client_kill_filter(_id=client_id)
    return len(ids)


async def test_a_revocation_sent_while_the_channel_was_down_is_found_on_reconnect(
    named_redis: tuple[Runtime, Redis, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(revocations, "SWEEP_S", 60.0)  # not the sweep: the lookup on reconnect
    process, admin, name = named_redis
    key_id, secret = await _key(process)
    async with revocations.watch(process, secret) as stopped:
        for _ in range(100):  # the listener subscribes in the background
            if await _drop_subscriptions(admin, name):
                break
            await asyncio.sleep(0.02)
        else:
            pytest.fail("the listener never subscribed")
        # sent while the listener is between connections (it waits RETRY_S[0] first)
        await revocations.revoke_key(process, key_id)
        await _set_within(stopped, RECONNECT_S)
