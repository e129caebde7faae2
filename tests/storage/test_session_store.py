"""The session store contract, run against the in-memory store and a real Redis.

Redis comes from ``INDOORPOS_REDIS_URL`` (default database 15 on localhost). It is skipped
when unreachable, unless ``INDOORPOS_TEST_REQUIRE_REDIS=1``, which turns that into a failure.
"""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, TypeVar

import pytest
import redis.exceptions
from redis.asyncio import Redis
from redis.asyncio.cluster import RedisCluster

from server.storage.memory_session_store import MemorySessionStore
from server.storage.redis_client import redis_client
from server.storage.redis_session_store import RedisSessionStore
from server.storage.session_store import (
    Allowance,
    BucketEmpty,
    SessionExists,
    SessionStore,
    StoredSession,
)
from tests.support.stores import REDIS_URL, redis_or_skip

TTL_S = 60
WAIT_S = 2.0  # upper bound for any single message to arrive
PREFIX = f"ips-test-{uuid.uuid4().hex[:8]}"  # keys of this run only, never the app's
T = TypeVar("T")


async def _redis_store() -> RedisSessionStore:
    return RedisSessionStore(await redis_or_skip(), prefix=PREFIX)


class FakeClock:
    """Monotonic time for the in-memory store, so its TTL tests need not wait."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    async def sleep(self, seconds: float) -> None:
        self.now += seconds
        await asyncio.sleep(0)


Sleep = Callable[[float], Awaitable[None]]


@pytest.fixture(params=["memory", "redis", "cluster"])
async def backend(request: pytest.FixtureRequest) -> AsyncIterator[tuple[SessionStore, Sleep]]:
    if request.param == "memory":
        clock = FakeClock()
        store: SessionStore = MemorySessionStore(clock=clock)
        sleep: Sleep = clock.sleep
    elif request.param == "cluster":
        url = request.getfixturevalue("redis_cluster_url")
        store, sleep = RedisSessionStore(redis_client(url), prefix=PREFIX), asyncio.sleep
    else:
        store, sleep = await _redis_store(), asyncio.sleep
    yield store, sleep
    await store.close()


@pytest.fixture
def store(backend: tuple[SessionStore, Sleep]) -> SessionStore:
    return backend[0]


@pytest.fixture
def sleep(backend: tuple[SessionStore, Sleep]) -> Sleep:
    """Wait for the store's clock: real time for Redis, a fake clock for memory."""
    return backend[1]


@pytest.fixture
async def new_id(store: SessionStore) -> AsyncIterator[Callable[..., str]]:
    """Make a session id (a fresh uuid unless given); deleted from the store at teardown."""
    made: list[str] = []

    def make(session_id: str | None = None) -> str:
        made.append(session_id if session_id is not None else uuid.uuid4().hex)
        return made[-1]

    yield make
    for session_id in made:
        await store.delete(session_id)


async def test_create_then_get(store: SessionStore, new_id: Callable[..., str]) -> None:
    sid = new_id()
    assert await store.get(sid) is None
    await store.create(sid, b"meta\x00\xff", b"state-1", TTL_S)
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.meta, stored.state) == (1, b"meta\x00\xff", b"state-1")


async def test_create_twice_raises(store: SessionStore, new_id: Callable[..., str]) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s", TTL_S)
    with pytest.raises(SessionExists):
        await store.create(sid, b"other", b"other", TTL_S)
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.meta, stored.state) == (1, b"m", b"s")


async def test_compare_and_set(store: SessionStore, new_id: Callable[..., str]) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s1", TTL_S)
    assert await store.compare_and_set(sid, 1, b"s2", TTL_S)
    assert await store.compare_and_set(sid, 2, b"", TTL_S)
    assert not await store.compare_and_set(sid, 2, b"stale", TTL_S)
    assert not await store.compare_and_set(sid, 4, b"future", TTL_S)
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.meta, stored.state) == (3, b"m", b"")


