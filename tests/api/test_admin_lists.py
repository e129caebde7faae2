"""Lists page with ``limit`` and an opaque ``cursor``: every item once across the pages,
in the documented order, and a bad ``limit`` or ``cursor`` is a 422 naming it."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from tests.support.toy_site import ToySite, build_toy_site, device_headers, walk_upload


async def walk(
    client: httpx.AsyncClient,
    url: str,
    headers: dict[str, str],
    limit: int,
    params: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Every item of a list, page after page; checks the shape of each page."""
    items: list[dict[str, Any]] = []
    cursor = None
    for _ in range(10_000):
        query = {**(params or {}), "limit": limit} | ({"cursor": cursor} if cursor else {})
        r = await client.get(url, params=query, headers=headers)
        assert r.status_code == 200, r.text
        page = r.json()
        assert set(page) == {"items", "count", "next_cursor"}
        assert page["count"] == len(page["items"]) <= limit
        items += page["items"]
        cursor = page["next_cursor"]
        if cursor is None:
            return items
        assert page["count"] == limit  # only the last page may be short
    pytest.fail("the pages never ended")


def ids(items: list[dict[str, Any]]) -> list[str]:
    return [x["id"] for x in items]


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def test_floors_page_by_level_and_a_new_floor_does_not_repeat_one(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    r = await client.post("/v1/sites", json={"name": "tower"}, headers=admin)
    site_id = r.json()["id"]
    r = await client.post(f"/v1/sites/{site_id}/buildings", json={"name": "T"}, headers=admin)
    url = f"/v1/buildings/{r.json()['id']}/floors"
    made = {}
    for level in (3, -1, 0, 7, 1):
        r = await client.post(url, json={"level": level}, headers=admin)
        made[level] = r.json()["id"]
    got = await walk(client, url, admin, limit=2)
    assert [f["level"] for f in got] == [-1, 0, 1, 3, 7]
    assert ids(got) == [made[level] for level in sorted(made)]
    # a floor added below the first page while a client pages on: the cursor holds the
    # last level seen, so nothing comes twice
    first = (await client.get(url, params={"limit": 2}, headers=admin)).json()
    await client.post(url, json={"level": -3}, headers=admin)
    rest = await walk(client, url, admin, limit=2, params={"cursor": first["next_cursor"]})
    assert [f["level"] for f in first["items"] + rest] == [-1, 0, 1, 3, 7]


async def test_every_site_comes_once_newest_first(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    made = []
    for i in range(5):
        r = await client.post("/v1/sites", json={"name": f"paged {i}"}, headers=admin)
        made.append(r.json()["id"])
    got = await walk(client, "/v1/sites", admin, limit=3)
    assert len(ids(got)) == len(set(ids(got)))
    assert ids(got)[:5] == made[::-1]  # nothing was made after them
    stamps = [x["created_at"] for x in got]
    assert stamps == sorted(stamps, reverse=True)
    # a key of one site sees its own only
    viewer = await device_headers(client, admin, ("viewer",), made[2])
    assert ids(await walk(client, "/v1/sites", viewer, limit=1)) == [made[2]]


async def test_buildings_page_oldest_first(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    r = await client.post("/v1/sites", json={"name": "campus"}, headers=admin)
    url = f"/v1/sites/{r.json()['id']}/buildings"
    made = [
        (await client.post(url, json={"name": f"B{i}"}, headers=admin)).json()["id"]
        for i in range(4)
    ]
    assert ids(await walk(client, url, admin, limit=3)) == made


async def test_keys_page_newest_first(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    made = []
    for i in range(3):
        r = await client.post(
            "/v1/keys", json={"name": f"k{i}", "scopes": ["viewer"]}, headers=admin
        )
        made.append(r.json()["id"])
    revoked = made[1]
    assert (await client.delete(f"/v1/keys/{revoked}", headers=admin)).status_code == 204
    live = ids(await walk(client, "/v1/keys", admin, limit=50))
    assert len(live) == len(set(live))
    assert live[:2] == [made[2], made[0]]
    everything = ids(
        await walk(client, "/v1/keys", admin, limit=50, params={"include_revoked": True})
    )
    assert everything[:3] == made[::-1]


async def test_sessions_list_by_site_and_activity(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    made = []
    for _ in range(3):
        r = await client.post("/v1/sessions", json={"site_id": site.site_id}, headers=site.device)
        made.append(r.json())
    ended = made[0]
    r = await client.delete(
        f"/v1/sessions/{ended['id']}", headers={"Authorization": f"Bearer {ended['token']}"}
    )
    assert r.status_code == 204
    url, by_site = "/v1/sessions", {"site_id": site.site_id}
    every = await walk(client, url, admin, limit=1, params=by_site)
    assert ids(every) == [m["id"] for m in made[::-1]]
    assert [s["active"] for s in every] == [True, True, False]
    assert every[-1]["ended_at"] is not None
    assert all("token" not in s for s in every)
    active = await walk(client, url, admin, limit=5, params={**by_site, "active": True})
    assert ids(active) == [made[2]["id"], made[1]["id"]]
    gone = await walk(client, url, admin, limit=5, params={**by_site, "active": "false"})
    assert ids(gone) == [ended["id"]]
    # a viewer key of the site sees them; of another site, none (as of a site that does
    # not exist); a device key may not list
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    assert ids(await walk(client, url, viewer, limit=5)) == ids(every)
    other = await build_toy_site(client, admin)
    stranger = await device_headers(client, admin, ("viewer",), other.site_id)
    r = await client.get(url, params=by_site, headers=stranger)
    assert r.status_code == 200, r.text
    assert r.json()["items"] == []
    assert (await client.get(url, headers=site.device)).status_code == 403


async def test_uploads_list_by_site_newest_first(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    made = []
    for i in range(3):
        r = await client.post(
            "/v1/uploads",
            params={"site_id": site.site_id},
            json=walk_upload(2.0 + i),
            headers=admin,
        )
        assert r.status_code == 202, r.text
        made.append(r.json()["id"])
    got = await walk(client, "/v1/uploads", admin, limit=2, params={"site_id": site.site_id})
    assert ids(got) == made[::-1]
    assert {u["site_id"] for u in got} == {site.site_id}
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    assert ids(await walk(client, "/v1/uploads", viewer, limit=10)) == made[::-1]
    r = await client.get("/v1/uploads", params={"status": "lost"}, headers=admin)
    assert r.status_code == 422
    assert "status" in r.json()["message"]


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"limit": 0}, "limit"),
        ({"limit": 1001}, "limit"),
        ({"limit": "ten"}, "limit"),
        ({"cursor": "not a cursor"}, "cursor"),
        ({"cursor": "W10"}, "cursor"),  # base64 of []
        ({"cursor": ""}, "cursor"),
        ({"cursor": "x" * 600}, "cursor"),
    ],
)
async def test_bad_limit_or_cursor_is_422_naming_it(
    client: httpx.AsyncClient,
    admin: dict[str, str],
    site: ToySite,
    params: dict[str, Any],
    field: str,
) -> None:
    for url in (
        "/v1/sites",
        f"/v1/buildings/{site.building_id}/floors",
        "/v1/keys",
        "/v1/uploads",
        "/v1/sessions",
    ):
        r = await client.get(url, params=params, headers=admin)
        assert r.status_code == 422, (url, r.text)
        assert r.json()["message"].startswith(f"{field}:"), (url, r.text)


async def test_a_cursor_of_another_list_is_refused(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    url = f"/v1/buildings/{site.building_id}/floors"
    cursor = (await client.get(url, params={"limit": 1}, headers=admin)).json()["next_cursor"]
    assert cursor is not None
    r = await client.get("/v1/sites", params={"cursor": cursor}, headers=admin)
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["cursor"]
    assert "another list" in r.json()["message"]
