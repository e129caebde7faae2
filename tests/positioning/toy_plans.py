"""A toy floor plan for the floor-plan tests: a 20 m x 10 m room, a wall with a door, a pillar."""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.positioning.plan.floor_plan import FloorPlan
from server.positioning.plan.geojson_plan import plan_from_geojson


def feature(kind: str, geometry_type: str, coordinates: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": {"kind": kind},
        "geometry": {"type": geometry_type, "coordinates": coordinates},
    }


def box(x0: float, y0: float, x1: float, y1: float) -> list[list[list[float]]]:
    return [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]


# 20 m x 10 m room, a thin wall at x = 10 with a 1 m door (y 4.5-5.5), a 2 m pillar
ROOM = {
    "type": "FeatureCollection",
    "features": [
        feature("walkable", "Polygon", box(0, 0, 20, 10)),
        feature("wall", "LineString", [[10, 0], [10, 10]]),
        feature("door", "LineString", [[10, 4.5], [10, 5.5]]),
        feature("wall", "Polygon", box(4, 2, 6, 4)),
        feature("anchor", "Point", [1, 1]),  # other kinds are ignored
    ],
}


@cache
def room() -> FloorPlan:
    return plan_from_geojson(ROOM)


def as_moves(a: Any, b: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_2d(np.asarray(b, dtype=float))
