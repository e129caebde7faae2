"""Zones of a floor over the API: replaced whole from GeoJSON (plain polygons, IMDF
geofences, units and sections, a whole plan whose other features are skipped), read back,
refused with the field named, and seen by a running session within seconds; webhooks are
an admin's, of their site only."""

from __future__ import annotations

from typing import Any

import httpx
import pytest
from fastapi import FastAPI

from server.services.maps import MapCache
from server.services.runtime import Runtime
from tests.support.sessions import open_session, scan
from tests.support.toy_plans import feature_collection as zones
from tests.support.toy_plans import square
from tests.support.toy_site import build_toy_site, device_headers

T0 = 1_700_000_000_000


async def test_zones_are_replaced_whole_and_read_back(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    url = f"/v1/floors/{site.floor_ids[0]}/zones"
    r = await client.get(url, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json() == {
        "type": "FeatureCollection",
        "floor_id": site.floor_ids[0],
        "features": [],
        "skipped": 0,
    }
    sent = zones(
        {
            "type": "Feature",
            "id": "a",
            "properties": {"name": "A", "x": 1},
            "geometry": square(0, 0, 5),
        },
        {
            "type": "Feature",
            "id": "u1",
            "feature_type": "unit",
            "properties": {"category": "shop", "name": {"en": "Shop"}},
            "geometry": square(6, 0, 3),
        },
        {
            "type": "Feature",
            "properties": {"kind": "wall"},
            "geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 1]]},
        },
    )
    r = await client.put(url, json=sent, headers=admin)
    assert r.status_code == 200, r.text
    stored = r.json()
    assert stored["skipped"] == 1
    assert [(f["id"], f["name"]) for f in stored["features"]] == [
        ("a", "A"),
        ("u1", "Shop"),
    ]
    assert stored["features"][0]["properties"] == {"name": "A", "x": 1}
    assert stored["features"][1]["properties"]["name"] == {"en": "Shop"}  # as sent
    r = await client.get(url, headers=admin)
    assert r.json()["features"] == stored["features"]
    # replaced whole
    r = await client.put(url, json=zones(), headers=admin)
    assert r.status_code == 200
    assert (await client.get(url, headers=admin)).json()["features"] == []
    # the other floor's zones are its own
    other = await client.get(f"/v1/floors/{site.floor_ids[1]}/zones", headers=admin)
    assert other.json()["features"] == []


@pytest.mark.parametrize(
    ("body", "field"),
    [
        (
            {
                "type": "FeatureCollection",
                "features": [
                    {
                        "type": "Feature",
                        "geometry": {"type": "Point", "coordinates": [1, 1]},
                        "properties": {"kind": "zone"},
                    }
                ],
            },
            "features.0.geometry.type",
        ),
        (
            {
                "type": "FeatureCollection",
                "features": [
                    {"type": "Feature", "id": "a b", "geometry": square(0, 0, 1), "properties": {}}
                ],
            },
            "features.0.id",
        ),
        ({"type": "Feature"}, "type"),
    ],
)
async def test_a_bad_zone_is_refused_naming_the_field(
    client: httpx.AsyncClient, admin: dict[str, str], body: dict[str, Any], field: str
) -> None:
    site = await build_toy_site(client, admin)
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/zones", json=body, headers=admin)
    assert r.status_code == 422, r.text
    assert field in r.text


async def test_degrees_are_refused_where_the_building_is_geo_referenced(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin, {"origin_lat": 48.85, "origin_lon": 2.35})
    degrees = square(2.35, 48.85, 0.0001)
    body = zones({"type": "Feature", "id": "z", "properties": {}, "geometry": degrees})
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/zones", json=body, headers=admin)
    assert r.status_code == 422, r.text
    assert "features.0.geometry.coordinates" in r.text


async def test_who_may_read_and_write_zones_and_webhooks(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    other = await build_toy_site(client, admin)
    url = f"/v1/floors/{site.floor_ids[0]}/zones"
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    maps_writer = await device_headers(client, admin, ("maps:write",), site.site_id)
    site_admin = await device_headers(client, admin, ("admin",), site.site_id)
    assert (await client.get(url, headers=viewer)).status_code == 200
    assert (await client.put(url, json=zones(), headers=viewer)).status_code == 403
    assert (await client.put(url, json=zones(), headers=maps_writer)).status_code == 200
    assert (await client.put(url, json=zones(), headers=site.device)).status_code == 403
    other_floor = f"/v1/floors/{other.floor_ids[0]}/zones"
    assert (await client.get(other_floor, headers=viewer)).status_code == 404
    missing = "/v1/floors/" + "0" * 32 + "/zones"
    assert (await client.get(missing, headers=admin)).status_code == 404

    hooks = f"/v1/sites/{site.site_id}/webhooks"
    body = {"url": "https://1.1.1.1/hook"}
    assert (await client.post(hooks, json=body, headers=maps_writer)).status_code == 403
    r = await client.post(hooks, json=body, headers=site_admin)
    assert r.status_code == 201, r.text
    hook_id = r.json()["id"]
    other_hooks = f"/v1/sites/{other.site_id}/webhooks"
    assert (await client.get(other_hooks, headers=site_admin)).status_code == 404
    # a webhook is found under its own site only
    r = await client.delete(f"{other_hooks}/{hook_id}", headers=admin)
    assert r.status_code == 404
    assert (
        await client.get(f"{other_hooks}/{hook_id}/deliveries", headers=admin)
    ).status_code == 404
    assert (await client.delete(f"{hooks}/{hook_id}", headers=site_admin)).status_code == 204
    assert (await client.get(hooks, headers=admin)).json()["items"] == []


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"url": "ftp://example.org/x"}, "url"),
        ({"url": "not a url"}, "url"),
        ({"url": "https://1.1.1.1", "events": ["zone.stay"]}, "events"),
        ({"url": "https://1.1.1.1", "events": []}, "events"),
        ({"url": "https://1.1.1.1", "secret": "mine"}, "secret"),
        ({"url": "http://127.0.0.1:8000/hook"}, "url"),  # the service's own network
        ({"url": "https://1.1.1.1/" + "x" * 2000}, "url"),
    ],
)
async def test_a_bad_webhook_is_refused_naming_the_field(
    client: httpx.AsyncClient, admin: dict[str, str], body: dict[str, Any], field: str
) -> None:
    site = await build_toy_site(client, admin)
    r = await client.post(f"/v1/sites/{site.site_id}/webhooks", json=body, headers=admin)
    assert r.status_code == 422, r.text
    assert field in r.text


