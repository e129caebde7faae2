"""Map quality of a floor: coverage against the floor plan, cell sampling, freshness and
emitters, on a toy floor whose expected figures follow from its geometry."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi import FastAPI
from sqlalchemy import select

from server.services import maps
from server.storage.models import SurveyPoint
from server.storage.repositories import uploads as upload_repo
from tests.api.toy_site import AP_XY, rssi_at

T0 = 1_700_000_000_000
DAY_MS = 86_400_000
GHOST = "02:00:00:00:ff:01"  # an AP heard only by a point created 60 days ago
SHADOWING_DB = 2.0  # RSS noise added to the toy's log-distance readings


def _polygon(x0: float, y0: float, x1: float, y1: float, kind: str) -> dict[str, Any]:
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {
        "type": "Feature",
        "properties": {"kind": kind},
        "geometry": {"type": "Polygon", "coordinates": [ring]},
    }


# 20 m x 10 m of floor with a 2 m x 2 m pillar: 200 - 4 walkable 1 m cells, 800 - 16
# walkable 0.5 m cells
PLAN = {
    "type": "FeatureCollection",
    "features": [_polygon(0, 0, 20, 10, "walkable"), _polygon(2, 2, 4, 4, "obstacle")],
}


def field_at(x_m: float) -> float:
    return 45.0 + 4.0 * math.sin(x_m / 3.0)


def magnetic_line(y_m: float) -> dict[str, Any]:
    """A walk along y = y_m from x = 0.125 to 19.875, a sample every 0.25 m: two samples in
    each of the 40 half-metre cells of its row."""
    n = 80
    samples = [
        [T0 + 250 * i, 0.6 * field_at(0.125 + 0.25 * i), 0.0, -0.8 * field_at(0.125 + 0.25 * i)]
        for i in range(n)
    ]
    return {
        "start": [0.125, y_m],
        "end": [19.875, y_m],
        "t_start": T0,
        "t_end": T0 + 250 * (n - 1),
        "samples": samples,
    }


async def _site(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> tuple[str, str, dict[int, str]]:
    r = await client.post("/v1/sites", json={"name": "quality"}, headers=admin)
    assert r.status_code == 201, r.text
    site_id = r.json()["id"]
    r = await client.post(f"/v1/sites/{site_id}/buildings", json={"name": "Q"}, headers=admin)
    assert r.status_code == 201, r.text
    building_id = r.json()["id"]
    floors = {}
    for level in (0, 1):
        r = await client.post(
            f"/v1/buildings/{building_id}/floors", json={"level": level}, headers=admin
        )
        assert r.status_code == 201, r.text
        floors[level] = r.json()["id"]
    return site_id, building_id, floors


@pytest.fixture
async def surveyed(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> tuple[str, str]:
    """Level 0 of a new building: plan, radio survey over the west half (x < 10, two
    points per 1 m cell on five days), one old point from an upload in the east half, a
    magnetic line. Returns the floor ids of levels 0 and 1."""
    site_id, building_id, floors = await _site(client, admin)
    rng = np.random.default_rng(7)
    floor = floors[0]
    r = await client.put(f"/v1/floors/{floor}/plan", json=PLAN, headers=admin)
    assert r.status_code == 200, r.text

    points: list[dict[str, Any]] = []
    for ix in range(10):
        for iy in range(10):
            for dx in (0.25, 0.75):
                k = len(points)
                x, y = ix + dx, iy + 0.5
                points.append(
                    {
                        "x_m": x,
                        "y_m": y,
                        "floor": 0,
                        "t": T0 + (k % 5) * DAY_MS + 1000 * k,
                        "wifi": [
                            {**w, "rssi_dbm": w["rssi_dbm"] + rng.normal(0.0, SHADOWING_DB)}
                            for w in rssi_at(x, y, 0)
                        ],
                    }
                )
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text

    # an upload's point in the east half, hearing an AP nobody heard since, made 60 days old
    async with app.state.runtime.transaction() as s:
        upload = await upload_repo.create_upload(
            s, site_id=site_id, content_type="text/plain", payload=b"", status="done"
        )
        ghost = maps.SurveyPointData(15.5, 5.5, 0, None, [(GHOST, -50.0)], [], None)
        await maps.add_survey(s, building_id, [ghost], upload_id=upload.id)
        row = (await s.scalars(select(SurveyPoint).where(SurveyPoint.upload_id == upload.id))).one()
        row.created_at = datetime.now(UTC) - timedelta(days=60)

    r = await client.post(
        f"/v1/floors/{floor}/magnetic-survey", json={"lines": [magnetic_line(5.25)]}, headers=admin
    )
    assert r.status_code == 201, r.text
    return floor, floors[1]


async def test_quality_of_a_surveyed_floor(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    r = await client.get(f"/v1/floors/{floor}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    q = r.json()
    assert q["floor_id"] == floor
    assert q["radio_map"]["version"] == 2
    assert q["magnetic_map"]["version"] == 1

    # radio: the 100 surveyed cells less the 4 under the pillar, plus the upload's cell
    cov = q["coverage"]
    assert cov["walkable_area_known"] is True
    assert cov["radio"] == pytest.approx((100 - 4 + 1) / 196)
    # magnetic: the line's 40 half-metre cells of the 784 walkable ones
    assert cov["magnetic"] == pytest.approx(40 / 784)

    # every surveyed RP: 2 points x 16 APs (both levels' 8 are heard); one RP of 1 reading
    radio = q["radio_cells"]
    assert radio["n_reference_points"] == 101
    assert radio["readings_per_rp"] == {"p10": 32.0, "p50": 32.0, "p90": 32.0}
    assert radio["emitters_per_rp"]["p50"] == 16.0
    assert 1.0 <= radio["var_db2"]["p50"] <= radio["var_db2"]["p90"]

    mag = q["magnetic_cells"]
    assert mag["known_cells"] == 40
    assert mag["samples_per_cell"] == {"p10": 2.0, "p50": 2.0, "p90": 2.0}
    assert 0.0 <= mag["var_ut2"]["p50"] <= mag["var_ut2"]["p90"]

    fresh = q["freshness"]
    assert fresh["n_points"] == 201
    assert fresh["n_surveyed_points"] == 200
    assert fresh["n_uploads"] == 1
    assert fresh["n_cells"] == 101
    newest = datetime.fromisoformat(fresh["newest"])
    oldest = datetime.fromisoformat(fresh["oldest"])
    assert datetime.now(UTC) - newest < timedelta(minutes=5)
    assert timedelta(days=59) < newest - oldest < timedelta(days=61)
    assert fresh["cell_age_days"]["p90"] < 1.0  # 100 of the 101 cells are new

    em = q["emitters"]
    assert em["seen"] == 17
    # level 0's APs within 4 m (-55 dBm) of the surveyed half: (0,0) (10,0) (0,10) (10,10)
    # (5,5); level 1's are 20 dB weaker, never strong
    assert em["fixed"] == 5
    assert em["retired"] == 1  # the ghost
    by_key = {p["key"]: p for p in em["positions"]}
    assert GHOST not in by_key  # one reading: no fit
    assert em["unlocated"] == 17 - len(em["positions"])
    # level 0's AP at (5, 5), in the middle of the survey: found to within a metre and
    # about its stated uncertainty; the path loss recovered, the residual the shadowing
    centre = by_key["02:00:00:00:00:06"]
    assert centre["kind"] == "wifi"
    assert centre["n"] == 200
    error_m = math.dist((centre["x_m"], centre["y_m"]), AP_XY[6])
    assert error_m < 1.0
    assert 0.0 < max(centre["xy_std_m"]) < 1.0
    assert error_m < 4.0 * math.hypot(*centre["xy_std_m"])
    assert centre["p0_dbm"] == pytest.approx(-40.0, abs=1.5)
    assert centre["exponent"] == pytest.approx(2.5, abs=0.2)
    assert centre["residual_rms_db"] == pytest.approx(SHADOWING_DB, rel=0.2)
    # level 1's AP at (5, 5), heard 20 dB weaker from level 0
    below = by_key["02:00:00:00:01:06"]
    assert math.dist((below["x_m"], below["y_m"]), AP_XY[6]) < 2.0
    assert below["p0_dbm"] == pytest.approx(-60.0, abs=2.0)


async def test_query_parameters(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    url = f"/v1/floors/{floor}/maps/quality"
    r = await client.get(url, params={"max_emitters": 2, "retired_after_days": 90}, headers=admin)
    assert r.status_code == 200, r.text
    em = r.json()["emitters"]
    assert em["retired"] == 0  # the ghost was heard 60 days ago: inside 90
    # every AP has 200 readings: ties go by key
    assert [p["key"] for p in em["positions"]] == ["02:00:00:00:00:00", "02:00:00:00:00:01"]
    assert all(
        math.dist((p["x_m"], p["y_m"]), xy) < 2.0
        for p, xy in zip(em["positions"], AP_XY[:2], strict=True)
    )

    r = await client.get(url, params={"max_emitters": 0}, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["emitters"]["positions"] == []
    assert r.json()["emitters"]["unlocated"] == 0

    for bad in ({"max_emitters": 501}, {"retired_after_days": 0}):
        r = await client.get(url, params=bad, headers=admin)
        assert r.status_code == 422, r.text
        assert next(iter(bad)) in r.json()["message"]


async def test_floor_without_its_own_maps(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    """Level 1 shares the building's radio map but has no RP, plan, grid or point."""
    _, upper = surveyed
    r = await client.get(f"/v1/floors/{upper}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    q = r.json()
    assert q["radio_map"] is not None
    assert q["magnetic_map"] is None
    assert q["coverage"] == {"radio": 0.0, "magnetic": 0.0, "walkable_area_known": False}
    assert q["radio_cells"]["n_reference_points"] == 0
    assert q["emitters"]["seen"] == 0


async def test_floor_without_a_plan(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    """Without a plan the shares are over the maps' own extent."""
    _, building_id, floors = await _site(client, admin)
    # three of the four 1 m cells of the box [0, 2) x [0, 2)
    points = [
        {"x_m": x, "y_m": y, "floor": 0, "wifi": rssi_at(x, y, 0)}
        for x, y in ((0.5, 0.5), (1.5, 0.5), (0.5, 1.5))
    ]
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    # the line's 40 cells in a grid of 42 x 3 (one empty cell around the samples' box)
    r = await client.post(
        f"/v1/floors/{floors[0]}/magnetic-survey",
        json={"lines": [magnetic_line(5.25)]},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/floors/{floors[0]}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    cov = r.json()["coverage"]
    assert cov["walkable_area_known"] is False
    assert cov["radio"] == pytest.approx(3 / 4)
    assert cov["magnetic"] == pytest.approx(40 / (42 * 3))


async def test_floor_without_any_map(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    _, _, floors = await _site(client, admin)
    r = await client.get(f"/v1/floors/{floors[0]}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json() == {
        "floor_id": floors[0],
        "radio_map": None,
        "magnetic_map": None,
        "coverage": {"radio": 0.0, "magnetic": 0.0, "walkable_area_known": False},
        "radio_cells": {
            "n_reference_points": 0,
            "readings_per_rp": None,
            "emitters_per_rp": None,
            "var_db2": None,
        },
        "magnetic_cells": {"known_cells": 0, "samples_per_cell": None, "var_ut2": None},
        "freshness": {
            "newest": None,
            "oldest": None,
            "n_cells": 0,
            "cell_age_days": None,
            "n_points": 0,
            "n_surveyed_points": 0,
            "n_uploads": 0,
        },
        "emitters": {"seen": 0, "fixed": 0, "retired": 0, "positions": [], "unlocated": 0},
    }


async def test_unknown_floor_and_no_admin(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    missing = "0" * 32
    r = await client.get(f"/v1/floors/{missing}/maps/quality", headers=admin)
    assert r.status_code == 404, r.text
    assert r.json()["detail"][0]["loc"] == ["floor_id"]
    assert missing in r.json()["message"]

    r = await client.get(f"/v1/floors/{missing}/maps/quality")
    assert r.status_code == 401
    r = await client.get(
        f"/v1/floors/{missing}/maps/quality", headers={"Authorization": "Bearer nope"}
    )
    assert r.status_code == 401
