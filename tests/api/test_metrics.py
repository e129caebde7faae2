"""Prometheus metrics: /metrics, request timing by route template, batch counters, store
errors.

The registry is process-global and other tests move it too, so every check reads a
value before and after and compares the difference.
"""

from __future__ import annotations

import asyncio
import json
import math
import socket
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from prometheus_client import REGISTRY
from redis.asyncio import Redis
from redis.exceptions import ConnectionError as RedisConnectionError
from sqlalchemy.exc import IntegrityError, OperationalError
from websockets.asyncio.client import connect

from server.services import batches as batch_service
from server.services import telemetry
from server.storage.rate_limits import RedisRateLimiter
from server.storage.redis_session_store import RedisSessionStore
from server.storage.upload_queue import RedisUploadQueue
from tests.support.admin_key import ADMIN_KEY
from tests.support.toy_site import ToySite, build_toy_site, rssi_at

T0 = 1_700_000_000_000
BATCH_ROUTE = "/v1/sessions/{session_id}/batches"


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


def value(name: str, **labels: str) -> float:
    """A sample's value, 0 when it does not exist yet."""
    return REGISTRY.get_sample_value(name, labels) or 0.0


def batches(transport: str, outcome: str) -> float:
    return value("indoorpos_batches_total", transport=transport, outcome=outcome)


def requests(route: str, status: str, method: str = "POST") -> float:
    return value(
        "indoorpos_http_request_duration_seconds_count", method=method, route=route, status=status
    )


def route_labels() -> set[str]:
    return {
        sample.labels["route"]
        for metric in REGISTRY.collect()
        for sample in metric.samples
        if "route" in sample.labels
    }


def scan(t: int, x: float, y: float) -> dict[str, Any]:
    return {"type": "wifi", "t": t, "readings": rssi_at(x, y, 0)}


def step(t: int) -> dict[str, Any]:
    return {"type": "step", "t": t, "length_m": 0.7, "heading_rad": math.pi / 2}


async def open_session(client: httpx.AsyncClient, site: ToySite) -> tuple[str, dict[str, str]]:
    r = await client.post(
        "/v1/sessions",
        json={"site_id": site.site_id, "engine": "step_ekf"},
        headers=site.device,
    )
    assert r.status_code == 201, r.text
    return r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}


async def test_metrics_answer_in_the_text_format(client: httpx.AsyncClient) -> None:
    r = await client.get("/metrics")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/plain; version=")
    for name in (
        "indoorpos_batches_total",
        "indoorpos_steps_total",
        "indoorpos_fixes_total",
        "indoorpos_active_sessions",
        "indoorpos_store_errors_total",
    ):
        assert f"# TYPE {name} " in r.text, name
    # no auth, not in the API document, and a scrape does not time itself
    assert "/metrics" not in (await client.get("/openapi.json")).json()["paths"]
    assert "/metrics" not in route_labels()


async def test_an_applied_batch_is_counted_with_its_steps_fixes_and_route_template(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    r = await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth)
    assert r.status_code == 200, r.text

    applied, replayed = batches("http", "applied"), batches("http", "replayed")
    steps, fixes = value("indoorpos_steps_total"), value("indoorpos_fixes_total")
    timed = requests(BATCH_ROUTE, "200")
    engine_runs = value("indoorpos_engine_step_seconds_count", engine="step_ekf")

    r = await client.post(
        url, json={"seq": 2, "events": [step(T0 + 600), step(T0 + 1200)]}, headers=auth
    )
    assert r.status_code == 200, r.text
    assert r.json()["replayed"] is False
    n_fixes = len(r.json()["fixes"])
    assert n_fixes > 0

    assert batches("http", "applied") == applied + 1
    assert batches("http", "replayed") == replayed
    assert value("indoorpos_steps_total") == steps + 2
    assert value("indoorpos_fixes_total") == fixes + n_fixes
    assert requests(BATCH_ROUTE, "200") == timed + 1
    assert value("indoorpos_engine_step_seconds_count", engine="step_ekf") == engine_runs + 1
    labels = route_labels()
    assert BATCH_ROUTE in labels
    assert not any(sid in label for label in labels)


async def test_a_replayed_batch_counts_as_replayed_and_adds_no_steps(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    batch = {"seq": 1, "events": [scan(T0, 5, 5), step(T0 + 600)]}
    assert (await client.post(url, json=batch, headers=auth)).status_code == 200
    applied, replayed = batches("http", "applied"), batches("http", "replayed")
    steps, fixes = value("indoorpos_steps_total"), value("indoorpos_fixes_total")

    again = await client.post(url, json=batch, headers=auth)
    assert again.status_code == 200, again.text
    assert again.json()["replayed"] is True
    assert again.json()["fixes"]

    assert batches("http", "replayed") == replayed + 1
    assert batches("http", "applied") == applied
    assert value("indoorpos_steps_total") == steps
    assert value("indoorpos_fixes_total") == fixes


async def test_failed_and_unmatched_requests_are_timed_by_template(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    refused, unmatched = requests(BATCH_ROUTE, "409"), requests("unmatched", "404", "GET")
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 5, "events": []}, headers=auth
    )
    assert r.status_code == 409  # seq 1 never came
    assert (await client.get(f"/v1/no-such-thing/{sid}")).status_code == 404
    assert requests(BATCH_ROUTE, "409") == refused + 1
    assert requests("unmatched", "404", "GET") == unmatched + 1
    assert not any(sid in label for label in route_labels())


