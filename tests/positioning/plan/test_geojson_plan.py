"""Floor plans from GeoJSON: raster and walls of the room, doors, ILC kinds, rooms, bad plans,
extents."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.plan.floor_plan import valid_moves, walkable_at
from server.positioning.plan.geojson_format import PlanError
from server.positioning.plan.geojson_plan import near_extent, plan_extent, plan_from_geojson
from tests.support.toy_plans import (
    FLOOR,
    as_moves,
    box,
    feature,
    feature_collection,
    room,
)


def test_room_raster_and_walls() -> None:
    plan = room()
    assert plan.origin_m == (0.0, 0.0)
    assert plan.cell_m == 0.25
    assert plan.walkable.shape == (40, 80)
    assert plan.walkable.sum() * 0.25**2 == pytest.approx(200 - 4)
    assert not plan.walkable[8:16, 16:24].any()  # the pillar
    assert plan.walkable[:8].all()
    # 4 outline edges, 4 pillar edges, the thin wall in two pieces around the door
    assert plan.walls.shape == (10, 4)
    thin = plan.walls[(plan.walls[:, 0] == 10) & (plan.walls[:, 2] == 10)]
    assert sorted(sorted((y1, y2)) for _, y1, _, y2 in thin.tolist()) == [[0, 4.5], [5.5, 10]]


def test_thick_wall_with_a_door_polygon() -> None:
    plan = plan_from_geojson(
        {
            "features": [
                feature("walkable", "Polygon", box(0, 0, 20, 10)),
                feature("wall", "Polygon", box(9.75, 0, 10.25, 10)),
                feature("door", "Polygon", box(9.7, 4.5, 10.3, 5.5)),  # wider than the wall
            ]
        }
    )
    a, b = as_moves(
        [[9.5, 5.0], [9.5, 2.0], [9.5, 2.0], [9.5, 4.4]],
        [[10.5, 5.0], [10.5, 2.0], [10.0, 2.0], [10.5, 4.4]],
    )
    assert valid_moves(plan, a, b).tolist() == [True, False, False, False]
    assert walkable_at(plan, [[10.0, 5.0], [10.0, 2.0]]).tolist() == [True, False]


def test_ilc_kinds_outline_minus_units() -> None:
    plan = plan_from_geojson(
        {
            "features": [
                feature("outline", "MultiPolygon", [box(0, 0, 10, 10)]),
                feature("unit", "Polygon", box(2, 2, 8, 8)),
                feature("obstacle", "Polygon", box(0, 0, 1, 1)),
            ]
        }
    )
    assert walkable_at(plan, [[1.0, 5.0], [5.0, 5.0], [0.5, 0.5], [1.5, 1.5]]).tolist() == [
        True,
        False,
        False,
        True,
    ]
    assert valid_moves(
        plan, *as_moves([[1.0, 5.0], [1.0, 5.0]], [[1.0, 6.0], [2.5, 5.0]])
    ).tolist() == [
        True,
        False,
    ]


@pytest.mark.parametrize(
    ("geojson", "message"),
    [
        pytest.param({"features": []}, "no walkable polygon", id="empty"),
        pytest.param({"features": [3]}, "features.0: not a GeoJSON feature", id="not a feature"),
        pytest.param(
            {"features": [feature("wall", "LineString", [[0, 0], [1, 1]])]},
            "no walkable polygon",
            id="walls only",
        ),
        pytest.param(
            {"features": [feature("walkable", "LineString", [[0, 0], [1, 1]])]},
            "features.0.geometry.type: a walkable is a Polygon or MultiPolygon, not a LineString",
            id="walkable line",
        ),
        pytest.param(
            {
                "features": [
                    feature("walkable", "Polygon", box(0, 0, 1, 1)),
                    feature("door", "Point", [0.5, 0.0]),
                ]
            },
            "features.1.geometry.type: a door is a Polygon, MultiPolygon, LineString or "
            "MultiLineString, not a Point",
            id="door point",
        ),
        pytest.param(
            {"features": [{"properties": {"kind": "walkable"}, "geometry": {"type": "Nope"}}]},
            "features.0.geometry: a walkable needs a GeoJSON geometry",
            id="bad geometry",
        ),
        pytest.param(
            {
                "features": [
                    feature("walkable", "Polygon", box(0, 0, 1, 1)),
                    feature("wall", "Polygon", box(-1, -1, 2, 2)),
                ]
            },
            "features: the walls and obstacles cover all the walkable area",
            id="all walled",
        ),
    ],
)
def test_bad_plans(geojson: dict[str, Any], message: str) -> None:
    with pytest.raises(PlanError, match=message):
        plan_from_geojson(geojson)


def test_a_self_crossing_polygon_is_repaired() -> None:
    bow_tie = [[[0, 0], [4, 4], [4, 0], [0, 4], [0, 0]]]  # two triangles meeting at (2, 2)
    plan = plan_from_geojson({"features": [feature("walkable", "Polygon", bow_tie)]})
    assert walkable_at(plan, [[0.5, 2.0], [2.0, 0.5], [3.5, 2.0]]).tolist() == [True, False, True]
    assert plan.walls.shape == (6, 4)
    assert not valid_moves(plan, [[0.5, 2.0]], [[3.5, 2.0]]).any()  # through the waist


def test_plan_extent_is_the_box_of_the_walkable_features() -> None:
    plan = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"kind": "walkable"},
                "geometry": {"type": "Polygon", "coordinates": [[[1, 2], [9, 2], [9, 5], [1, 2]]]},
            },
            {
                "type": "Feature",
                "properties": {"beacon": "b"},
                "geometry": {"type": "Point", "coordinates": [500, 500]},
            },
        ],
    }
    assert plan_extent(plan) == (1.0, 2.0, 9.0, 5.0)
    assert plan_extent({"type": "FeatureCollection", "features": []}) is None
    assert plan_extent(None) is None


coordinate = st.floats(-100.0, 100.0)


@given(x=coordinate, y=coordinate)
def test_a_point_is_near_an_extent_within_the_margin_per_axis(x: float, y: float) -> None:
    # the box (0, 0)..(20, 10) grown by the 10 m margin: x in [-10, 30], y in [-10, 20]
    (x_near, y_near), *_ = near_extent((0.0, 0.0, 20.0, 10.0), [(x, y)]).tolist()
    assert x_near == (-10.0 <= x <= 30.0)
    assert y_near == (-10.0 <= y <= 20.0)
    # one extent per point: the same answer
    boxes = [(0.0, 0.0, 20.0, 10.0), (-5.0, -5.0, 5.0, 5.0)]
    both = near_extent(boxes, [(x, y), (x, y)], margin_m=0.0).tolist()
    assert both == [[0.0 <= x <= 20.0, 0.0 <= y <= 10.0], [-5.0 <= x <= 5.0, -5.0 <= y <= 5.0]]


def test_a_room_is_walled_along_its_rings() -> None:
    plan = plan_from_geojson(
        feature_collection(
            FLOOR,
            feature("room", "Polygon", box(12, 4, 18, 8)),
            feature("door", "LineString", [[14, 4], [15, 4]]),
        )
    )
    a, b = as_moves([[14.5, 2.0], [16.5, 2.0], [2.0, 2.0]], [[14.5, 6.0], [16.5, 6.0], [2.0, 6.0]])
    assert valid_moves(plan, a, b).tolist() == [True, False, True]
