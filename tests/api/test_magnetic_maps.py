"""Magnetic surveys through the admin API: points and walked lines become the floor's
next grid version, later surveys are merged into it, and sessions see the new map."""

from __future__ import annotations

import math
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi import FastAPI

from server.positioning.magnetic.field_grid import sample
from server.services.maps import site_maps
from tests.support.toy_site import build_toy_site, toy_plan

T0 = 1_700_000_000_000


def field_at(x_m: float, y_m: float) -> float:
    """A smooth synthetic field magnitude (µT) over the toy floor."""
    return 45.0 + 4.0 * math.sin(x_m / 3.0) + 2.0 * math.cos(y_m / 2.0)


def line_body(y_m: float, n: int = 41) -> dict[str, Any]:
    """A walk along y = y_m from x = 0 to x = 20 in 20 s, one sample every 0.5 s, with the
    field split over the phone's axes."""
    samples = []
    for i in range(n):
        x = 20.0 * i / (n - 1)
        b = field_at(x, y_m)
        samples.append([T0 + 500 * i, 0.6 * b, 0.0, -0.8 * b])
    return {
        "start": [0.0, y_m],
        "end": [20.0, y_m],
        "t_start": T0,
        "t_end": T0 + 20_000,
        "samples": samples,
    }


async def test_surveys_make_versions_that_merge(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> None:
    site = await build_toy_site(client, admin)
    floor = site.floor_ids[0]
    url = f"/v1/floors/{floor}/magnetic-survey"
    points = [
        {"x_m": float(x), "y_m": 5.0, "magnitude_ut": field_at(x, 5.0), "horizontal_ut": 20.0}
        for x in range(0, 21, 2)
    ]
    r = await client.post(url, json={"points": points, "lines": [line_body(2.0)]}, headers=admin)
    assert r.status_code == 201, r.text
    first = r.json()
    assert first["version"] == 1
    assert first["n_samples"] == len(points) + 41
    assert first["resolution_m"] == 0.5
    assert 0 < first["known_cells"] <= first["n_samples"]

    # the same line again: one more version, counts add up, the known cells stay
    r = await client.post(url, json={"lines": [line_body(2.0)]}, headers=admin)
    assert r.status_code == 201, r.text
    second = r.json()
    assert second["version"] == 2
    assert second["n_samples"] == first["n_samples"] + 41
    assert second["known_cells"] == first["known_cells"]

    r = await client.get(f"/v1/floors/{floor}/magnetic-maps", headers=admin)
    assert r.status_code == 200
    assert [m["version"] for m in r.json()["items"]] == [1, 2]

    # what a session's engine samples is the surveyed field (cell means, bilinear)
    rt = app.state.runtime
    rt.maps.invalidate(site.site_id)
    async with rt.transaction() as s:
        maps = await site_maps(s, rt.maps, site.site_id)
    assert maps.magnetic is not None
    index = [f.floor_id for f in maps.floors].index(floor)
    grid = maps.magnetic.grids[index]
    assert grid is not None
    assert maps.magnetic.grids[1 - index] is None
    xs = np.linspace(1.0, 19.0, 10)
    got = sample(grid, np.column_stack([xs, np.full(10, 2.0)]))
    want = [field_at(x, 2.0) for x in xs]
    assert np.all(np.isfinite(got))
    # a 0.5 m cell averages ~1 sample; the field changes by < 0.7 µT per 0.5 m
    np.testing.assert_allclose(got, want, atol=0.7)


async def test_survey_points_with_a_field_feed_the_magnetic_map(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    body = {
        "points": [
            {"x_m": 3.0, "y_m": 4.0, "floor": 1, "mag_ut": [30.0, 0.0, -40.0]},
            {"x_m": 3.1, "y_m": 4.1, "floor": 1, "mag_ut": [0.0, 30.0, -40.0]},
        ]
    }
    r = await client.post(f"/v1/buildings/{site.building_id}/survey", json=body, headers=admin)
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/floors/{site.floor_ids[1]}/magnetic-maps", headers=admin)
    (version,) = r.json()["items"]
    assert version["n_samples"] == 2
    assert version["known_cells"] == 1
    r = await client.get(f"/v1/floors/{site.floor_ids[0]}/magnetic-maps", headers=admin)
    assert r.json()["items"] == []


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"points": [{"x_m": 0, "y_m": 0}]}, "points.0"),
        ({"points": [{"x_m": 0, "y_m": 0, "magnitude_ut": 50, "field_ut": [1, 2, 3]}]}, "points.0"),
        ({"points": [{"x_m": 0, "y_m": 0, "field_ut": [900, 0, 0]}]}, "points.0.field_ut.0"),
        ({"points": [{"x_m": 0, "y_m": 0, "magnitude_ut": -1}]}, "points.0.magnitude_ut"),
        ({"lines": [{**line_body(1.0), "t_end": T0}]}, "lines.0"),
        ({"lines": [{**line_body(1.0), "samples": []}]}, "lines.0.samples"),
        ({"lines": [{**line_body(1.0), "start": [0.0, 1e6]}]}, "lines.0.start"),
        ({"points": [], "lines": []}, "body"),
        (
            {"lines": [{**line_body(1.0), "t_start": T0 + 60_000, "t_end": T0 + 70_000}]},
            "lines.0.samples",
        ),
        # two points 200 km apart: a 1.2 TiB grid once
        (
            {
                "points": [
                    {"x_m": -1e5, "y_m": -1e5, "magnitude_ut": 50.0},
                    {"x_m": 1e5, "y_m": 1e5, "magnitude_ut": 50.0},
                ]
            },
            "points",
        ),
        # two points 2 km apart: 16 million cells
        (
            {
                "points": [
                    {"x_m": 0.0, "y_m": 0.0, "magnitude_ut": 50.0},
                    {"x_m": 1500.0, "y_m": 1500.0, "magnitude_ut": 50.0},
                ]
            },
            "points",
        ),
        # a walked line 12 km long
        ({"lines": [{**line_body(1.0), "end": [12_000.0, 1.0]}]}, "lines.0"),
    ],
)
async def test_bad_magnetic_surveys_are_422_naming_the_field(
    client: httpx.AsyncClient, admin: dict[str, str], body: dict[str, Any], field: str
) -> None:
    site = await build_toy_site(client, admin)
    floor = site.floor_ids[0]
    r = await client.post(f"/v1/floors/{floor}/magnetic-survey", json=body, headers=admin)
    assert r.status_code == 422, r.text
    assert field in r.json()["message"], r.json()
    r = await client.get(f"/v1/floors/{floor}/magnetic-maps", headers=admin)
    assert r.json()["count"] == 0  # nothing half-written


