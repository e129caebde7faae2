"""Where to survey a floor: the placement plan answered as GeoJSON points (on the toy
floor of the map-quality tests: 20 m x 10 m, a pillar, the west half surveyed)."""

from __future__ import annotations

import httpx
import numpy as np

from server.positioning.plan.floor_plan import walkable_at
from server.positioning.plan.geojson_plan import plan_from_geojson
from tests.support.quality_floor import PLAN, new_site


async def test_plan_of_a_surveyed_floor(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    r = await client.get(f"/v1/floors/{floor}/maps/placement", headers=admin)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["type"] == "FeatureCollection"
    summary = body["properties"]
    assert summary["floor_id"] == floor
    assert summary["noise_source"] == "map"
    assert 1.0 < summary["noise_db"] < 4.0  # the survey's 2 dB shadowing, give or take
    assert summary["n_access_points"] >= 4
    xy = np.array([f["geometry"]["coordinates"] for f in body["features"]])
    assert summary["n_points"] == len(xy) > 0
    assert walkable_at(plan_from_geojson(PLAN), xy).all()
    rules = {f["properties"]["rule"] for f in body["features"]}
    assert rules <= {"ap_line", "coverage"}
    assert "ap_line" in rules
    surveyed_x = [
        f["geometry"]["coordinates"][0] for f in body["features"] if f["properties"]["surveyed"]
    ]
    # only the west half was surveyed (and the upload's point at x = 15.5)
    assert summary["n_surveyed"] == len(surveyed_x) > 0
    assert all(x < 11 or abs(x - 15.5) <= 1.5 for x in surveyed_x)
    assert 0 <= summary["expected_error_m"] <= summary["expected_error_p90_m"] < 10


async def test_a_given_noise_distance_and_bad_input(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, empty = surveyed
    dense = await client.get(f"/v1/floors/{floor}/maps/placement?noise_distance_m=2", headers=admin)
    sparse = await client.get(
        f"/v1/floors/{floor}/maps/placement?noise_distance_m=6", headers=admin
    )
    assert dense.status_code == sparse.status_code == 200
    assert dense.json()["properties"]["noise_source"] == "given"
    assert dense.json()["properties"]["n_points"] > 2 * sparse.json()["properties"]["n_points"]
    r = await client.get(f"/v1/floors/{floor}/maps/placement?noise_distance_m=0", headers=admin)
    assert r.status_code == 422
    assert "noise_distance_m" in r.text
    # level 1 has no plan and no reference points of its own
    r = await client.get(f"/v1/floors/{empty}/maps/placement", headers=admin)
    assert r.status_code == 422
    assert "floor_id" in r.text
    r = await client.get(f"/v1/floors/{'0' * 32}/maps/placement", headers=admin)
    assert r.status_code == 404


async def test_a_floor_without_a_plan_is_planned_over_its_reference_points(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    _, building, floors = await new_site(client, admin)
    points = [
        {
            "x_m": x + 0.5,
            "y_m": 0.5,
            "floor": 0,
            "wifi": [{"bssid": "02:00:00:00:00:01", "rssi_dbm": -40.0 - x}],
        }
        for x in range(12)
    ]
    r = await client.post(
        f"/v1/buildings/{building}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/floors/{floors[0]}/maps/placement", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["properties"]["n_points"] > 0
