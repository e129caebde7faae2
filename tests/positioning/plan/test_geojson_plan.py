"""Floor plans from GeoJSON: raster and walls of the room, doors, ILC kinds, bad plans, extents."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.plan.floor_plan import valid_moves, walkable_at
from server.positioning.plan.geojson_plan import (
    PlanError,
    near_extent,
    plan_extent,
    plan_from_geojson,
    validate_plan,
)
from tests.positioning.toy_plans import ROOM, as_moves, box, feature, room


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


# validate_plan: what a plan sent to the service must pass


def _plan(*features: dict[str, Any]) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": list(features)}


def _unkinded(geometry_type: str, coordinates: Any, **members: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": members.pop("properties", {}),
        "geometry": {"type": geometry_type, "coordinates": coordinates},
        **members,
    }


FLOOR = feature("walkable", "Polygon", box(0, 0, 20, 10))
BARCELONA = (41.39, 2.17)  # (lat, lon) of a building's origin


@pytest.mark.parametrize(
    ("plan", "origin", "field", "reason"),
    [
        pytest.param(
            _plan(FLOOR, _unkinded("Polygon", box(2, 2, 4, 4))),
            None,
            "features.1.properties.kind",
            "missing: a Polygon needs a kind",
            id="polygon without a kind",
        ),
        pytest.param(
            _plan(FLOOR, _unkinded("LineString", [[0, 5], [20, 5]])),
            None,
            "features.1.properties.kind",
            "missing: a LineString needs a kind",
            id="line without a kind",
        ),
        pytest.param(
            _plan(feature("corridor", "Polygon", box(0, 0, 20, 10))),
            None,
            "features.0.properties.kind",
            "unknown kind 'corridor'",
            id="unknown kind",
        ),
        pytest.param(
            _plan({**FLOOR, "properties": {"kind": 3}}),
            None,
            "features.0.properties.kind",
            "must be a string",
            id="kind not a string",
        ),
        pytest.param(
            _plan({**FLOOR, "properties": "walkable"}),
            None,
            "features.0.properties",
            "must be an object",
            id="properties not an object",
        ),
        pytest.param(
            _plan(feature("walkable", "Polygon", [[[0, 0], [10, 10]]])),
            None,
            "features.0.geometry.coordinates.0",
            "this one has 2 positions",
            id="two-point ring",
        ),
        pytest.param(
            _plan(feature("walkable", "Polygon", [[[0, 0], [10, 0], [10, 10], [0, 10]]])),
            None,
            "features.0.geometry.coordinates.0",
            "not closed",
            id="ring not closed",
        ),
        pytest.param(
            _plan(feature("walkable", "Polygon", [[[0, 0], [4, 4], [4, 0], [0, 4], [0, 0]]])),
            None,
            "features.0.geometry",
            "not a valid Polygon \\(Self-intersection",
            id="self-crossing ring",
        ),
        pytest.param(
            _plan(feature("walkable", "MultiPolygon", [box(0, 0, 6, 6), box(4, 4, 10, 10)])),
            None,
            "features.0.geometry",
            "not a valid MultiPolygon",
            id="overlapping parts",
        ),
        pytest.param(
            _plan(FLOOR, feature("wall", "Polygon", [box(4, 4, 6, 6)[0], box(8, 8, 9, 9)[0]])),
            None,
            "features.1.geometry",
            "not a valid Polygon \\(Hole lies outside shell",
            id="hole outside its shell",
        ),
        pytest.param(
            _plan(feature("walkable", "Polygon", [[[0, 0], [10, 0], [10, "y"], [0, 0]]])),
            None,
            "features.0.geometry.coordinates.0.2",
            "a position is \\[x, y\\] or \\[x, y, z\\]",
            id="position not numbers",
        ),
        pytest.param(
            _plan(feature("wall", "LineString", [[0, 0], [float("inf"), 0]])),
            None,
            "features.0.geometry.coordinates.1",
            "in finite metres",
            id="position not finite",
        ),
        pytest.param(
            _plan(feature("walkable", "LineString", [[0, 0], [1, 1]])),
            None,
            "features.0.geometry.type",
            "a walkable is a Polygon or MultiPolygon, not 'LineString'",
            id="walkable line",
        ),
        pytest.param(
            _plan({**FLOOR, "geometry": None}),
            None,
            "features.0.geometry",
            "must be a GeoJSON geometry",
            id="walkable without geometry",
        ),
        pytest.param(
            # a 180 m x 110 m building in degrees, no geo-reference to compare with
            _plan(feature("walkable", "Polygon", box(2.17, 41.39, 2.1721, 41.391))),
            None,
            "features.0.geometry.coordinates",
            "spans 0.0021 m x 0.001 m, all within longitude/latitude ranges",
            id="degrees read as metres",
        ),
        pytest.param(
            # beacons only, but right where the building's origin is in degrees
            _plan(
                _unkinded("Point", [2.1702, 41.3901], properties={"beacon": "door"}),
                _unkinded("Point", [2.1712, 41.3905], properties={"beacon": "lift"}),
            ),
            BARCELONA,
            "features.0.geometry.coordinates",
            "within 0.05 degrees of the building's origin",
            id="degrees at the building's origin",
        ),
        pytest.param(
            _plan(feature("walkable", "Polygon", box(41.39, 2.17, 41.392, 2.171))),
            BARCELONA,
            "features.0.geometry.coordinates",
            "these are longitude/latitude",
            id="latitude first",
        ),
        pytest.param(
            _plan(feature("walkable", "Polygon", box(0, 0, 3000, 10))),
            None,
            "features.0.geometry.coordinates",
            "spans 3000 m x 10 m",
            id="a city, not a floor",
        ),
        pytest.param(
            _plan(feature("wall", "LineString", [[0, 0], [10, 0]])),
            None,
            "features",
            "walls and doors but no walkable area",
            id="walls only",
        ),
        pytest.param(
            _plan(FLOOR, feature("obstacle", "Polygon", box(-1, -1, 21, 11))),
            None,
            "features",
            "cover all the walkable area",
            id="all covered",
        ),
    ],
)
def test_validation_refuses_naming_the_feature_and_property(
    plan: dict[str, Any], origin: tuple[float, float] | None, field: str, reason: str
) -> None:
    with pytest.raises(PlanError, match=reason) as refused:
        validate_plan(plan, origin)
    assert refused.value.field == field
    assert str(refused.value).startswith(f"{field}: ")


def test_validation_keeps_a_good_plan_as_it_is() -> None:
    plan = {**ROOM, "name": "ground floor"}
    assert validate_plan(plan) == plan
    assert validate_plan(plan, BARCELONA) == plan  # metres, though the building is geo-referenced
    # anchors only, a malformed one among them (anchors skip it), and a feature without geometry
    anchors = _plan(
        _unkinded("Point", [17.5, 2.5], properties={"anchor": "elevator", "beacon": "lift-a"}),
        _unkinded("Point", {"x": 1, "y": 2}, properties={"beacon": "lift-b"}),
        {"type": "Feature", "properties": {"note": "fire exit"}, "geometry": None},
    )
    assert validate_plan(anchors, BARCELONA) == anchors
    # a small plan far from its frame's origin is metres, not degrees
    small = _plan(feature("walkable", "Polygon", box(1000.0, 500.0, 1001.5, 501.0)))
    assert validate_plan(small) == small


def test_the_ilc_sample_plans_pass_validation() -> None:
    from server.datasets.ilc import read_site
    from tests.datasets.conftest import dataset_dir

    site = read_site(dataset_dir("ilc20-sample") / "site2")
    for floor in site.floors:
        assert floor.plan is not None
        assert validate_plan(floor.plan) == floor.plan


# an IMDF-style floor in metres: a corridor unit (y 0-4), an office unit above it with an
# opening at x 4-6, a column fixture, an elevator unit, and the level (informational)
IMDF_FLOOR = _plan(
    _unkinded("Polygon", box(0, 0, 20, 4), feature_type="unit", properties={"category": "walkway"}),
    _unkinded("Polygon", box(0, 4, 10, 10), feature_type="unit", properties={"category": "office"}),
    _unkinded(
        "LineString",
        [[4, 4], [6, 4]],
        feature_type="opening",
        properties={"category": "pedestrian"},
    ),
    _unkinded("Polygon", box(15, 1, 16, 2), feature_type="fixture", properties={}),
    _unkinded(
        "Polygon", box(17, 4, 20, 7), properties={"feature_type": "unit", "category": "elevator"}
    ),
    _unkinded("Polygon", box(0, 0, 20, 10), feature_type="level", properties={"ordinal": 0}),
)


def test_imdf_units_and_openings_are_stored_with_their_kinds() -> None:
    stored = validate_plan(IMDF_FLOOR)
    kinds = [f["properties"].get("kind") for f in stored["features"]]
    assert kinds == ["walkable", "room", "door", "obstacle", "elevator", None]
    assert IMDF_FLOOR["features"][0]["properties"] == {"category": "walkway"}  # not changed
    assert validate_plan(stored) == stored
    plan = plan_from_geojson(stored)
    # into the office through the opening only; the column is no place to stand; the
    # elevator opens onto the corridor
    a, b = as_moves([[5.0, 2.0], [2.0, 2.0], [18.5, 2.0]], [[5.0, 6.0], [2.0, 6.0], [18.5, 5.5]])
    assert valid_moves(plan, a, b).tolist() == [True, False, True]
    assert walkable_at(plan, [[15.5, 1.5], [8.0, 8.0], [14.0, 8.0]]).tolist() == [
        False,
        True,
        False,
    ]


def test_a_room_is_walled_along_its_rings() -> None:
    plan = plan_from_geojson(
        _plan(
            FLOOR,
            feature("room", "Polygon", box(12, 4, 18, 8)),
            feature("door", "LineString", [[14, 4], [15, 4]]),
        )
    )
    a, b = as_moves([[14.5, 2.0], [16.5, 2.0], [2.0, 2.0]], [[14.5, 6.0], [16.5, 6.0], [2.0, 6.0]])
    assert valid_moves(plan, a, b).tolist() == [True, False, True]


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=20,
)
_position = st.lists(st.integers(-(10**400), 10**400) | st.floats(), min_size=1, max_size=4)
_geometry = st.fixed_dictionaries(
    {
        "type": st.sampled_from(["Point", "LineString", "Polygon", "MultiPolygon", "Nope"]) | _json,
        "coordinates": st.recursive(_position, lambda c: st.lists(c, max_size=6), max_leaves=30)
        | _json,
    }
)
_feature = st.fixed_dictionaries(
    {
        "type": st.just("Feature"),
        "properties": st.none()
        | st.fixed_dictionaries(
            {},
            optional={
                "kind": st.sampled_from(["walkable", "room", "wall", "door", "x"]) | _json,
                "category": st.sampled_from(["walkway", "office", "column"]) | _json,
                "feature_type": st.sampled_from(["unit", "opening", "level"]) | _json,
            },
        )
        | _json,
        "geometry": st.none() | _geometry | _json,
    },
    optional={"feature_type": st.sampled_from(["unit", "opening", "level"]) | _json},
)


@settings(max_examples=300, deadline=None)
@given(st.lists(_feature | _json, max_size=4))
def test_validation_answers_any_json_with_a_plan_or_a_plan_error(features: list[Any]) -> None:
    answer: dict[str, Any] | PlanError
    try:
        answer = validate_plan({"type": "FeatureCollection", "features": features})
    except PlanError as refused:
        answer = refused
    if isinstance(answer, PlanError):
        assert answer.field.startswith("features")
    else:
        assert len(answer["features"]) == len(features)
