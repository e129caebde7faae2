"""DELETE of sites, buildings and floors: what each removes, and the refusal (409 naming
the sessions) while the site has active sessions."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from sqlalchemy import func, select, update

from server.storage.models import (
    ApiKey,
    Building,
    EngineSetting,
    Floor,
    MagneticMapVersion,
    RadioMapVersion,
    SessionContribution,
    SessionRecord,
    SurveyPoint,
    Upload,
    utcnow,
)
from tests.support.toy_site import (
    ToySite,
    build_toy_site,
    device_headers,
    rssi_at,
    walk_upload,
)

T0 = 1_700_000_000_000


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def _session(
    client: httpx.AsyncClient, site: ToySite, headers: dict[str, str] | None = None, **body: Any
) -> tuple[str, dict[str, str]]:
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, **body}, headers=headers or site.device
    )
    assert r.status_code == 201, r.text
    return r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}


async def _count(app: FastAPI, model: Any, *where: Any) -> int:
    async with app.state.runtime.read() as s:
        return int(await s.scalar(select(func.count()).select_from(model).where(*where)) or 0)


async def _surveyed_magnetic(client: httpx.AsyncClient, admin: dict[str, str], floor: str) -> None:
    points = {"points": [{"x_m": 1.0, "y_m": 1.0, "magnitude_ut": 48.0}]}
    r = await client.post(f"/v1/floors/{floor}/magnetic-survey", json=points, headers=admin)
    assert r.status_code == 201, r.text


async def test_an_active_session_blocks_deleting_its_site_and_what_is_in_it(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite
) -> None:
    sid, auth = await _session(client, site)
    other = await build_toy_site(client, admin)
    await _session(client, other)  # another site's session blocks nothing here
    for url, field in (
        (f"/v1/sites/{site.site_id}", "site_id"),
        (f"/v1/buildings/{site.building_id}", "building_id"),
        (f"/v1/floors/{site.floor_ids[1]}", "floor_id"),
    ):
        r = await client.delete(url, headers=admin)
        assert r.status_code == 409, r.text
        assert r.json()["detail"][0]["loc"] == [field]
        assert sid in r.json()["message"]
        assert "1 active session" in r.json()["message"]
    # nothing went: the session goes on
    r = await client.post(
        f"/v1/sessions/{sid}/batches",
        json={"seq": 1, "events": [{"type": "wifi", "t": T0, "readings": rssi_at(5, 5, 0)}]},
        headers=auth,
    )
    assert r.status_code == 200, r.text
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    assert (
        await client.delete(f"/v1/floors/{site.floor_ids[1]}", headers=admin)
    ).status_code == 204


async def test_deleting_a_site_removes_all_it_holds(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite, app: FastAPI
) -> None:
    await _surveyed_magnetic(client, admin, site.floor_ids[0])
    r = await client.post(
        "/v1/uploads", params={"site_id": site.site_id}, json=walk_upload(2.0), headers=admin
    )
    assert r.status_code == 202, r.text
    upload_id = r.json()["id"]
    r = await client.put(
        f"/v1/sites/{site.site_id}/engines/wknn", json={"params": {}}, headers=admin
    )
    assert r.status_code == 200, r.text
    assert await _count(app, EngineSetting, EngineSetting.site_id == site.site_id) == 1
    viewer = await device_headers(client, admin, ("viewer",), site.site_id)
    site_admin = await device_headers(client, admin, ("admin",), site.site_id)
    # a contributing session left idle (not ended): it kept a batch, it blocks nothing
    contributor = await device_headers(client, admin, ("device", "contribute"), site.site_id)
    idle, auth = await _session(client, site, contributor, contribute=True)
    scan = {"type": "wifi", "t": T0, "readings": rssi_at(5, 5, 0)}
    r = await client.post(
        f"/v1/sessions/{idle}/batches", json={"seq": 1, "events": [scan]}, headers=auth
    )
    assert r.status_code == 200, r.text
    assert await _count(app, SessionContribution, SessionContribution.session_id == idle) == 1
    long_ago = utcnow() - timedelta(days=1)
    async with app.state.runtime.transaction() as s:
        await s.execute(
            update(SessionRecord).where(SessionRecord.id == idle).values(last_active_at=long_ago)
        )

    # a key of the site alone may not delete it: that takes an admin key of every site
    assert (await client.delete(f"/v1/sites/{site.site_id}", headers=site_admin)).status_code == 403
    assert (await client.delete(f"/v1/sites/{site.site_id}", headers=admin)).status_code == 204

    assert (await client.get(f"/v1/sites/{site.site_id}", headers=admin)).status_code == 404
    assert (await client.get(f"/v1/buildings/{site.building_id}", headers=admin)).status_code == 404
    assert (await client.get(f"/v1/floors/{site.floor_ids[0]}", headers=admin)).status_code == 404
    assert (await client.get(f"/v1/uploads/{upload_id}", headers=admin)).status_code == 404
    # the site's own keys stop working
    assert (await client.get("/v1/sites", headers=viewer)).status_code == 401
    assert (await client.delete(f"/v1/sites/{site.site_id}", headers=admin)).status_code == 404
    b = site.building_id
    for model, where in (
        (Building, Building.site_id == site.site_id),
        (Floor, Floor.building_id == b),
        (SurveyPoint, SurveyPoint.building_id == b),
        (RadioMapVersion, RadioMapVersion.building_id == b),
        (MagneticMapVersion, MagneticMapVersion.floor_id == site.floor_ids[0]),
        (Upload, Upload.site_id == site.site_id),
        (SessionRecord, SessionRecord.site_id == site.site_id),
        (SessionContribution, SessionContribution.session_id == idle),
        (EngineSetting, EngineSetting.site_id == site.site_id),
        (ApiKey, ApiKey.site_id == site.site_id),
    ):
        assert await _count(app, model, where) == 0, model.__name__


async def test_deleting_a_building_keeps_its_site(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite, app: FastAPI
) -> None:
    r = await client.post(f"/v1/sites/{site.site_id}/buildings", json={"name": "C"}, headers=admin)
    kept_building = r.json()["id"]
    named = await client.post(
        "/v1/uploads",
        params={"site_id": site.site_id, "building_id": site.building_id},
        json=walk_upload(2.0),
        headers=admin,
    )
    unnamed = await client.post(
        "/v1/uploads", params={"site_id": site.site_id}, json=walk_upload(3.0), headers=admin
    )
    assert named.status_code == unnamed.status_code == 202
    site_admin = await device_headers(client, admin, ("admin",), site.site_id)
    r = await client.delete(f"/v1/buildings/{site.building_id}", headers=site_admin)
    assert r.status_code == 204, r.text
    r = await client.get(f"/v1/sites/{site.site_id}/buildings", headers=admin)
    assert [x["id"] for x in r.json()["items"]] == [kept_building]
    for floor in site.floor_ids.values():
        assert (await client.get(f"/v1/floors/{floor}", headers=admin)).status_code == 404
    assert (await client.get(f"/v1/uploads/{named.json()['id']}", headers=admin)).status_code == 404
    assert (
        await client.get(f"/v1/uploads/{unnamed.json()['id']}", headers=admin)
    ).status_code == 200
    assert await _count(app, RadioMapVersion, RadioMapVersion.building_id == site.building_id) == 0
    r = await client.delete(f"/v1/buildings/{site.building_id}", headers=admin)
    assert r.status_code == 404
    assert "building_id" in r.json()["message"]


async def test_deleting_a_surveyed_floor_leaves_the_other_floors_working(
    client: httpx.AsyncClient, admin: dict[str, str], site: ToySite, app: FastAPI
) -> None:
    gone, kept = site.floor_ids[1], site.floor_ids[0]
    await _surveyed_magnetic(client, admin, gone)
    assert (await client.delete(f"/v1/floors/{gone}", headers=admin)).status_code == 204
    assert (await client.get(f"/v1/floors/{gone}", headers=admin)).status_code == 404
    r = await client.get(f"/v1/buildings/{site.building_id}/floors", headers=admin)
    assert [f["id"] for f in r.json()["items"]] == [kept]
    assert await _count(app, SurveyPoint, SurveyPoint.floor_id == gone) == 0
    assert await _count(app, MagneticMapVersion, MagneticMapVersion.floor_id == gone) == 0
    # the radio map version made over both floors still serves the one left
    sid, auth = await _session(client, site, engine="wknn")
    scan = {"type": "wifi", "t": T0, "readings": rssi_at(5, 5, 0)}
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": [scan]}, headers=auth
    )
    assert r.status_code == 200, r.text
    (fix,) = r.json()["fixes"]
    assert fix["floor_id"] == kept
    assert abs(fix["x_m"] - 5) < 1.5
    assert abs(fix["y_m"] - 5) < 1.5
    assert (await client.delete(f"/v1/sessions/{sid}", headers=auth)).status_code == 204
    # and the next survey folds into it
    url = f"/v1/buildings/{site.building_id}/survey"
    point = {"x_m": 3.0, "y_m": 3.0, "floor": 0, "wifi": rssi_at(3, 3, 0)}
    r = await client.post(url, json={"points": [point]}, headers=admin)
    assert r.status_code == 201, r.text
    r = await client.post(url, json={"points": [{**point, "floor": 1}]}, headers=admin)
    assert r.status_code == 422
    assert "points.0.floor" in r.json()["message"]