async def test_active_sessions_follow_create_and_delete(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    before = telemetry.active_sessions()
    sid, auth = await open_session(client, site)
    assert value("indoorpos_active_sessions") == telemetry.active_sessions() == before + 1
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": [step(T0)]}, headers=auth
    )
    assert r.status_code == 200, r.text
    assert telemetry.active_sessions() == before + 1  # the same session, seen again
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    assert telemetry.active_sessions() == before
    # a scrape prunes and reports the same number
    text = (await client.get("/metrics")).text
    assert f"indoorpos_active_sessions {float(before)}" in text


async def test_a_session_store_failure_is_counted_and_answered_503(
    app: FastAPI, client: httpx.AsyncClient, site: ToySite, monkeypatch: pytest.MonkeyPatch
) -> None:
    sid, auth = await open_session(client, site)

    async def unreachable(session_id: str) -> None:
        raise RedisConnectionError("Connection refused")

    monkeypatch.setattr(app.state.runtime.store, "get", unreachable)
    errors = value("indoorpos_store_errors_total", store="session")
    r = await client.get(f"/v1/sessions/{sid}", headers=auth)
    assert r.status_code == 503, r.text
    assert r.headers["retry-after"] == "1"
    assert r.json()["detail"][0]["type"] == "StoreUnavailable"
    assert value("indoorpos_store_errors_total", store="session") == errors + 1
    assert requests("/v1/sessions/{session_id}", "503", "GET") >= 1


async def test_an_error_that_is_no_store_failure_stays_a_500(
    app: FastAPI, client: httpx.AsyncClient, site: ToySite, monkeypatch: pytest.MonkeyPatch
) -> None:
    sid, auth = await open_session(client, site)

    async def broken(session_id: str) -> None:
        raise IntegrityError("INSERT ...", {}, Exception("duplicate key"))

    monkeypatch.setattr(app.state.runtime.store, "get", broken)
    stores = ("session", "sql", "queue")
    totals = [value("indoorpos_store_errors_total", store=s) for s in stores]
    with pytest.raises(IntegrityError):  # the in-process client re-raises what the app raised
        await client.get(f"/v1/sessions/{sid}", headers=auth)
    assert [value("indoorpos_store_errors_total", store=s) for s in stores] == totals


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


async def test_store_failures_are_told_apart_by_where_they_were_raised() -> None:
    client = Redis.from_url(f"redis://127.0.0.1:{_closed_port()}/0", socket_connect_timeout=2)
    try:
        with pytest.raises(RedisConnectionError) as from_store:
            await RedisSessionStore(client).get("0" * 32)
        with pytest.raises(RedisConnectionError) as from_queue:
            await RedisUploadQueue(client, visibility_timeout_s=60).publish("0" * 32)
        with pytest.raises(RedisConnectionError) as from_limits:  # a batch's first call
            await RedisRateLimiter(client).take("batches:0", 10.0, 10)
    finally:
        await client.aclose()
    assert telemetry.store_of(from_store.value) == "session"
    assert telemetry.store_of(from_queue.value) == "queue"
    # Redis down is the session store's, not the database's (it was reported as SQL)
    assert telemetry.store_of(from_limits.value) == "session"
    assert telemetry.store_of(OperationalError("SELECT 1", {}, Exception("gone"))) == "sql"
    assert telemetry.store_of(IntegrityError("INSERT", {}, Exception("dup"))) is None
    assert telemetry.store_of(ValueError("not a store")) is None
    with pytest.raises(ConnectionRefusedError) as elsewhere:  # an OSError outside any store
        _refuse()
    assert telemetry.store_of(elsewhere.value) is None


def _refuse() -> None:
    raise ConnectionRefusedError("refused")


async def test_batches_over_the_socket_count_as_ws(
    live_url: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    admin = {"Authorization": f"Bearer {ADMIN_KEY}"}
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, admin)
        sid, auth = await open_session(client, site)
    token = auth["Authorization"].removeprefix("Bearer ")
    ws_url = live_url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"
    applied, replayed = batches("ws", "applied"), batches("ws", "replayed")
    http_applied, steps = batches("http", "applied"), value("indoorpos_steps_total")
    async with connect(ws_url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:

        async def result() -> dict[str, Any]:
            while True:
                message: dict[str, Any] = json.loads(await asyncio.wait_for(ws.recv(), 10))
                if message["type"] in ("batch_result", "error"):
                    return message

        assert json.loads(await asyncio.wait_for(ws.recv(), 10))["type"] == "ready"
        batch = {"type": "batch", "seq": 1, "events": [scan(T0, 5, 5), step(T0 + 600)]}
        await ws.send(json.dumps(batch))
        assert (await result())["replayed"] is False
        await ws.send(json.dumps(batch))
        assert (await result())["replayed"] is True

        # a store failing under the socket is counted, and the socket stays open
        async def unreachable(*args: object) -> None:
            raise RedisConnectionError("Connection refused")

        monkeypatch.setattr(batch_service, "apply_batch", unreachable)
        errors = value("indoorpos_store_errors_total", store="session")
        await ws.send(json.dumps({**batch, "seq": 2}))
        assert (await result())["status"] == 500
        assert value("indoorpos_store_errors_total", store="session") == errors + 1

    assert batches("ws", "applied") == applied + 1
    assert batches("ws", "replayed") == replayed + 1
    assert batches("http", "applied") == http_applied
    assert value("indoorpos_steps_total") == steps + 1
