"""A small IMDF-style building for the routing tests: three levels in floor metres.

Levels 0 and 1 have the same footprint (x east, y north, metres)::

    y 20          +---------+         (level 0: the Bakery at x 0-10; level 1: the Office
                  |  room   |          at x 20-30; each with a door onto the hall)
    y 14 +----+   |         |
         |back|   |         |
    y 10 +----+---+--door---+-------------------+------+
         |        |                             | Lift |  an elevator unit on each level
         | west   |     hall (walkway)          +------+  y 6-10
         | lobby  |                             +------+  y 0-4
         |        |                             |Main  |  a stairs unit on each level
    y  0 +--------+-----------------------------+stairs+
        x -5      0                            30     34

* the west lobby of level 0 and the west lobby of level 1 are joined by a ``relationship``
  of category ``traversal`` through the "Back stairs" (a stairs unit north of the level-0
  lobby, with no counterpart on level 1): the only stairs link of the back stairs;
* level 1 has an ``amenity`` point, the "Toilets";
* level 2, the "Roof terrace", is a walkway with no stairs, lift or relationship: no route
  reaches it.

Names are IMDF labels (``{"en": ...}``); ids are per feature, as in IMDF, so the units of
one lift or staircase on two levels share a name and a footprint but not an id.
"""

from __future__ import annotations

import copy
from typing import Any

from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.routing_graph import FloorInput

BUILDING_ID = "imdf-b1"
LEVELS = (0, 1, 2)

Feature = dict[str, Any]


def box(x0: float, y0: float, x1: float, y1: float) -> dict[str, Any]:
    """A GeoJSON Polygon: the rectangle ``[x0, x1] x [y0, y1]``."""
    ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
    return {"type": "Polygon", "coordinates": [ring]}


def unit(feature_id: str, category: str, name: str | None, geometry: dict[str, Any]) -> Feature:
    properties: dict[str, Any] = {"category": category}
    if name is not None:
        properties["name"] = {"en": name}
    return {
        "type": "Feature",
        "id": feature_id,
        "feature_type": "unit",
        "geometry": geometry,
        "properties": properties,
    }


def opening(feature_id: str, line: list[list[float]]) -> Feature:
    return {
        "type": "Feature",
        "id": feature_id,
        "feature_type": "opening",
        "geometry": {"type": "LineString", "coordinates": line},
        "properties": {"category": "pedestrian"},
    }


def amenity(feature_id: str, category: str, name: str, xy: list[float]) -> Feature:
    return {
        "type": "Feature",
        "id": feature_id,
        "feature_type": "amenity",
        "geometry": {"type": "Point", "coordinates": xy},
        "properties": {"category": category, "name": {"en": name}},
    }


def ref(feature_id: str) -> dict[str, str]:
    return {"id": feature_id, "feature_type": "unit"}


BACK_STAIRS_TRAVERSAL: Feature = {
    "type": "Feature",
    "id": "r-back-stairs",
    "feature_type": "relationship",
    "geometry": None,
    "properties": {
        "category": "traversal",
        "direction": "undirected",
        "origin": ref("u0-west-lobby"),
        "intermediary": [ref("u0-back-stairs")],
        "destination": ref("u1-west-lobby"),
    },
}


def _level_0() -> list[Feature]:
    return [
        unit("u0-hall", "walkway", "Ground hall", box(0, 0, 30, 10)),
        unit("u0-bakery", "room", "Bakery", box(0, 10, 10, 20)),
        opening("o0-bakery", [[4, 10], [6, 10]]),
        unit("u0-main-stairs", "stairs", "Main stairs", box(30, 0, 34, 4)),
        unit("u0-lift", "elevator", "Lift", box(30, 6, 34, 10)),
        unit("u0-west-lobby", "walkway", "West lobby", box(-5, 0, 0, 10)),
        unit("u0-back-stairs", "stairs", "Back stairs", box(-5, 10, -1, 14)),
        BACK_STAIRS_TRAVERSAL,
    ]


def _level_1() -> list[Feature]:
    return [
        unit("u1-hall", "walkway", "First floor hall", box(0, 0, 30, 10)),
        unit("u1-office", "room", "Office", box(20, 10, 30, 20)),
        opening("o1-office", [[24, 10], [26, 10]]),
        unit("u1-main-stairs", "stairs", "Main stairs", box(30, 0, 34, 4)),
        unit("u1-lift", "elevator", "Lift", box(30, 6, 34, 10)),
        unit("u1-west-lobby", "walkway", "Upper west lobby", box(-5, 0, 0, 10)),
        amenity("a1-toilets", "restroom", "Toilets", [15, 8]),
    ]


def _level_2() -> list[Feature]:
    return [unit("u2-terrace", "walkway", "Roof terrace", box(0, 0, 30, 10))]


def imdf_levels() -> list[tuple[int, dict[str, Any]]]:
    """``(level, FeatureCollection)`` per level, lowest first; fresh copies to change."""
    features = (_level_0(), _level_1(), _level_2())
    return [
        (level, {"type": "FeatureCollection", "features": copy.deepcopy(found)})
        for level, found in zip(LEVELS, features, strict=True)
    ]


def floor_inputs(
    levels: list[tuple[int, dict[str, Any]]], building_id: str = BUILDING_ID
) -> list[FloorInput]:
    """The routing graph's input for ``(level, plan GeoJSON)`` pairs of one building."""
    return [
        FloorInput(building_id, level, plan_from_geojson(geojson), geojson)
        for level, geojson in levels
    ]
