"""Fixes in world coordinates: a geo-referenced building's fixes carry WGS84 ``lat``/``lon``,
the floor's ``level``, ``accuracy_m`` and ``heading_deg`` from north, in the batch's answer,
the track and ``/v1/locate``; a building without a geo-reference gives nulls."""

from __future__ import annotations

import math

import httpx
import pytest
from geographiclib.geodesic import Geodesic

from tests.support.sessions import open_session, scan, step
from tests.support.toy_site import build_toy_site, rssi_at

T0 = 1_700_000_000_000
ORIGIN = (51.4779, -0.0015)  # Greenwich
ROTATION_RAD = math.radians(25.0)  # the building's y axis, clockwise from north


def expected_lat_lon(x_m: float, y_m: float) -> tuple[float, float]:
    """geographiclib's geodesic from the origin, at the bearing of the local direction."""
    bearing = math.degrees(math.atan2(x_m, y_m) + ROTATION_RAD)
    end = Geodesic.WGS84.Direct(ORIGIN[0], ORIGIN[1], bearing, math.hypot(x_m, y_m))
    return end["lat2"], end["lon2"]


def apart_m(lat: float, lon: float, other: tuple[float, float]) -> float:
    return float(Geodesic.WGS84.Inverse(lat, lon, other[0], other[1])["s12"])


async def test_a_geo_referenced_building_s_fixes_are_in_wgs84(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    building = {"origin_lat": ORIGIN[0], "origin_lon": ORIGIN[1], "rotation_rad": ROTATION_RAD}
    site = await build_toy_site(client, admin, building)
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    events = [scan(T0, 5, 5), step(T0 + 600, heading_rad=math.pi / 2), scan(T0 + 700, 6, 5)]
    r = await client.post(url, json={"seq": 1, "events": events}, headers=auth)
    assert r.status_code == 200, r.text
    fixes = r.json()["fixes"]
    assert fixes
    for fix in fixes:
        assert apart_m(fix["lat"], fix["lon"], expected_lat_lon(fix["x_m"], fix["y_m"])) < 0.1
        assert fix["level"] == fix["floor"] == 0
        assert fix["accuracy_m"] == fix["accuracy_68_m"]
        if fix["heading_rad"] is None:
            assert fix["heading_deg"] is None
        else:
            assert 0.0 <= fix["heading_deg"] < 360.0
    # the phone stepped east (a step's heading is the phone's, from north): the fix heads
    # east, whatever the building's rotation; in the building's frame it is 90 - 25 degrees
    stepped = [f for f in fixes if f["heading_rad"] is not None]
    assert stepped
    assert stepped[-1]["heading_deg"] == pytest.approx(90.0, abs=5.0)
    assert math.degrees(stepped[-1]["heading_rad"]) == pytest.approx(65.0, abs=5.0)
    track = await client.get(f"/v1/sessions/{sid}/track", headers=auth)
    assert track.status_code == 200, track.text
    body = track.json()
    kept = body["items"]
    assert [(f["lat"], f["lon"]) for f in kept][-len(fixes) :] == [
        (f["lat"], f["lon"]) for f in fixes
    ]

    located = await client.post(
        "/v1/locate",
        json={"site_id": site.site_id, "wifi": rssi_at(12.0, 6.0, 0)},
        headers=site.device,
    )
    assert located.status_code == 200, located.text
    here = located.json()
    assert apart_m(here["lat"], here["lon"], expected_lat_lon(here["x_m"], here["y_m"])) < 0.1
    assert here["level"] == 0
    assert here["accuracy_m"] == here["accuracy_68_m"]


async def test_without_a_geo_reference_the_world_fields_are_null(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    sid, auth = await open_session(client, site)
    events = [scan(T0, 5, 5), step(T0 + 600, heading_rad=math.pi)]
    r = await client.post(
        f"/v1/sessions/{sid}/batches", json={"seq": 1, "events": events}, headers=auth
    )
    assert r.status_code == 200, r.text
    first, stepped = r.json()["fixes"]
    for fix in (first, stepped):
        assert fix["lat"] is None
        assert fix["lon"] is None
        assert fix["level"] == 0
        assert fix["accuracy_m"] == fix["accuracy_68_m"]
    assert first["heading_deg"] is None  # a scan alone says nothing of the heading
    # a building that is not turned: its y axis is north, the heading is the step's, south
    assert stepped["heading_deg"] == pytest.approx(180.0, abs=5.0)
