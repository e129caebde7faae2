"""A small surveyed site built through the admin API, for the tests of the API, the
services and the live server.

One building, levels 0 and 1, a 20 m x 10 m floor surveyed every metre; eight WiFi
access points per floor with log-distance path loss (no shadowing), so a scan taken at a
surveyed point matches that point best.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np
from numpy.typing import NDArray

WIDTH_M, DEPTH_M = 20.0, 10.0
LEVELS = (0, 1)
AP_XY = np.array(
    [[0, 0], [10, 0], [20, 0], [0, 10], [10, 10], [20, 10], [5, 5], [15, 5]], dtype=float
)


def rssi_at(x_m: float, y_m: float, level: int) -> list[dict[str, Any]]:
    """Readings a phone at (x, y) on ``level`` hears: the floor's own APs loud, the other
    floor's 20 dB weaker."""
    readings = []
    for lvl in LEVELS:
        d = np.maximum(np.hypot(AP_XY[:, 0] - x_m, AP_XY[:, 1] - y_m), 1.0)
        rss: NDArray[np.float64] = -40.0 - 25.0 * np.log10(d) - 20.0 * abs(lvl - level)
        for i, value in enumerate(rss):
            if value > -95:
                readings.append(
                    {"bssid": f"02:00:00:00:{lvl:02x}:{i:02x}", "rssi_dbm": float(value)}
                )
    return readings


def toy_plan() -> dict[str, Any]:
    """A floor plan of the toy floor: one walkable 20 m x 10 m rectangle."""
    outline = [[0.0, 0.0], [WIDTH_M, 0.0], [WIDTH_M, DEPTH_M], [0.0, DEPTH_M], [0.0, 0.0]]
    walkable = {"type": "Polygon", "coordinates": [outline]}
    feature = {"type": "Feature", "properties": {"kind": "walkable"}, "geometry": walkable}
    return {"type": "FeatureCollection", "features": [feature]}


def linked_toy_plan() -> dict[str, Any]:
    """The toy floor with a lift at its west end and stairs at its east end (the same ids
    on every floor) and a point of interest, the information desk at (10, 8)."""
    plan = toy_plan()
    plan["features"] += [
        {
            "type": "Feature",
            "id": "lift",
            "properties": {"kind": "elevator", "name": "Lift"},
            "geometry": _square(1, 4, 2),
        },
        {
            "type": "Feature",
            "id": "stairs",
            "properties": {"kind": "stairs", "name": "Stairs"},
            "geometry": _square(WIDTH_M - 4, 4, 2),
        },
        {
            "type": "Feature",
            "properties": {"kind": "poi", "name": "Information desk"},
            "geometry": {"type": "Point", "coordinates": [10.0, 8.0]},
        },
    ]
    return plan


def _square(x0: float, y0: float, size: float) -> dict[str, Any]:
    ring = [[x0, y0], [x0 + size, y0], [x0 + size, y0 + size], [x0, y0 + size], [x0, y0]]
    return {"type": "Polygon", "coordinates": [ring]}


async def device_headers(
    client: httpx.AsyncClient,
    admin: dict[str, str],
    scopes: tuple[str, ...] = ("device",),
    site_id: str | None = None,
) -> dict[str, str]:
    """The header of a new key with ``scopes`` (for ``site_id`` only, when given)."""
    body: dict[str, Any] = {"name": "test device", "scopes": list(scopes)}
    if site_id is not None:
        body["site_id"] = site_id
    r = await client.post("/v1/keys", json=body, headers=admin)
    assert r.status_code == 201, r.text
    return {"Authorization": f"Bearer {r.json()['key']}"}


async def new_key(
    client: httpx.AsyncClient,
    admin: dict[str, str],
    scopes: tuple[str, ...],
    site_id: str | None = None,
) -> tuple[str, str]:
    """A new key with ``scopes`` (for ``site_id`` only, when given): its id and secret."""
    body: dict[str, Any] = {"name": "test key", "scopes": list(scopes), "site_id": site_id}
    r = await client.post("/v1/keys", json=body, headers=admin)
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["key"]


@dataclass(frozen=True)
class ToySite:
    site_id: str
    building_id: str
    floor_ids: dict[int, str]
    device: dict[str, str]  # the header of a device key for the site


async def build_toy_site(
    client: httpx.AsyncClient, admin: dict[str, str], building: dict[str, Any] | None = None
) -> ToySite:
    """The toy site; ``building`` adds fields to its building (e.g. a geo-reference)."""
    r = await client.post("/v1/sites", json={"name": "toy"}, headers=admin)
    assert r.status_code == 201, r.text
    site_id = r.json()["id"]
    r = await client.post(
        f"/v1/sites/{site_id}/buildings", json={"name": "B", **(building or {})}, headers=admin
    )
    assert r.status_code == 201, r.text
    building_id = r.json()["id"]
    floor_ids = {}
    for level in LEVELS:
        r = await client.post(
            f"/v1/buildings/{building_id}/floors", json={"level": level}, headers=admin
        )
        assert r.status_code == 201, r.text
        floor_ids[level] = r.json()["id"]
    points = [
        {"x_m": float(x), "y_m": float(y), "floor": level, "wifi": rssi_at(x, y, level)}
        for level in LEVELS
        for x in range(int(WIDTH_M) + 1)
        for y in range(int(DEPTH_M) + 1)
    ]
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    device = await device_headers(client, admin, site_id=site_id)
    return ToySite(site_id, building_id, floor_ids, device)


WALK_T0_MS = 1_700_000_000_000


def walk_batch(n: int) -> list[dict[str, Any]]:
    """Batch ``n`` of a walk east and back along y = 5 m: a step, a scan, a magnetometer
    reading."""
    x = 2.0 + (n % 30) * 0.5 if (n // 30) % 2 == 0 else 17.0 - (n % 30) * 0.5
    t = WALK_T0_MS + 600 * n
    heading = math.pi / 2 if (n // 30) % 2 == 0 else -math.pi / 2
    return [
        {"type": "step", "t": t, "length_m": 0.5, "heading_rad": heading},
        {"type": "wifi", "t": t + 50, "readings": rssi_at(x, 5.0, 0)},
        {"type": "mag", "t": t + 60, "field_ut": [20.0, 5.0, -40.0]},
    ]


def walk_upload(x0_m: float) -> dict[str, Any]:
    """A short walk of our own events east along y = 5 m from ``x0_m``, with two anchors:
    an upload the service accepts."""
    events = [
        {"type": "wifi", "t": WALK_T0_MS + 1000 * k, "readings": rssi_at(x0_m + k, 5, 0)}
        for k in range(4)
    ]
    anchors = [
        {"t": WALK_T0_MS, "x_m": x0_m, "y_m": 5.0},
        {"t": WALK_T0_MS + 3000, "x_m": x0_m + 3, "y_m": 5.0},
    ]
    return {"events": events, "anchors": anchors}
