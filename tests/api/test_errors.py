"""One error shape for everything the service refuses, bodies bounded, no session probing."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Any

import httpx
import pytest

from tests.support.sessions import open_session, step
from tests.support.toy_site import ToySite, build_toy_site, device_headers

T0 = 1_700_000_000_000
JSON = {"content-type": "application/json"}


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


def assert_shape(r: httpx.Response, status: int, field: str) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/json")
    body: dict[str, Any] = r.json()
    assert body["message"].startswith(f"{field}: "), body
    assert body["detail"][0]["loc"] == field.split(".")
    return body


async def test_unknown_route_and_wrong_method_answer_in_the_api_shape(
    client: httpx.AsyncClient,
) -> None:
    assert_shape(await client.get("/v1/no-such-thing"), 404, "path")
    assert_shape(await client.put("/v1/sessions"), 405, "method")


@pytest.mark.parametrize(
    ("path", "allowed"),
    [
        ("/v1/sessions", {"GET", "POST"}),  # a route per method at one path
        ("/v1/sessions/" + "0" * 32, {"GET", "DELETE"}),
        ("/healthz", {"GET"}),
    ],
)
async def test_a_wrong_method_lists_every_method_of_the_path(
    client: httpx.AsyncClient, path: str, allowed: set[str]
) -> None:
    r = await client.patch(path)
    assert_shape(r, 405, "method")
    assert {m.strip() for m in r.headers["allow"].split(",")} == allowed


@pytest.mark.parametrize(
    "raw",
    [b"\xff\xfe not utf-8", b"[" * 1000 + b"]" * 1000, b'{"site_id": '],
    ids=["bad-utf8", "deep-nesting", "truncated"],
)
async def test_an_unparseable_body_names_the_body(
    client: httpx.AsyncClient, admin: dict[str, str], raw: bytes
) -> None:
    r = await client.post("/v1/sessions", content=raw, headers={**admin, **JSON})
    assert r.status_code in (400, 422), r.text
    body = r.json()
    assert body["message"].startswith("body"), body


async def test_a_declared_large_body_is_refused_before_it_is_read(
    client: httpx.AsyncClient, app: Any
) -> None:
    limit = app.state.runtime.settings.json_max_bytes
    big = b'{"site_id": "' + b"a" * limit + b'"}'
    r = await client.post("/v1/sessions", content=big, headers={"content-type": "application/json"})
    assert_shape(r, 413, "body")


async def test_a_chunked_large_body_is_cut_off_at_the_limit(
    client: httpx.AsyncClient, app: Any, admin: dict[str, str]
) -> None:
    limit = app.state.runtime.settings.json_max_bytes
    sent = 0

    async def chunks() -> AsyncIterator[bytes]:
        nonlocal sent
        yield b'{"site_id": "'
        for _ in range(4 * limit // 65536):
            sent += 65536
            yield b"a" * 65536
        yield b'"}'

    r = await client.post("/v1/sessions", content=chunks(), headers={**admin, **JSON})
    assert_shape(r, 413, "body")


async def test_a_batch_under_the_limit_still_passes(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    # 2,000 steps: about 150 KB, far below the device limit
    events = [step(T0 + 600 * i) for i in range(2000)]
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": events}, headers=auth
    )
    assert r.status_code == 200, r.text


async def test_a_missing_session_and_a_wrong_token_get_the_same_answer(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    wrong = {"Authorization": "Bearer not-the-token"}
    missing = "0" * 32
    answers = [
        await client.get(f"/v1/sessions/{sid}", headers=wrong),
        await client.get(f"/v1/sessions/{missing}", headers=auth),
        await client.post(
            f"/v1/sessions/{missing}/batches", json={"seq": 1, "events": []}, headers=auth
        ),
        await client.delete(f"/v1/sessions/{missing}", headers=auth),
    ]
    bodies = [assert_shape(r, 403, "authorization") for r in answers]
    assert all(b == bodies[0] for b in bodies)


@pytest.mark.parametrize(
    ("batch", "field"),
    [
        ({"seq": "1", "events": []}, "seq"),
        ({"seq": True, "events": []}, "seq"),
        ({"seq": 1.0, "events": []}, "seq"),
        ({"seq": 1, "events": [{**step(T0), "t": "1700000000000"}]}, "t"),
        ({"seq": 1, "events": [{**step(T0), "length_m": "0.7"}]}, "length_m"),
        ({"seq": 1, "events": [{**step(T0), "length_m": True}]}, "length_m"),
    ],
)
async def test_numbers_are_not_coerced_from_strings_or_booleans(
    client: httpx.AsyncClient, site: ToySite, batch: dict[str, Any], field: str
) -> None:
    sid, auth = await open_session(client, site)
    r = await client.post(f"/v1/sessions/{sid}/batches", json=batch, headers=auth)
    assert r.status_code == 422, r.text
    assert field in r.json()["message"]
    # an integer where a float is asked stays fine
    ok = {"seq": 1, "events": [{**step(T0), "length_m": 1}]}
    assert (
        await client.post(f"/v1/sessions/{sid}/batches", json=ok, headers=auth)
    ).status_code == 200


async def test_a_floor_level_must_be_an_integer(
    client: httpx.AsyncClient, site: ToySite, admin: dict[str, str]
) -> None:
    url = f"/v1/buildings/{site.building_id}/floors"
    for level in (True, "3", 3.0):
        r = await client.post(url, json={"level": level, "name": "x"}, headers=admin)
        assert r.status_code == 422, (level, r.text)
        assert "level" in r.json()["message"]


@pytest.mark.parametrize("model", ["Pixel\x1b[31m", "Pixel\x9b31m", "Pixel\n7", "x" * 129])
async def test_device_model_is_plain_short_text(
    client: httpx.AsyncClient, site: ToySite, model: str
) -> None:
    r = await client.post(
        "/v1/sessions",
        json={"site_id": site.site_id, "device_model": model},
        headers=site.device,
    )
    assert r.status_code == 422, r.text
    assert "device_model" in r.json()["message"]


async def test_the_bulk_body_size_is_only_for_a_key_the_route_lets_in(
    client: httpx.AsyncClient, app: Any, admin: dict[str, str]
) -> None:
    limit = app.state.runtime.settings.json_max_bytes
    big = b'{"points": [' + b" " * limit + b"]}"
    url = f"/v1/buildings/{'0' * 32}/survey"
    viewer = await device_headers(client, admin, ("viewer",))
    cases = [
        ({}, 401, "authorization"),  # no key: never read
        ({"Authorization": "Bearer wrong"}, 401, "authorization"),
        (viewer, 403, "authorization"),  # a key without the route's scope
    ]
    for headers, status, field in cases:
        r = await client.post(url, content=big, headers={**headers, **JSON})
        assert_shape(r, status, field)
    # an admin key's body is read whole, past the device limit, and judged
    r = await client.post(url, content=big, headers={**admin, **JSON})
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("points: ")


async def test_a_malformed_session_id_is_refused_before_the_body_is_read(
    client: httpx.AsyncClient,
) -> None:
    r = await client.post(
        "/v1/sessions/xyz/batches",
        content=b"not json at all",
        headers={"Authorization": "Bearer nope", **JSON},
    )
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["message"].startswith("session_id: "), body
    assert len(body["detail"]) == 1  # the path alone: the body was never looked at
