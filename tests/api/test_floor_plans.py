"""Floor plans through the API: a wrong plan is refused with 422 naming the feature and
the property, and the floor keeps the plan it had; IMDF-style units and openings are
stored with the kinds they map to."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

ORIGIN = {"origin_lat": 41.39, "origin_lon": 2.17}  # a geo-referenced building


def _box(x0: float, y0: float, x1: float, y1: float) -> list[list[list[float]]]:
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


def _feature(geometry_type: str, coordinates: Any, **properties: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": properties,
        "geometry": {"type": geometry_type, "coordinates": coordinates},
    }


def _plan(*features: dict[str, Any]) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": list(features)}


FLOOR = _feature("Polygon", _box(0, 0, 20, 10), kind="walkable")
GOOD = _plan(FLOOR, _feature("LineString", [[10, 0], [10, 10]], kind="wall"))


async def _floor(client: httpx.AsyncClient, admin: dict[str, str], building: dict[str, Any]) -> str:
    r = await client.post("/v1/sites", json={"name": "plans"}, headers=admin)
    site_id = r.json()["id"]
    body = {"name": "b", **building}
    r = await client.post(f"/v1/sites/{site_id}/buildings", json=body, headers=admin)
    building_id = r.json()["id"]
    r = await client.post(f"/v1/buildings/{building_id}/floors", json={"level": 0}, headers=admin)
    assert r.status_code == 201, r.text
    floor_id: str = r.json()["id"]
    return floor_id


@pytest.mark.parametrize(
    ("building", "plan", "field"),
    [
        pytest.param(
            {},
            _plan(FLOOR, _feature("Polygon", _box(2, 2, 4, 4))),
            "features.1.properties.kind",
            id="polygon without a kind",
        ),
        pytest.param(
            {},
            _plan(_feature("Polygon", [[[0, 0], [10, 10]]], kind="walkable")),
            "features.0.geometry.coordinates.0",
            id="two-point ring",
        ),
        pytest.param(
            {},
            _plan(_feature("Polygon", [[[0, 0], [4, 4], [4, 0], [0, 4], [0, 0]]], kind="walkable")),
            "features.0.geometry",
            id="self-crossing ring",
        ),
        pytest.param(
            {},
            _plan(_feature("Polygon", _box(2.17, 41.39, 2.1721, 41.391), kind="walkable")),
            "features.0.geometry.coordinates",
            id="degrees read as metres",
        ),
        pytest.param(
            ORIGIN,
            _plan(_feature("Point", [2.1702, 41.3901], beacon="door")),
            "features.0.geometry.coordinates",
            id="degrees at the building's origin",
        ),
    ],
)
async def test_a_wrong_plan_is_refused_naming_the_feature_and_property(
    client: httpx.AsyncClient,
    admin: dict[str, str],
    building: dict[str, Any],
    plan: dict[str, Any],
    field: str,
) -> None:
    floor_id = await _floor(client, admin, building)
    url = f"/v1/floors/{floor_id}/plan"
    assert (await client.put(url, json=GOOD, headers=admin)).status_code == 200
    r = await client.put(url, json=plan, headers=admin)
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["message"].startswith(f"{field}: "), body
    assert body["detail"][0]["loc"] == field.split(".")
    # the floor keeps the plan it had
    assert (await client.get(url, headers=admin)).json() == GOOD


async def test_a_good_plan_is_stored_as_sent(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    floor_id = await _floor(client, admin, ORIGIN)  # metres, though geo-referenced
    r = await client.put(f"/v1/floors/{floor_id}/plan", json=GOOD, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["has_plan"] is True
    assert (await client.get(f"/v1/floors/{floor_id}/plan", headers=admin)).json() == GOOD


async def test_imdf_units_and_openings_are_stored_with_our_kinds(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    floor_id = await _floor(client, admin, {})
    corridor = _feature("Polygon", _box(0, 0, 20, 4), category="walkway")
    office = _feature("Polygon", _box(0, 4, 10, 10), category="office")
    door = _feature("LineString", [[4, 4], [6, 4]], category="pedestrian")
    level = _feature("Polygon", _box(0, 0, 20, 10), ordinal=0)
    plan = _plan(
        {**corridor, "feature_type": "unit"},
        {**office, "feature_type": "unit"},
        {**door, "feature_type": "opening"},
        {**level, "feature_type": "level"},
    )
    r = await client.put(f"/v1/floors/{floor_id}/plan", json=plan, headers=admin)
    assert r.status_code == 200, r.text
    stored = (await client.get(f"/v1/floors/{floor_id}/plan", headers=admin)).json()
    assert [f["properties"].get("kind") for f in stored["features"]] == [
        "walkable",
        "room",
        "door",
        None,
    ]
    assert [f["feature_type"] for f in stored["features"]] == ["unit", "unit", "opening", "level"]
