"""API keys: scopes decide what a key may do, a site key stays on its site, keys can be
listed (never their secrets), revoked and rotated."""

from __future__ import annotations

import httpx
import pytest

from tests.support.toy_site import ToySite, build_toy_site, device_headers, rssi_at


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def _calls(
    client: httpx.AsyncClient, site: ToySite, headers: dict[str, str]
) -> dict[str, int]:
    """The status of one call of each kind, made with ``headers``."""
    floor = site.floor_ids[0]
    survey = {"points": [{"x_m": 1.0, "y_m": 1.0, "floor": 0, "wifi": rssi_at(1, 1, 0)}]}
    magnetic = {"points": [{"x_m": 1.0, "y_m": 1.0, "magnitude_ut": 48.0}]}
    calls = {
        "read floors": client.get(f"/v1/buildings/{site.building_id}/floors", headers=headers),
        "read quality": client.get(f"/v1/floors/{floor}/maps/quality", headers=headers),
        "survey": client.post(
            f"/v1/buildings/{site.building_id}/survey", json=survey, headers=headers
        ),
        "magnetic survey": client.post(
            f"/v1/floors/{floor}/magnetic-survey", json=magnetic, headers=headers
        ),
        "create site": client.post("/v1/sites", json={"name": "x"}, headers=headers),
        "list keys": client.get("/v1/keys", headers=headers),
        "open session": client.post(
            "/v1/sessions", json={"site_id": site.site_id}, headers=headers
        ),
        "locate": client.post(
            "/v1/locate", json={"site_id": site.site_id, "wifi": rssi_at(3, 3, 0)}, headers=headers
        ),
    }
    return {name: (await call).status_code for name, call in calls.items()}


@pytest.mark.parametrize(
    ("scopes", "allowed"),
    [
        (("viewer",), {"read floors", "read quality"}),
        (("maps:write",), {"read floors", "read quality", "survey", "magnetic survey"}),
        (("device",), {"open session", "locate"}),
        (
            ("admin",),
            {
                "read floors",
                "read quality",
                "survey",
                "magnetic survey",
                "create site",
                "list keys",
                "open session",
                "locate",
            },
        ),
    ],
)
async def test_a_key_does_what_its_scopes_allow_and_nothing_else(
    client: httpx.AsyncClient,
    admin: dict[str, str],
    site: ToySite,
    scopes: tuple[str, ...],
    allowed: set[str],
) -> None:
    headers = await device_headers(client, admin, scopes)
    statuses = await _calls(client, site, headers)
    for name, status in statuses.items():
        if name in allowed:
            assert status < 400, (name, status)
        else:
            assert status == 403, (name, status)


async def test_a_site_key_stays_on_its_site(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    other = await build_toy_site(client, admin)
    headers = await device_headers(client, admin, ("viewer", "device"), site.site_id)
    mine = await _calls(client, site, headers)
    assert mine["read floors"] == 200
    assert mine["open session"] == 201
    # another site's things answer as things that do not exist
    theirs = await _calls(client, other, headers)
    assert theirs["read floors"] == 404
    assert theirs["read quality"] == 404
    assert theirs["open session"] == 404
    assert theirs["locate"] == 404
    listed = (await client.get("/v1/sites", headers=headers)).json()
    assert [s["id"] for s in listed["items"]] == [site.site_id]


async def test_keys_are_listed_revoked_and_rotated(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    r = await client.post(
        "/v1/keys",
        json={"name": "kiosk", "scopes": ["device"], "site_id": site.site_id},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    made = r.json()
    key_id, secret = made["id"], made["key"]
    assert made["scopes"] == ["device"]
    listed = (await client.get("/v1/keys", headers=admin)).json()["items"]
    mine = [k for k in listed if k["id"] == key_id]
    assert mine
    assert "key" not in mine[0]
    assert secret not in (await client.get("/v1/keys", headers=admin)).text

    async def session_with(key: str) -> httpx.Response:
        return await client.post(
            "/v1/sessions",
            json={"site_id": site.site_id},
            headers={"Authorization": f"Bearer {key}"},
        )

    assert (await session_with(secret)).status_code == 201
    r = await client.post(f"/v1/keys/{key_id}:rotate", headers=admin)
    assert r.status_code == 200, r.text
    rotated = r.json()["key"]
    assert rotated != secret
    assert r.json()["rotated_at"] is not None
    assert (await session_with(secret)).status_code == 401
    assert (await session_with(rotated)).status_code == 201
    assert (await client.delete(f"/v1/keys/{key_id}", headers=admin)).status_code == 204
    assert (await session_with(rotated)).status_code == 401
    assert (await client.delete(f"/v1/keys/{key_id}", headers=admin)).status_code == 404
    listed = (await client.get("/v1/keys", headers=admin)).json()["items"]
    assert key_id not in [k["id"] for k in listed]
    everything = (await client.get("/v1/keys?include_revoked=true", headers=admin)).json()
    assert key_id in [k["id"] for k in everything["items"]]


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"name": "x", "scopes": ["root"]}, "scopes.0"),
        ({"name": "x", "scopes": []}, "scopes"),
        ({"name": "x", "scopes": ["device"], "site_id": "0" * 32}, "site_id"),
    ],
)
async def test_bad_key_requests_name_the_field(
    client: httpx.AsyncClient, admin: dict[str, str], body: dict[str, object], field: str
) -> None:
    r = await client.post("/v1/keys", json=body, headers=admin)
    assert r.status_code in (404, 422), r.text
    assert r.json()["message"].startswith(f"{field}: ")


async def test_a_site_admin_cannot_reach_beyond_its_site(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    site_admin = await device_headers(client, admin, ("admin",), site.site_id)
    r = await client.post("/v1/keys", json={"name": "x", "scopes": ["admin"]}, headers=site_admin)
    assert r.status_code == 403, r.text
    assert (await client.get("/v1/keys", headers=site_admin)).status_code == 403
    assert (
        await client.post("/v1/sites", json={"name": "x"}, headers=site_admin)
    ).status_code == 403
    # its own site it runs
    r = await client.post(
        f"/v1/buildings/{site.building_id}/floors", json={"level": 7}, headers=site_admin
    )
    assert r.status_code == 201, r.text
