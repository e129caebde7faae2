"""Map versions: each survey folds into the current version; activating an older version
rolls back, and what comes next folds into that one."""

from __future__ import annotations

import httpx

from tests.support.toy_site import build_toy_site, rssi_at


async def test_radio_map_rollback(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    site = await build_toy_site(client, admin)  # version 1: the whole toy survey
    url = f"/v1/buildings/{site.building_id}"
    r = await client.get(f"{url}/radio-maps", headers=admin)
    (v1,) = r.json()["items"]
    # a bad contribution: floor 0's corner surveyed with floor 1's readings
    bad = [{"x_m": 0.5, "y_m": 0.5, "floor": 0, "wifi": rssi_at(0.5, 0.5, 1)}]
    r = await client.post(f"{url}/survey", json={"points": bad * 5}, headers=admin)
    assert r.status_code == 201, r.text
    v2 = r.json()
    assert v2["version"] == 2
    assert v2["n_survey_points"] == v1["n_survey_points"] + 5
    assert v2["n_reference_points"] == v1["n_reference_points"]  # folded into a known cell

    r = await client.post(f"{url}/radio-maps/1:activate", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["version"] == 1
    assert r.json()["activated_at"] > v2["activated_at"]
    r = await client.get(f"{url}/radio-maps", headers=admin)
    current = max(r.json()["items"], key=lambda m: m["activated_at"])
    assert current["version"] == 1

    # the next survey folds into version 1, without the bad points
    good = [{"x_m": 30.0, "y_m": 5.0, "floor": 0, "wifi": rssi_at(30.0, 5.0, 0)}]
    r = await client.post(f"{url}/survey", json={"points": good}, headers=admin)
    v3 = r.json()
    assert v3["version"] == 3
    assert v3["n_survey_points"] == v1["n_survey_points"] + 1
    assert v3["n_reference_points"] == v1["n_reference_points"] + 1

    for bad_version, status in (("9", 404), ("0", 422), ("x", 422)):
        r = await client.post(f"{url}/radio-maps/{bad_version}:activate", headers=admin)
        assert r.status_code == status, r.text
        assert "version" in r.json()["message"]
    r = await client.post(f"{url}/radio-maps/1:activate")
    assert r.status_code == 401


async def test_magnetic_map_rollback(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    site = await build_toy_site(client, admin)
    floor = site.floor_ids[0]
    url = f"/v1/floors/{floor}"
    first = {"points": [{"x_m": 1.0, "y_m": 1.0, "magnitude_ut": 45.0}]}
    second = {"points": [{"x_m": 9.0, "y_m": 1.0, "magnitude_ut": 80.0}] * 3}
    for body in (first, second):
        r = await client.post(f"{url}/magnetic-survey", json=body, headers=admin)
        assert r.status_code == 201, r.text
    r = await client.post(f"{url}/magnetic-maps/1:activate", headers=admin)
    assert r.status_code == 200, r.text
    r = await client.post(f"{url}/magnetic-survey", json=first, headers=admin)
    v3 = r.json()
    assert v3["version"] == 3
    assert v3["n_samples"] == 2  # version 1's sample and this one; not the three of v2
    assert v3["known_cells"] == 1
    r = await client.post(f"{url}/magnetic-maps/7:activate", headers=admin)
    assert r.status_code == 404
    assert "version" in r.json()["message"]
