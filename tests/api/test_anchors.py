"""An anchor marked in a floor plan reaches the ``everywhere_ekf`` engine of a session."""

from __future__ import annotations

import httpx

from tests.support.toy_site import ToySite, build_toy_site

T0 = 1_700_000_000_000


async def test_a_beacon_in_the_plan_places_the_phone(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site: ToySite = await build_toy_site(client, admin)
    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [17.5, 2.5]},
                "properties": {"anchor": "elevator", "beacon": "lift-a"},
            }
        ],
    }
    r = await client.put(f"/v1/floors/{site.floor_ids[1]}/plan", json=plan, headers=admin)
    assert r.status_code == 200, r.text
    r = await client.post(
        "/v1/sessions",
        json={"site_id": site.site_id, "engine": "everywhere_ekf"},
        headers=site.device,
    )
    assert r.status_code == 201, r.text
    sid, token = r.json()["id"], r.json()["token"]
    auth = {"Authorization": f"Bearer {token}"}
    weak = {"type": "ble", "t": T0, "readings": [{"id": "lift-a", "rssi_dbm": -80}]}
    near = {"type": "ble", "t": T0 + 1000, "readings": [{"id": "lift-a", "rssi_dbm": -55}]}
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": [weak, near]}, headers=auth
    )
    assert r.status_code == 200, r.text
    (fix,) = r.json()["fixes"]
    assert fix["source"] == "anchor"
    assert (fix["x_m"], fix["y_m"], fix["floor"]) == (17.5, 2.5, 1)


async def test_a_malformed_anchor_is_skipped_not_fatal(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site: ToySite = await build_toy_site(client, admin)
    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": {"x": 1, "y": 2}},
                "properties": {"beacon": "lift-a"},
            }
        ],
    }
    r = await client.put(f"/v1/floors/{site.floor_ids[0]}/plan", json=plan, headers=admin)
    assert r.status_code == 200, r.text
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, "engine": "wknn"}, headers=site.device
    )
    assert r.status_code == 201, r.text
