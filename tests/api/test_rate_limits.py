"""Rate limits: past its allowance a client address, a key or a session gets 429 with
``Retry-After``, on the buckets the replicas share (Redis in the production shape)."""

from __future__ import annotations

import asyncio
import random
from collections.abc import AsyncIterator

import httpx
import pytest
from asgi_lifespan import LifespanManager
from fastapi import FastAPI

from server.app import create_app
from server.config import Settings
from server.storage.rate_limits import MemoryRateLimiter
from tests.support.toy_site import ToySite, build_toy_site, rssi_at

LIMIT = 5


@pytest.fixture(scope="module")
async def limited_app(settings: Settings) -> AsyncIterator[FastAPI]:
    limited = settings.model_copy(
        update={
            "rate_limits": True,
            "rate_sessions_per_min": LIMIT,
            "rate_locate_per_min": LIMIT,
            "rate_batches_per_min": LIMIT,
            "rate_uploads_per_min": LIMIT,
            "rate_auth_failures_per_min": LIMIT,
        }
    )
    application = create_app(limited)
    async with LifespanManager(application):
        yield application


def _client(app: FastAPI) -> httpx.AsyncClient:
    # an address of its own for each test: buckets in Redis outlive a test run
    address = f"10.{random.randrange(256)}.{random.randrange(256)}.{random.randrange(1, 255)}"
    transport = httpx.ASGITransport(app=app, client=(address, 40000))
    return httpx.AsyncClient(transport=transport, base_url="http://test")


@pytest.fixture
async def limited(limited_app: FastAPI) -> AsyncIterator[httpx.AsyncClient]:
    async with _client(limited_app) as c:
        yield c


@pytest.fixture
async def site(limited: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(limited, admin)


def _refused(r: httpx.Response) -> bool:
    if r.status_code != 429:
        return False
    assert int(r.headers["retry-after"]) >= 1
    assert r.json()["message"].startswith("request: too many")
    return True


async def test_sessions_per_address_are_limited(limited: httpx.AsyncClient, site: ToySite) -> None:
    body = {"site_id": site.site_id}
    answers = [
        await limited.post("/v1/sessions", json=body, headers=site.device) for _ in range(LIMIT + 3)
    ]
    assert [r.status_code for r in answers[:LIMIT]] == [201] * LIMIT
    assert all(_refused(r) for r in answers[LIMIT:])


async def test_locate_per_address_is_limited(limited: httpx.AsyncClient, site: ToySite) -> None:
    body = {"site_id": site.site_id, "wifi": rssi_at(3, 3, 0)}
    answers = [
        await limited.post("/v1/locate", json=body, headers=site.device) for _ in range(LIMIT + 2)
    ]
    assert [r.status_code for r in answers[:LIMIT]] == [200] * LIMIT
    assert all(_refused(r) for r in answers[LIMIT:])


async def test_batches_per_session_are_limited(limited_app: FastAPI, admin: dict[str, str]) -> None:
    async with _client(limited_app) as setup:
        site = await build_toy_site(setup, admin)
        r = await setup.post("/v1/sessions", json={"site_id": site.site_id}, headers=site.device)
        sid, token = r.json()["id"], r.json()["token"]
    auth = {"Authorization": f"Bearer {token}"}
    async with _client(limited_app) as phone:
        answers = [
            await phone.post(
                f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": []}, headers=auth
            )
            for seq in range(1, LIMIT + 3)
        ]
    assert [r.status_code for r in answers[:LIMIT]] == [200] * LIMIT
    assert all(_refused(r) for r in answers[LIMIT:])
    # a refused batch was not applied: its seq is still the next one
    async with _client(limited_app) as phone:
        r = await phone.get(f"/v1/sessions/{sid}", headers=auth)
    assert r.json()["last_seq"] == LIMIT


async def test_failed_authentication_is_limited_per_address(
    limited: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    wrong = {"Authorization": "Bearer wrong-key"}
    answers = [await limited.get("/v1/sites", headers=wrong) for _ in range(LIMIT + 3)]
    assert [r.status_code for r in answers[:LIMIT]] == [401] * LIMIT
    assert all(_refused(r) for r in answers[LIMIT:])
    # while barred, nothing from the address is looked at: not a session token, and not
    # the right key either
    r = await limited.get(f"/v1/sessions/{'0' * 32}", headers=wrong)
    assert _refused(r)
    assert _refused(await limited.get("/v1/sites", headers=admin))
    # nor a body of a bulk route, whatever its key and size
    big = b'{"points": [' + b" " * (8 * 1024 * 1024) + b"]}"
    r = await limited.put(
        f"/v1/floors/{'0' * 32}/plan",
        content=big,
        headers={**wrong, "content-type": "application/json"},
    )
    assert _refused(r)


async def test_wrong_session_tokens_count_as_failures(
    limited: httpx.AsyncClient, site: ToySite
) -> None:
    wrong = {"Authorization": "Bearer wrong-token"}
    answers = [
        await limited.get(f"/v1/sessions/{'0' * 32}", headers=wrong) for _ in range(LIMIT + 1)
    ]
    assert [r.status_code for r in answers[:LIMIT]] == [403] * LIMIT
    assert _refused(answers[LIMIT])


async def test_a_stranger_cannot_spend_a_sessions_batch_allowance(
    limited_app: FastAPI, admin: dict[str, str]
) -> None:
    async with _client(limited_app) as setup:
        site = await build_toy_site(setup, admin)
        r = await setup.post("/v1/sessions", json={"site_id": site.site_id}, headers=site.device)
        sid, token = r.json()["id"], r.json()["token"]
    async with _client(limited_app) as stranger:
        for _ in range(LIMIT):
            r = await stranger.post(
                f"/v1/sessions/{sid}/batches",
                json={"seq": 1, "events": []},
                headers={"Authorization": "Bearer not-the-token"},
            )
            assert r.status_code == 403
    async with _client(limited_app) as phone:
        r = await phone.post(
            f"/v1/sessions/{sid}/batches",
            json={"seq": 1, "events": []},
            headers={"Authorization": f"Bearer {token}"},
        )
    assert r.status_code == 200, r.text


async def test_a_bucket_refills_over_time() -> None:
    limiter = MemoryRateLimiter()
    assert await limiter.take("b", per_s=1000.0, burst=1) is None
    wait = await limiter.take("b", per_s=1000.0, burst=1)
    assert wait is not None
    assert 0 < wait <= 0.001
    await asyncio.sleep(0.005)
    assert await limiter.take("b", per_s=1000.0, burst=1) is None


async def test_the_memory_limiter_forgets_the_least_recently_used_bucket() -> None:
    limiter = MemoryRateLimiter(max_buckets=2)
    for name in ("a", "b"):
        assert await limiter.take(name, per_s=0.001, burst=1) is None
    assert await limiter.take("a", per_s=0.001, burst=1) is not None  # a used again, empty
    assert await limiter.take("c", per_s=0.001, burst=1) is None  # b is forgotten
    assert await limiter.peek("a", per_s=0.001, burst=1) is not None  # a was kept
    assert await limiter.take("b", per_s=0.001, burst=1) is None  # b comes back full
