"""Coverage grid of a floor: the toy floor of ``tests.support.quality_floor`` (its west
half surveyed, one old point in the east half) cell by cell, floors without maps or plan,
and the parameter's bounds."""

from __future__ import annotations

import math
from typing import Any

import httpx
import numpy as np
import pytest

from server.positioning.radio import fix_error
from tests.support.quality_floor import new_site, polygon
from tests.support.toy_site import rssi_at

FIGURES = (
    "in_area",
    "readings",
    "points",
    "emitters",
    "var_db2",
    "age_days",
    "nearest_rp_m",
    "expected_error_m",
)


def figure(body: dict[str, Any], name: str) -> np.ndarray:
    """A figure of the answer as an array, null as NaN."""
    return np.array(body["cells"][name], dtype=np.float64)


async def test_coverage_of_a_surveyed_floor(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    r = await client.get(f"/v1/floors/{floor}/maps/coverage", headers=admin)
    assert r.status_code == 200, r.text
    g = r.json()
    assert g["floor_id"] == floor
    assert g["radio_map"]["version"] == 2
    assert g["fix_error"] == "default"  # surveyed through the API: no walks to learn from
    assert g["walkable_area_known"] is True
    # the 20 m x 10 m floor in 2 m cells
    assert (g["origin_m"], g["cell_m"], g["rows"], g["cols"]) == ([0.0, 0.0], 2.0, 5, 10)
    for name in FIGURES:
        assert np.shape(g["cells"][name]) == (5, 10), name
    # the pillar [2, 4] x [2, 4] fills cell (1, 1): the one cell out of the area
    in_area = np.array(g["cells"]["in_area"])
    assert np.argwhere(~in_area).tolist() == [[1, 1]]

    west, east = np.s_[:, :5], np.s_[:, 5:]
    ghost = (2, 7)  # the upload's point at (15.5, 5.5), 60 days old, one AP heard
    readings, points = figure(g, "readings"), figure(g, "points")
    # four 1 m reference points of 2 points x 16 APs in each western cell
    assert (readings[west] == 4 * 2 * 16).all()
    assert (points[west] == 4 * 2).all()
    assert (figure(g, "emitters")[west] == 16).all()
    assert readings[ghost] == points[ghost] == figure(g, "emitters")[ghost] == 1
    empty = np.ones((5, 10), dtype=bool)
    empty[west] = False
    empty[ghost] = False
    assert (readings[empty] == 0).all()
    assert (points[empty] == 0).all()

    var = figure(g, "var_db2")
    assert (var[west] > 0).all()
    assert np.isnan(var[east]).all()  # the ghost's one reading has no variance

    age = figure(g, "age_days")
    assert (age[west] < 1.0).all()
    assert age[ghost] == pytest.approx(60.0, abs=0.01)
    assert np.isnan(age[empty]).all()

    # in the west every cell's centre is 0.71 m from a reference point hearing 16 APs
    d = figure(g, "nearest_rp_m")
    error = figure(g, "expected_error_m")
    sigma = fix_error.DEFAULT.sigma("wifi", 16)
    np.testing.assert_allclose(d[west], math.sqrt(0.5), atol=0.01)
    np.testing.assert_allclose(error[west], math.sqrt(2 * sigma**2 + 0.5), atol=0.01)
    # farther from the survey, the expected error is worse everywhere
    assert error[east].min() > error[west].max()
    assert error[0, 9] > error[0, 5]
    # the ghost's reference point hears one AP: the worst σ of the table
    assert error[ghost] == pytest.approx(
        math.sqrt(2 * fix_error.DEFAULT.sigma("wifi", 1) ** 2 + d[ghost] ** 2), abs=0.01
    )


async def test_cell_size(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    r = await client.get(f"/v1/floors/{floor}/maps/coverage", params={"cell_m": 5}, headers=admin)
    assert r.status_code == 200, r.text
    g = r.json()
    assert (g["rows"], g["cols"], g["cell_m"]) == (2, 4, 5.0)
    assert all(all(row) for row in g["cells"]["in_area"])  # the pillar fills no 5 m cell
    # every reading and point in some cell: 100 reference points of 32, the ghost's 1
    assert figure(g, "readings").sum() == 100 * 32 + 1
    assert figure(g, "points").sum() == 201


async def test_bad_cell_sizes_are_refused(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    _, _, floors = await new_site(client, admin)
    url = f"/v1/floors/{floors[0]}/maps/coverage"
    for bad in (0.4, 51, "wide"):
        r = await client.get(url, params={"cell_m": bad}, headers=admin)
        assert r.status_code == 422, r.text
        assert "cell_m" in r.json()["message"]

    # 150 m x 150 m of floor: 90,000 cells of 0.5 m, more than a grid may have
    plan = {"type": "FeatureCollection", "features": [polygon(0, 0, 150, 150, "walkable")]}
    r = await client.put(f"/v1/floors/{floors[0]}/plan", json=plan, headers=admin)
    assert r.status_code == 200, r.text
    r = await client.get(url, params={"cell_m": 0.5}, headers=admin)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["cell_m"]
    # 200 x 200 cells of 0.75 m fit
    assert "at least 0.75 m" in r.json()["message"]
    r = await client.get(url, params={"cell_m": 0.75}, headers=admin)
    assert r.status_code == 200, r.text
    assert (r.json()["rows"], r.json()["cols"]) == (200, 200)


async def test_floors_without_maps(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    _, _, floors = await new_site(client, admin)
    # neither plan nor data: no cell
    r = await client.get(f"/v1/floors/{floors[0]}/maps/coverage", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json() == {
        "floor_id": floors[0],
        "radio_map": None,
        "fix_error": "default",
        "walkable_area_known": False,
        "origin_m": [0.0, 0.0],
        "cell_m": 2.0,
        "rows": 0,
        "cols": 0,
        "cells": {name: [] for name in FIGURES},
    }

    # a plan and no survey: its cells, all without data
    plan = {"type": "FeatureCollection", "features": [polygon(0, 0, 6, 4, "walkable")]}
    r = await client.put(f"/v1/floors/{floors[1]}/plan", json=plan, headers=admin)
    assert r.status_code == 200, r.text
    r = await client.get(f"/v1/floors/{floors[1]}/maps/coverage", headers=admin)
    assert r.status_code == 200, r.text
    g = r.json()
    assert (g["rows"], g["cols"], g["walkable_area_known"]) == (2, 3, True)
    assert g["cells"]["in_area"] == [[True] * 3] * 2
    assert g["cells"]["readings"] == g["cells"]["points"] == [[0] * 3] * 2
    for name in ("var_db2", "age_days", "nearest_rp_m", "expected_error_m"):
        assert g["cells"][name] == [[None] * 3] * 2, name


async def test_floor_without_a_plan(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    """Level 1 shares the building's radio map but has no reference point, plan or
    point: no cell; once surveyed, the grid covers its points' box."""
    _, building_id, floors = await new_site(client, admin)
    points = [{"x_m": x, "y_m": y, "floor": 0, "wifi": rssi_at(x, y, 0)} for x, y in ((0.5, 0.5),)]
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/floors/{floors[1]}/maps/coverage", headers=admin)
    assert r.status_code == 200, r.text
    g = r.json()
    assert g["radio_map"] is not None
    assert (g["rows"], g["cols"]) == (0, 0)

    # two points on level 1: reference points at (0.5, 0.5) and (3.5, 2.5), in 2 m cells
    # from (0, 0)
    points = [
        {"x_m": x, "y_m": y, "floor": 1, "wifi": rssi_at(x, y, 1)}
        for x, y in ((0.5, 0.5), (3.5, 2.5))
    ]
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/floors/{floors[1]}/maps/coverage", headers=admin)
    assert r.status_code == 200, r.text
    g = r.json()
    assert g["walkable_area_known"] is False
    assert (g["origin_m"], g["rows"], g["cols"]) == ([0.0, 0.0], 2, 2)
    assert g["cells"]["in_area"] == [[True, True], [True, True]]
    assert g["cells"]["points"] == [[1, 0], [0, 1]]
    assert g["cells"]["nearest_rp_m"][0][0] == pytest.approx(math.sqrt(0.5), abs=0.01)


async def test_unknown_floor_and_no_key(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    missing = "0" * 32
    r = await client.get(f"/v1/floors/{missing}/maps/coverage", headers=admin)
    assert r.status_code == 404, r.text
    assert r.json()["detail"][0]["loc"] == ["floor_id"]
    r = await client.get(f"/v1/floors/{missing}/maps/coverage")
    assert r.status_code == 401
