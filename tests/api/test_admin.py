"""Admin API: keys required, sites/buildings/floors, plans, surveys and radio map versions."""

from __future__ import annotations

import httpx
import pytest

from tests.support.toy_site import build_toy_site, rssi_at, toy_plan


@pytest.mark.parametrize(
    ("method", "path"),
    [
        ("GET", "/v1/sites"),
        ("POST", "/v1/sites"),
        ("GET", "/v1/buildings/x/floors"),
        ("POST", "/v1/buildings/x/survey"),
    ],
)
async def test_admin_calls_need_a_key(client: httpx.AsyncClient, method: str, path: str) -> None:
    r = await client.request(method, path, json={"name": "x"})
    assert r.status_code == 401
    assert "authorization" in r.json()["message"]
    r = await client.request(
        method, path, json={"name": "x"}, headers={"Authorization": "Bearer wrong"}
    )
    assert r.status_code == 401


async def test_site_building_floor_round_trip(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    r = await client.post("/v1/sites", json={"name": "Mall"}, headers=admin)
    assert r.status_code == 201
    site = r.json()
    listed = (await client.get("/v1/sites", headers=admin)).json()
    assert site["id"] in [s["id"] for s in listed["items"]]
    assert listed["count"] == len(listed["items"])
    assert (await client.get(f"/v1/sites/{site['id']}", headers=admin)).json() == site

    r = await client.post(
        f"/v1/sites/{site['id']}/buildings",
        json={"name": "North", "origin_lat": 41.0, "origin_lon": 2.0, "rotation_rad": 0.1},
        headers=admin,
    )
    assert r.status_code == 201
    building = r.json()
    assert building["site_id"] == site["id"]
    assert (await client.get(f"/v1/buildings/{building['id']}", headers=admin)).json() == building

    r = await client.post(
        f"/v1/buildings/{building['id']}/floors", json={"level": -1, "name": "B1"}, headers=admin
    )
    assert r.status_code == 201
    floor = r.json()
    assert floor["has_plan"] is False
    dup = await client.post(
        f"/v1/buildings/{building['id']}/floors", json={"level": -1}, headers=admin
    )
    assert dup.status_code == 409
    assert "level" in dup.json()["message"]

    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"kind": "walkable"},
                "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [5, 0], [5, 5], [0, 0]]]},
            }
        ],
    }
    r = await client.put(f"/v1/floors/{floor['id']}/plan", json=plan, headers=admin)
    assert r.status_code == 200
    assert r.json()["has_plan"] is True
    assert (await client.get(f"/v1/floors/{floor['id']}/plan", headers=admin)).json() == plan


async def test_missing_things_are_404_naming_the_field(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    unknown = "0" * 32
    r = await client.get(f"/v1/sites/{unknown}", headers=admin)
    assert r.status_code == 404
    assert "site_id" in r.json()["message"]
    r = await client.post(f"/v1/buildings/{unknown}/floors", json={"level": 0}, headers=admin)
    assert r.status_code == 404
    assert "building_id" in r.json()["message"]
    # something that cannot be an id of ours is refused before any lookup
    for bad in ("nope", "%00", "a" * 33):
        r = await client.get(f"/v1/sites/{bad}", headers=admin)
        assert r.status_code == 422
        assert "site_id" in r.json()["message"]


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"name": "a\u0000b"}, "name"),
        ({"name": "\ud800"}, "name"),
        ({"name": ""}, "name"),
    ],
)
async def test_bad_names_are_422(
    client: httpx.AsyncClient, admin: dict[str, str], body: dict[str, str], field: str
) -> None:
    import json

    raw = json.dumps(body)  # \u escapes: the control character arrives as such
    r = await client.post(
        "/v1/sites", content=raw, headers={**admin, "content-type": "application/json"}
    )
    assert r.status_code == 422, r.text
    assert field in r.json()["message"]