async def test_magnetic_survey_needs_a_known_floor_and_an_admin(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    body = {"points": [{"x_m": 0, "y_m": 0, "magnitude_ut": 50}]}
    r = await client.post(f"/v1/floors/{'0' * 32}/magnetic-survey", json=body, headers=admin)
    assert r.status_code == 404
    assert "floor_id" in r.json()["message"]
    r = await client.post(f"/v1/floors/{'0' * 32}/magnetic-survey", json=body)
    assert r.status_code == 401


async def test_a_survey_must_lie_on_the_floor_plan(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    floor = site.floor_ids[0]
    r = await client.put(f"/v1/floors/{floor}/plan", json=toy_plan(), headers=admin)
    assert r.status_code == 200, r.text
    url = f"/v1/floors/{floor}/magnetic-survey"
    inside = {"x_m": 25.0, "y_m": 5.0, "magnitude_ut": 50.0}  # within the 10 m margin
    far = {"x_m": 5.0, "y_m": 45.0, "magnitude_ut": 50.0}
    r = await client.post(url, json={"points": [inside, far]}, headers=admin)
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("points.1: "), r.json()
    r = await client.post(
        url, json={"lines": [{**line_body(1.0), "end": [60.0, 1.0]}]}, headers=admin
    )
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("lines.0.end: "), r.json()
    r = await client.post(url, json={"points": [inside], "lines": [line_body(1.0)]}, headers=admin)
    assert r.status_code == 201, r.text


async def test_a_plan_with_odd_feature_properties_does_not_break_surveys(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> None:
    site = await build_toy_site(client, admin)
    floor = site.floor_ids[0]
    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": "corridor",
                "geometry": {"type": "Point", "coordinates": [1.0, 1.0]},
            }
        ],
    }
    assert (
        await client.put(f"/v1/floors/{floor}/plan", json=plan, headers=admin)
    ).status_code < 500
    body = {"points": [{"x_m": 1.0, "y_m": 1.0, "magnitude_ut": 48.0}]}
    r = await client.post(f"/v1/floors/{floor}/magnetic-survey", json=body, headers=admin)
    assert r.status_code == 201, r.text