async def test_get_changed_sends_the_record_only_when_it_changed(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()
    assert await store.get_changed(sid, 1) is None
    await store.create(sid, b"m", b"s1", TTL_S)
    assert await store.get_changed(sid, 1) == 1
    assert await store.get_changed(sid, 7) == StoredSession(1, b"m", b"s1")
    assert await store.compare_and_set(sid, 1, b"s2", TTL_S)
    assert await store.get_changed(sid, 1) == StoredSession(2, b"m", b"s2")
    assert await store.get_changed(sid, 2) == 2
    await store.delete(sid)
    assert await store.get_changed(sid, 2) is None


async def test_a_write_takes_from_the_sessions_bucket_or_changes_nothing(
    store: SessionStore, new_id: Callable[..., str], sleep: Sleep
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s1", TTL_S)
    allowance = Allowance(per_s=10.0, burst=2)  # two writes, then one every 0.1 s
    assert await store.compare_and_set(sid, 1, b"s2", TTL_S, allowance=allowance)
    assert await store.compare_and_set(sid, 2, b"s3", TTL_S, allowance=allowance)
    with pytest.raises(BucketEmpty) as refused:
        await store.compare_and_set(sid, 3, b"s4", TTL_S, b"live", [b"f"], 5, allowance)
    assert 0 < refused.value.wait_s <= 0.1
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.state) == (3, b"s3")
    assert await store.track(sid, 5) == []
    assert await store.compare_and_set(sid, 3, b"s4", TTL_S)  # without the allowance: written
    await sleep(0.15)
    assert await store.compare_and_set(sid, 4, b"s5", TTL_S, allowance=allowance)
    # a stale version is told apart from an empty bucket, and takes nothing
    assert not await store.compare_and_set(sid, 4, b"stale", TTL_S, allowance=allowance)


async def test_entries_go_on_the_log_until_the_next_snapshot(
    store: SessionStore, new_id: Callable[..., str], sleep: Sleep
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"snap-1", TTL_S)
    assert await store.compare_and_set(sid, 1, None, TTL_S, entry=b"e2")
    assert await store.compare_and_set(sid, 2, None, TTL_S, entry=b"e3\x00\xff")
    assert not await store.compare_and_set(sid, 2, None, TTL_S, entry=b"stale")
    stored = await store.get(sid)
    assert stored == StoredSession(3, b"m", b"snap-1", (b"e2", b"e3\x00\xff"))
    assert await store.get_changed(sid, 3) == 3
    assert await store.get_changed(sid, 2) == stored
    # a snapshot empties the log
    assert await store.compare_and_set(sid, 3, b"snap-4", TTL_S)
    assert await store.get(sid) == StoredSession(4, b"m", b"snap-4", ())
    assert await store.compare_and_set(sid, 4, None, TTL_S, entry=b"e5")
    # the log expires with the record, and a record made again starts with none
    assert await store.delete(sid)
    await store.create(sid, b"m2", b"snap-new", TTL_S)
    assert await store.get(sid) == StoredSession(1, b"m2", b"snap-new", ())
    with pytest.raises(ValueError, match="exactly one"):
        await store.compare_and_set(sid, 1, b"both", TTL_S, entry=b"both")
    with pytest.raises(ValueError, match="exactly one"):
        await store.compare_and_set(sid, 1, None, TTL_S)


async def test_the_log_expires_with_its_record(
    store: SessionStore, new_id: Callable[..., str], sleep: Sleep
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s", 1)
    assert await store.compare_and_set(sid, 1, None, 1, entry=b"e2")
    await sleep(1.2)
    assert await store.get(sid) is None
    await store.create(sid, b"m", b"s", TTL_S)
    assert await store.get(sid) == StoredSession(1, b"m", b"s", ())


async def test_compare_and_set_on_a_missing_session(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()
    assert not await store.compare_and_set(sid, 1, b"s", TTL_S)
    assert await store.get(sid) is None


async def test_concurrent_writers_exactly_one_wins(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s1", TTL_S)
    writers = [f"writer-{i}".encode() for i in range(8)]
    results = await asyncio.gather(
        *(store.compare_and_set(sid, 1, state, TTL_S) for state in writers)
    )
    assert sum(results) == 1
    stored = await store.get(sid)
    assert stored is not None
    assert stored.version == 2
    assert stored.state == writers[results.index(True)]


async def test_ttl_expiry_and_failed_write_does_not_refresh(
    store: SessionStore, new_id: Callable[..., str], sleep: Sleep
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s", 1)
    await sleep(0.5)
    assert await store.get(sid) is not None
    assert not await store.compare_and_set(sid, 7, b"stale", 60)  # must not extend the TTL
    await sleep(0.6)
    assert await store.get(sid) is None
    assert not await store.compare_and_set(sid, 1, b"late", 60)
    await store.create(sid, b"again", b"s", TTL_S)  # an expired id is free again
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.meta) == (1, b"again")


async def test_successful_write_refreshes_ttl(
    store: SessionStore, new_id: Callable[..., str], sleep: Sleep
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s", 1)
    await sleep(0.5)
    assert await store.compare_and_set(sid, 1, b"s2", 2)
    await sleep(1.0)  # past the first TTL, within the refreshed one
    stored = await store.get(sid)
    assert stored is not None
    assert stored.state == b"s2"


async def test_non_positive_ttl_is_refused(store: SessionStore, new_id: Callable[..., str]) -> None:
    sid = new_id()
    with pytest.raises(ValueError, match="ttl_s"):
        await store.create(sid, b"m", b"s", 0)
    await store.create(sid, b"m", b"s", TTL_S)
    with pytest.raises(ValueError, match="ttl_s"):
        await store.compare_and_set(sid, 1, b"s", -1)
    assert await store.get(sid) is not None


async def test_delete(store: SessionStore, new_id: Callable[..., str]) -> None:
    sid, other = new_id(), new_id()
    await store.create(sid, b"m", b"s", TTL_S)
    await store.create(other, b"m", b"s", TTL_S)
    assert await store.delete(sid)
    assert not await store.delete(sid)
    assert await store.get(sid) is None
    assert not await store.compare_and_set(sid, 1, b"s", TTL_S)
    assert await store.get(other) is not None


async def test_compare_and_set_keeps_the_newest_fixes_on_the_track(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s1", TTL_S)
    assert await store.track(sid, 10) == []
    assert await store.compare_and_set(sid, 1, b"s2", TTL_S, track=[b"f1", b"f2"], track_len=3)
    assert await store.compare_and_set(sid, 2, b"s3", TTL_S, track=[b"f3", b"f4"], track_len=3)
    assert await store.track(sid, 10) == [b"f2", b"f3", b"f4"]  # capped at 3, oldest first
    assert await store.track(sid, 2) == [b"f3", b"f4"]
    # a batch of more fixes than the track holds keeps its newest only
    batch = [f"g{i}".encode() for i in range(7)]
    assert await store.compare_and_set(sid, 3, b"s4", TTL_S, track=batch, track_len=3)
    assert await store.track(sid, 10) == batch[-3:]
    # a lost write pushes nothing; a write without fixes, or with no track kept, neither
    assert not await store.compare_and_set(sid, 1, b"stale", TTL_S, track=[b"lost"], track_len=3)
    assert await store.compare_and_set(sid, 4, b"s5", TTL_S, track_len=3)
    assert await store.compare_and_set(sid, 5, b"s6", TTL_S, track=[b"off"], track_len=0)
    assert await store.track(sid, 10) == batch[-3:]
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.state) == (6, b"s6")


async def test_track_goes_with_its_session(
    store: SessionStore, new_id: Callable[..., str], sleep: Sleep
) -> None:
    sid, other = new_id(), new_id()
    for session_id in (sid, other):
        await store.create(session_id, b"m", b"s", TTL_S)
        assert await store.compare_and_set(session_id, 1, b"s", TTL_S, track=[b"f"], track_len=5)
    assert await store.delete(sid)
    assert await store.track(sid, 5) == []
    assert await store.track(other, 5) == [b"f"]  # another session's track is its own
    await store.create(sid, b"m", b"s", TTL_S)  # the id again: a new, empty track
    assert await store.track(sid, 5) == []
    # the track expires with the record, and a write refreshes both
    assert await store.compare_and_set(sid, 1, b"s", 1, track=[b"f1"], track_len=5)
    await sleep(0.6)
    assert await store.compare_and_set(sid, 2, b"s", 1)  # no fixes, the track lives on
    await sleep(0.6)
    assert await store.track(sid, 5) == [b"f1"]
    await sleep(0.6)
    assert await store.get(sid) is None
    assert await store.track(sid, 5) == []


async def _next(messages: AsyncIterator[T]) -> T:
    async with asyncio.timeout(WAIT_S):
        return await anext(messages)


async def test_publish_subscribe(store: SessionStore, new_id: Callable[..., str]) -> None:
    sid, other = new_id(), new_id()
    sent = [f"m{i}".encode() for i in range(5)]
    async with store.subscribe(sid) as first:
        async with store.subscribe(sid) as second:
            for message in sent:
                await store.publish(sid, message)
            await store.publish(other, b"not for us")
            assert [await _next(first) for _ in sent] == sent
            assert [await _next(second) for _ in sent] == sent
        # second unsubscribed: it gets nothing more, first still does
        await store.publish(sid, b"after")
        assert await _next(first) == b"after"
        assert [m async for m in second] == []
    assert [m async for m in first] == []
    if isinstance(store, RedisSessionStore):
        await _assert_no_subscribers(store, sid)


async def test_compare_and_set_publishes_only_what_it_writes(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()
    await store.create(sid, b"m", b"s1", TTL_S)
    async with store.subscribe(sid) as messages:
        assert not await store.compare_and_set(sid, 5, b"stale", TTL_S, publish=b"lost")
        assert await store.compare_and_set(sid, 1, b"s2", TTL_S, publish=b"fix 1")
        assert await store.compare_and_set(sid, 2, b"s3", TTL_S)  # nothing to publish
        await store.publish(sid, b"marker")
        assert await _next(messages) == b"fix 1"
        assert await _next(messages) == b"marker"  # neither "lost" nor an empty message
    stored = await store.get(sid)
    assert stored is not None
    assert (stored.version, stored.state) == (3, b"s3")


async def _assert_no_subscribers(store: RedisSessionStore, session_id: str) -> None:
    """Redis drops a closed subscription when it sees the connection go, soon after."""
    channel = store.live_channel(session_id)
    client = Redis.from_url(REDIS_URL, decode_responses=False)
    try:
        for _ in range(200):
            if (await client.pubsub_numsub(channel))[0][1] == 0:
                return
            await asyncio.sleep(0.01)
        pytest.fail(f"{channel} still has subscribers")
    finally:
        await client.aclose()


async def test_subscription_is_live_on_enter(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()
    for i in range(3):
        async with store.subscribe(sid) as messages:
            await store.publish(sid, f"first-{i}".encode())
            assert await _next(messages) == f"first-{i}".encode()


async def test_cancelled_reader_unsubscribes(
    store: SessionStore, new_id: Callable[..., str]
) -> None:
    sid = new_id()

    async def read_forever() -> None:
        async with store.subscribe(sid) as messages:
            async for _ in messages:
                pass

    task = asyncio.create_task(read_forever())
    await asyncio.sleep(0.1)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    if isinstance(store, RedisSessionStore):
        await _assert_no_subscribers(store, sid)
    async with store.subscribe(sid) as messages:
        await store.publish(sid, b"still works")
        assert await _next(messages) == b"still works"


async def _replica(store: SessionStore, request: pytest.FixtureRequest) -> SessionStore | None:
    """Another process's store on the same backend (None in memory: one process)."""
    backend = request.node.callspec.params["backend"]
    if backend == "memory":
        return None
    url = request.getfixturevalue("redis_cluster_url") if backend == "cluster" else REDIS_URL
    return RedisSessionStore(redis_client(url), prefix=PREFIX)


async def test_revoked_keys_reach_every_subscriber_in_every_process(
    store: SessionStore, request: pytest.FixtureRequest
) -> None:
    other = await _replica(store, request) or store
    try:
        await store.publish_revoked("before")  # nobody listens: lost
        async with store.subscribe_revoked() as here, other.subscribe_revoked() as there:
            await store.publish_revoked("k1")
            await other.publish_revoked("k2")
            assert [await _next(here), await _next(here)] == ["k1", "k2"]
            assert [await _next(there), await _next(there)] == ["k1", "k2"]
        async with other.subscribe_revoked() as late:
            await store.publish_revoked("k3")
            assert await _next(late) == "k3"
    finally:
        if other is not store:
            await other.close()


async def _drop_pubsub_connections(url: str, name: str | None) -> int:
    """Kill the pub/sub connections (those named ``name`` when given) on every node of
    the Redis at ``url``; how many there were."""
    client = redis_client(url, decode_responses=True)
    try:
        if isinstance(client, RedisCluster):
            await client.initialize()
        nodes = client.get_nodes() if isinstance(client, RedisCluster) else [None]
        killed = 0
        for node in nodes:
            kwargs: dict[str, Any] = {"target_nodes": node} if node is not None else {}
            for listed in await client.client_list(_type="pubsub", **kwargs):
                if name is None or listed.get("name") == name:
                    await client.client_kill_filter(_id=listed["id"], **kwargs)
                    killed += 1
        return killed
    finally:
        await client.aclose()


@pytest.mark.parametrize("kind", ["redis", "cluster"])
async def test_a_broken_subscription_to_revoked_keys_raises(
    kind: str, request: pytest.FixtureRequest
) -> None:
    """Messages sent while the connection was down are lost: the subscriber is told,
    even when redis-py reconnected by itself (a cluster node's client retries)."""
    if kind == "cluster":
        # the run's own cluster: every pub/sub connection on it is this test's
        url, name = request.getfixturevalue("redis_cluster_url"), None
        store = RedisSessionStore(redis_client(url), prefix=PREFIX)
    else:  # a shared Redis: only this store's connections, by their name
        await (await redis_or_skip()).aclose()
        url, name = REDIS_URL, f"{PREFIX}-{uuid.uuid4().hex[:8]}"
        store = RedisSessionStore(Redis.from_url(url, client_name=name), prefix=PREFIX)
    try:
        async with store.subscribe_revoked() as key_ids:
            assert await _drop_pubsub_connections(url, name) == 1
            with pytest.raises((ConnectionError, redis.exceptions.ConnectionError)):
                async with asyncio.timeout(5.0):  # a cluster node's client waits up to 2 s
                    await anext(key_ids)
        async with store.subscribe_revoked() as key_ids:  # subscribing again works
            await store.publish_revoked("k")
            assert await _next(key_ids) == "k"
    finally:
        await store.close()


ODD_IDS = ["a", "a}", "{a", "a}:state:v1", "a:b", "*", "?", "[x]", "with space", "ü€", "x\ny"]


async def test_odd_session_ids_stay_in_their_own_keys(
    store: SessionStore, new_id: Callable[..., str], request: pytest.FixtureRequest
) -> None:
    run = uuid.uuid4().hex
    ids = [new_id(f"{run}{odd}") for odd in ODD_IDS] + [new_id(f"{odd}{run}") for odd in ODD_IDS]
    for sid in ids:
        await store.create(sid, sid.encode(), sid.encode(), TTL_S)
    for sid in ids:
        stored = await store.get(sid)
        assert stored is not None
        assert stored.meta == stored.state == sid.encode()
    assert await store.compare_and_set(ids[0], 1, b"changed", TTL_S)
    assert await store.delete(ids[1])
    for sid in ids[2:]:
        stored = await store.get(sid)
        assert stored is not None
        assert (stored.version, stored.state) == (1, sid.encode())
    if isinstance(store, RedisSessionStore):
        on_cluster = request.node.callspec.params["backend"] == "cluster"
        url = request.getfixturevalue("redis_cluster_url") if on_cluster else REDIS_URL
        client = redis_client(url)  # every node's keys, on a cluster
        try:
            keys = {k async for k in client.scan_iter(match=f"{PREFIX}:*{run}*")}
        finally:
            await client.aclose()
        assert keys == {store.state_key(sid).encode() for sid in ids if sid != ids[1]}
        # the track is in the session's slot too (one script writes state and track)
        assert await store.compare_and_set(ids[2], 1, b"s", TTL_S, track=[b"f"], track_len=1)
        assert await store.track(ids[2], 1) == [b"f"]


async def test_ping(store: SessionStore) -> None:
    await store.ping()


# --- in-memory specifics --------------------------------------------------------------------


async def test_memory_slow_subscriber_drops_oldest() -> None:
    store = MemorySessionStore(queue_size=3)
    async with store.subscribe("s") as messages:
        for i in range(5):
            await store.publish("s", f"m{i}".encode())  # never blocks
        assert [await _next(messages) for _ in range(3)] == [b"m2", b"m3", b"m4"]


async def test_memory_sweep_drops_expired_records() -> None:
    now = [0.0]
    store = MemorySessionStore(clock=lambda: now[0])
    for i in range(10):
        await store.create(f"s{i}", b"m", b"s", 10)
    await store.create("long", b"m", b"s", 10_000)
    now[0] = 5_000.0
    assert await store.get("long") is not None
    assert list(store._records) == ["long"]