async def test_survey_errors_name_the_reading(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    url = f"/v1/buildings/{site.building_id}/survey"
    body = {
        "points": [{"x_m": 0, "y_m": 0, "floor": 0, "wifi": [{"bssid": "a b", "rssi_dbm": -50}]}]
    }
    r = await client.post(url, json=body, headers=admin)
    assert r.status_code == 422
    assert "points.0.wifi.0.bssid" in r.json()["message"]
    far = {"points": [{"x_m": 1e39, "y_m": 0, "floor": 0}]}
    r = await client.post(url, json=far, headers=admin)
    assert r.status_code == 422
    assert "points.0.x_m" in r.json()["message"]
    late = {"points": [{"x_m": 0, "y_m": 0, "floor": 0, "t": 2**63}]}
    r = await client.post(url, json=late, headers=admin)
    assert r.status_code == 422
    assert "points.0.t" in r.json()["message"]
    # the field goes into the magnetic map: a calibrated magnetometer's, within ±500 µT
    for field_ut in ([1e308, 0, 0], [0, 0, -501]):
        odd = {"points": [{"x_m": 0, "y_m": 0, "floor": 0, "mag_ut": field_ut}]}
        r = await client.post(url, json=odd, headers=admin)
        assert r.status_code == 422, r.text
        axis = 0 if field_ut[0] else 2
        assert r.json()["message"].startswith(f"points.0.mag_ut.{axis}: "), r.json()


async def test_a_survey_point_must_lie_on_its_floor_plan(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    """As magnetic surveys: a point farther than 10 m outside its floor's plan is refused,
    naming the coordinate, and nothing of the survey is stored; a floor without a plan
    takes any point in the coordinate range."""
    site = await build_toy_site(client, admin)
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/plan", json=toy_plan(), headers=admin)
    assert r.status_code == 200, r.text
    url = f"/v1/buildings/{site.building_id}/survey"
    versions = f"/v1/buildings/{site.building_id}/radio-maps"
    before = (await client.get(versions, headers=admin)).json()["count"]
    near = {"x_m": 29.5, "y_m": -9.5, "floor": 0, "wifi": rssi_at(19, 0, 0)}  # within 10 m
    for far, field in (
        ({**near, "x_m": 1000.0}, "points.2.x_m"),
        ({**near, "x_m": -10.5}, "points.2.x_m"),
        ({**near, "y_m": 20.5}, "points.2.y_m"),
        ({**near, "x_m": 1000.0, "y_m": -1000.0}, "points.2.x_m"),
    ):
        body = {"points": [near, {**near, "floor": 1, "x_m": 1000.0}, far, far]}
        r = await client.post(url, json=body, headers=admin)
        assert r.status_code == 422, r.text
        assert r.json()["message"].startswith(f"{field}: "), r.json()
        assert "outside the floor plan" in r.json()["message"]
    assert (await client.get(versions, headers=admin)).json()["count"] == before
    # level 1 has no plan: bounded by the coordinate range alone
    body = {"points": [near, {**near, "floor": 1, "x_m": 1000.0}]}
    r = await client.post(url, json=body, headers=admin)
    assert r.status_code == 201, r.text
    assert r.json()["version"] == before + 1


async def test_survey_builds_new_versions(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    site = await build_toy_site(client, admin)
    maps = (await client.get(f"/v1/buildings/{site.building_id}/radio-maps", headers=admin)).json()
    assert maps["count"] == 1
    first = maps["items"][0]
    assert first["version"] == 1
    assert first["n_survey_points"] == 2 * 21 * 11
    assert first["n_reference_points"] == 2 * 21 * 11  # 1 m cells, one point each
    assert first["n_emitters"] == 16

    extra = {
        "points": [{"x_m": 0.2, "y_m": 0.2, "floor": 0, "ble": [{"id": "b1", "rssi_dbm": -70}]}]
    }
    r = await client.post(f"/v1/buildings/{site.building_id}/survey", json=extra, headers=admin)
    assert r.status_code == 201
    second = r.json()
    assert second["version"] == 2
    assert second["n_survey_points"] == first["n_survey_points"] + 1
    assert second["n_reference_points"] == first["n_reference_points"]  # merged into a cell
    assert second["n_emitters"] == 17


async def test_survey_on_unknown_level_names_the_point(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    body = {"points": [{"x_m": 0, "y_m": 0, "floor": 0}, {"x_m": 1, "y_m": 1, "floor": 7}]}
    r = await client.post(f"/v1/buildings/{site.building_id}/survey", json=body, headers=admin)
    assert r.status_code == 422
    assert "points.1.floor" in r.json()["message"]


async def test_locate_finds_the_surveyed_point(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    body = {"site_id": site.site_id, "wifi": rssi_at(12, 3, 1)}
    assert (await client.post("/v1/locate", json=body)).status_code == 401
    r = await client.post("/v1/locate", json=body, headers=site.device)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["floor"] == 1
    assert body["floor_id"] == site.floor_ids[1]
    assert abs(body["x_m"] - 12) < 1.0
    assert abs(body["y_m"] - 3) < 1.0
    r = await client.post("/v1/locate", json={"site_id": site.site_id}, headers=site.device)
    assert r.status_code == 422
    r = await client.post(
        "/v1/locate",
        json={"site_id": site.site_id, "wifi": [{"bssid": "ff:ff", "rssi_dbm": -50}]},
        headers=site.device,
    )
    assert r.status_code == 422
    assert "wifi" in r.json()["message"]


async def test_health(client: httpx.AsyncClient) -> None:
    assert (await client.get("/healthz")).json() == {"status": "ok"}
    r = await client.get("/readyz")
    assert r.status_code == 200
    assert r.json() == {"status": "ok"}


async def test_concurrent_admin_writes_conflict_or_take_turns(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    import asyncio

    site = await build_toy_site(client, admin)
    floors = await asyncio.gather(
        *(
            client.post(
                f"/v1/buildings/{site.building_id}/floors", json={"level": 9}, headers=admin
            )
            for _ in range(4)
        )
    )
    assert sorted(r.status_code for r in floors) == [201, 409, 409, 409]
    point = {
        "points": [{"x_m": 3.0, "y_m": 3.0, "floor": 0, "wifi": [{"bssid": "aa", "rssi_dbm": -50}]}]
    }
    surveys = await asyncio.gather(
        *(
            client.post(f"/v1/buildings/{site.building_id}/survey", json=point, headers=admin)
            for _ in range(4)
        )
    )
    assert [r.status_code for r in surveys] == [201] * 4
    versions = sorted(r.json()["version"] for r in surveys)
    assert versions == [2, 3, 4, 5]
    counts = sorted(r.json()["n_survey_points"] for r in surveys)
    first = counts[0]
    assert counts == [first, first + 1, first + 2, first + 3]  # each saw the ones before
