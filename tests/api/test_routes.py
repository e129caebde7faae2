"""Routes over the API: between points of two floors through the plan's stairs or lift,
to a zone and to a named place, accessible routes by lift only, and the refusals that
name why."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from tests.support.toy_plans import square
from tests.support.toy_site import ToySite, build_toy_site, linked_toy_plan


async def _site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    site = await build_toy_site(client, admin)
    for floor_id in site.floor_ids.values():
        r = await client.put(f"/v1/floors/{floor_id}/plan", json=linked_toy_plan(), headers=admin)
        assert r.status_code in (200, 201), r.text
    return site


def _point(site: ToySite, level: int, x: float, y: float) -> dict[str, Any]:
    return {"floor_id": site.floor_ids[level], "x_m": x, "y_m": y}


async def test_a_route_between_floors_takes_the_stairs_or_the_lift(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await _site(client, admin)
    url = f"/v1/sites/{site.site_id}/routes"
    body = {"origin": _point(site, 0, 14.0, 2.0), "destination": _point(site, 1, 14.0, 8.0)}
    r = await client.post(url, json=body, headers=admin)
    assert r.status_code == 200, r.text
    route = r.json()
    assert [leg["level"] for leg in route["legs"]] == [0, 1]
    assert [c["kind"] for c in route["floor_changes"]] == ["stairs"]  # nearer than the lift
    kinds = [s["kind"] for s in route["steps"]]
    assert kinds[0] == "start"
    assert kinds[-1] == "arrive"
    assert "stairs_up" in kinds
    assert route["legs"][0]["geometry"]["coordinates"][0] == [14.0, 2.0]
    assert route["legs"][-1]["geometry"]["coordinates"][-1] == [14.0, 8.0]
    assert route["length_m"] >= 6.0
    assert route["duration_s"] > route["length_m"] / 1.2  # the stairs take time too
    # accessible: the lift, at the far end
    r = await client.post(url, json={**body, "accessible": True}, headers=admin)
    assert r.status_code == 200, r.text
    accessible = r.json()
    assert [c["kind"] for c in accessible["floor_changes"]] == ["elevator"]
    assert "lift_up" in [s["kind"] for s in accessible["steps"]]
    assert accessible["length_m"] > route["length_m"]


async def test_a_route_ends_at_a_zone_or_a_named_place(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await _site(client, admin)
    zones = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "id": "cafe", "properties": {"name": "Café"},
             "geometry": square(15, 0, 5)},
        ],
    }  # fmt: skip
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/zones", json=zones, headers=admin)
    assert r.status_code == 200, r.text
    url = f"/v1/sites/{site.site_id}/routes"
    origin = _point(site, 0, 2.0, 8.0)
    r = await client.post(url, json={"origin": origin, "destination": {"zone_id": "cafe"}},
                          headers=admin)  # fmt: skip
    assert r.status_code == 200, r.text
    end = r.json()["destination"]
    assert end["name"] == "Café"
    assert 14.0 <= end["x_m"] <= 16.0  # its nearest border, not its middle
    r = await client.post(
        url, json={"origin": origin, "destination": {"place": "information desk"}}, headers=admin
    )
    assert r.status_code == 200, r.text
    assert r.json()["destination"]["name"] == "Information desk"
    assert r.json()["steps"][-1]["text"] == "Arrive at Information desk"


@pytest.mark.parametrize(
    ("destination", "status", "field"),
    [
        ({"x_m": 50.0, "y_m": 5.0}, 404, "destination"),
        ({"place": "nowhere"}, 404, "destination.place"),
        ({"zone_id": "nope"}, 404, "destination.zone_id"),
        ({"x_m": 5.0}, 422, "destination"),
    ],
)
async def test_no_route_says_why(
    client: httpx.AsyncClient,
    admin: dict[str, str],
    destination: dict[str, Any],
    status: int,
    field: str,
) -> None:
    site = await _site(client, admin)
    if "x_m" in destination:
        destination = {"floor_id": site.floor_ids[1], **destination}
    body = {"origin": _point(site, 0, 2.0, 2.0), "destination": destination}
    r = await client.post(f"/v1/sites/{site.site_id}/routes", json=body, headers=admin)
    assert r.status_code == status, r.text
    assert r.json()["message"].startswith(f"{field}:"), r.text
