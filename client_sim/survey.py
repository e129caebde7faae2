"""Survey points: one WiFi and one BLE scan and a magnetic reading at every grid point.

The grid covers the walkable ground of every floor (``spacing_m`` apart, default 2 m,
clear of walls); each point becomes a JSON-ready ``SurveyIn`` point
``{x_m, y_m, floor, t, wifi: [{bssid, rssi_dbm}], ble: [{id, rssi_dbm}], mag_ut}`` with
``mag_ut`` in the building frame (x east, y north, z up). :func:`survey_bodies` cuts the
points into request bodies of at most ``max_points`` points.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from client_sim.world import SyntheticWorld

MAX_POINTS_PER_REQUEST = 5000
_DECIMALS = 3


def survey_points(
    world: SyntheticWorld,
    rng: np.random.Generator,
    *,
    spacing_m: float = 2.0,
    t0_ms: int = 1_700_000_000_000,
    period_ms: int = 1000,
) -> list[dict[str, Any]]:
    """Survey points of every floor, lowest level first, ``period_ms`` apart in time."""
    points: list[dict[str, Any]] = []
    for floor in world.building.floors:
        xy = floor.walkable_grid(spacing_m)
        wifi = world.radio.wifi.scan(xy, floor.level, rng)
        ble = world.radio.ble.scan(xy, floor.level, rng)
        mag = np.round(world.magnetic.sample(xy, floor.level, rng), _DECIMALS)
        for i, (x, y) in enumerate(np.round(xy, _DECIMALS).tolist()):
            points.append(
                {
                    "x_m": x,
                    "y_m": y,
                    "floor": floor.level,
                    "t": t0_ms + period_ms * len(points),
                    "wifi": world.radio.wifi.readings(wifi[i]),
                    "ble": world.radio.ble.readings(ble[i]),
                    "mag_ut": mag[i].tolist(),
                }
            )
    return points


def survey_bodies(
    points: Sequence[dict[str, Any]], max_points: int = MAX_POINTS_PER_REQUEST
) -> Iterator[dict[str, Any]]:
    """``SurveyIn`` bodies ``{"points": [...]}`` of at most ``max_points`` points each, in
    order; nothing for no points."""
    if max_points < 1:
        raise ValueError("max_points must be at least 1")
    for start in range(0, len(points), max_points):
        yield {"points": list(points[start : start + max_points])}