# map_markov reads its maps through a cache of its own (the floor graphs)
@pytest.mark.parametrize("engine", ["step_ekf", "map_markov"])
async def test_a_running_session_sees_new_zones_and_fixes_name_them(
    client: httpx.AsyncClient, admin: dict[str, str], engine: str
) -> None:
    site = await build_toy_site(client, admin)
    sid, auth = await open_session(client, site, engine)
    url = f"/v1/sessions/{sid}/batches"
    r = await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5)]}, headers=auth)
    assert r.status_code == 200, r.text
    assert r.json()["fixes"][-1]["zones"] == []
    body = zones({"type": "Feature", "id": "hall", "properties": {}, "geometry": square(0, 0, 10)})
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/zones", json=body, headers=admin)
    assert r.status_code == 200, r.text
    seen: list[Any] = []
    for k in range(2, 40):  # standing at (5, 5): in once the dwell time has passed
        r = await client.post(
            url, json={"seq": k, "events": [scan(T0 + 500 * k, 5, 5)]}, headers=auth
        )
        assert r.status_code == 200, r.text
        seen += r.json()["fixes"]
        if seen[-1]["zones"] == ["hall"]:
            break
    assert seen[-1]["zones"] == ["hall"]
    assert [e["type"] for f in seen for e in f["zone_events"]] == ["enter"]
    track = (await client.get(f"/v1/sessions/{sid}/track", headers=auth)).json()["items"]
    assert track[-1]["zones"] == ["hall"]


async def test_locate_says_which_zones_its_position_lies_in(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    body = zones(
        {"type": "Feature", "id": "west", "properties": {}, "geometry": square(0, 0, 10)},
        {"type": "Feature", "id": "east", "properties": {}, "geometry": square(10, 0, 10)},
    )
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/zones", json=body, headers=admin)
    assert r.status_code == 200, r.text
    for x, expected in ((3.0, ["west"]), (17.0, ["east"])):
        scan_body = {"site_id": site.site_id, "wifi": scan(T0, x, 5)["readings"]}
        r = await client.post("/v1/locate", json=scan_body, headers=site.device)
        assert r.status_code == 200, r.text
        assert r.json()["zones"] == expected


async def test_another_replica_sees_new_zones_by_their_version_keeping_its_maps(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> None:
    site = await build_toy_site(client, admin)
    rt: Runtime = app.state.runtime
    replica = MapCache(4)  # another process's cache: the PUT below does not touch it
    async with rt.transaction() as s:
        before = await replica.get(s, site.site_id)
    assert not before.zones
    body = zones({"type": "Feature", "id": "hall", "properties": {}, "geometry": square(0, 0, 10)})
    r = await client.put(f"/v1/floors/{site.floor_ids[1]}/zones", json=body, headers=admin)
    assert r.status_code == 200, r.text
    replica.expire(site.site_id)  # as its VERSION_CHECK_S running out would
    async with rt.transaction() as s:
        after = await replica.get(s, site.site_id)
    assert [(z.floor, z.id) for z in after.zones.zones] == [(1, "hall")]
    assert after.radio is before.radio  # the maps themselves were not loaded again
    assert after.plans is before.plans
