"""The toy floor of the map-quality and survey-plan tests, built through the admin API.

20 m x 10 m of floor with a 2 m x 2 m pillar, the toy site's access points
(``tests.support.toy_site``); ``survey_floor`` surveys the west half of level 0, adds an
old upload's point in the east half and a magnetic line, so that the expected figures of
its quality follow from its geometry (the fixture: ``surveyed`` in
``tests/api/conftest.py``).
"""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import numpy as np
from fastapi import FastAPI
from sqlalchemy import select

from server.positioning.mapping.survey_points import SurveyPointData
from server.services import maps
from server.storage.models import SurveyPoint
from server.storage.repositories import uploads as upload_repo
from tests.support.toy_site import rssi_at

T0 = 1_700_000_000_000
DAY_MS = 86_400_000
GHOST = "02:00:00:00:ff:01"  # an AP heard only by a point created 60 days ago
SHADOWING_DB = 2.0  # RSS noise added to the toy's log-distance readings


def polygon(x0: float, y0: float, x1: float, y1: float, kind: str) -> dict[str, Any]:
    """A plan feature of ``kind``: the box [x0, x1] x [y0, y1]."""
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
    "features": [polygon(0, 0, 20, 10, "walkable"), polygon(2, 2, 4, 4, "obstacle")],
}


def field_at(x_m: float) -> float:
    """The magnetic field's strength (µT) at ``x_m`` along the magnetic line."""
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


async def new_site(
    client: httpx.AsyncClient, admin: dict[str, str]
) -> tuple[str, str, dict[int, str]]:
    """A new site with one building of levels 0 and 1, nothing surveyed: the site's, the
    building's and the floors' ids."""
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


async def survey_floor(
    client: httpx.AsyncClient, admin: dict[str, str], app: FastAPI
) -> tuple[str, str]:
    """Level 0 of a new building: plan, radio survey over the west half (x < 10, two
    points per 1 m cell on five days), one old point from an upload in the east half, a
    magnetic line. Returns the floor ids of levels 0 and 1."""
    site_id, building_id, floors = await new_site(client, admin)
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
        ghost = SurveyPointData(15.5, 5.5, 0, None, [(GHOST, -50.0)], [], None)
        await maps.add_survey(s, building_id, [ghost], upload_id=upload.id)
        row = (await s.scalars(select(SurveyPoint).where(SurveyPoint.upload_id == upload.id))).one()
        row.created_at = datetime.now(UTC) - timedelta(days=60)

    r = await client.post(
        f"/v1/floors/{floor}/magnetic-survey", json={"lines": [magnetic_line(5.25)]}, headers=admin
    )
    assert r.status_code == 201, r.text
    return floor, floors[1]
