"""``validate_plan``: what a floor plan sent to the service must pass, what it refuses and how
it names the feature at fault, IMDF-style plans, and any JSON at all."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.plan.floor_plan import valid_moves, walkable_at
from server.positioning.plan.geojson_format import PlanError
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.positioning.plan.geojson_validation import validate_plan
from tests.support.toy_plans import FLOOR, ROOM, as_moves, box, feature, feature_collection


def _unkinded(geometry_type: str, coordinates: Any, **members: Any) -> dict[str, Any]:
    return {
        "type": "Feature",
        "properties": members.pop("properties", {}),
        "geometry": {"type": geometry_type, "coordinates": coordinates},
        **members,
    }


BARCELONA = (41.39, 2.17)  # (lat, lon) of a building's origin


@pytest.mark.parametrize(
    ("plan", "origin", "field", "reason"),
    [
        pytest.param(
            feature_collection(FLOOR, _unkinded("Polygon", box(2, 2, 4, 4))),
            None,
            "features.1.properties.kind",
            "missing: a Polygon needs a kind",
            id="polygon without a kind",
        ),
        pytest.param(
            feature_collection(FLOOR, _unkinded("LineString", [[0, 5], [20, 5]])),
            None,
            "features.1.properties.kind",
            "missing: a LineString needs a kind",
            id="line without a kind",
        ),
        pytest.param(
            feature_collection(feature("corridor", "Polygon", box(0, 0, 20, 10))),
            None,
            "features.0.properties.kind",
            "unknown kind 'corridor'",
            id="unknown kind",
        ),
        pytest.param(
            feature_collection({**FLOOR, "properties": {"kind": 3}}),
            None,
            "features.0.properties.kind",
            "must be a string",
            id="kind not a string",
        ),
        pytest.param(
            feature_collection({**FLOOR, "properties": "walkable"}),
            None,
            "features.0.properties",
            "must be an object",
            id="properties not an object",
        ),
        pytest.param(
            feature_collection(feature("walkable", "Polygon", [[[0, 0], [10, 10]]])),
            None,
            "features.0.geometry.coordinates.0",
            "this one has 2 positions",
            id="two-point ring",
        ),
        pytest.param(
            feature_collection(
                feature("walkable", "Polygon", [[[0, 0], [10, 0], [10, 10], [0, 10]]])
            ),
            None,
            "features.0.geometry.coordinates.0",
            "not closed",
            id="ring not closed",
        ),
        pytest.param(
            feature_collection(
                feature("walkable", "Polygon", [[[0, 0], [4, 4], [4, 0], [0, 4], [0, 0]]])
            ),
            None,
            "features.0.geometry",
            "not a valid Polygon \\(Self-intersection",
            id="self-crossing ring",
        ),
        pytest.param(
            feature_collection(
                feature("walkable", "MultiPolygon", [box(0, 0, 6, 6), box(4, 4, 10, 10)])
            ),
            None,
            "features.0.geometry",
            "not a valid MultiPolygon",
            id="overlapping parts",
        ),
        pytest.param(
            feature_collection(
                FLOOR, feature("wall", "Polygon", [box(4, 4, 6, 6)[0], box(8, 8, 9, 9)[0]])
            ),
            None,
            "features.1.geometry",
            "not a valid Polygon \\(Hole lies outside shell",
            id="hole outside its shell",
        ),
        pytest.param(
            feature_collection(
                feature("walkable", "Polygon", [[[0, 0], [10, 0], [10, "y"], [0, 0]]])
            ),
            None,
            "features.0.geometry.coordinates.0.2",
            "a position is \\[x, y\\] or \\[x, y, z\\]",
            id="position not numbers",
        ),
        pytest.param(
            feature_collection(feature("wall", "LineString", [[0, 0], [float("inf"), 0]])),
            None,
            "features.0.geometry.coordinates.1",
            "in finite metres",
            id="position not finite",
        ),
        pytest.param(
            feature_collection(feature("walkable", "LineString", [[0, 0], [1, 1]])),
            None,
            "features.0.geometry.type",
            "a walkable is a Polygon or MultiPolygon, not 'LineString'",
            id="walkable line",
        ),
        pytest.param(
            feature_collection({**FLOOR, "geometry": None}),
            None,
            "features.0.geometry",
            "must be a GeoJSON geometry",
            id="walkable without geometry",
        ),
        pytest.param(
            # a 180 m x 110 m building in degrees, no geo-reference to compare with
            feature_collection(feature("walkable", "Polygon", box(2.17, 41.39, 2.1721, 41.391))),
            None,
            "features.0.geometry.coordinates",
            "spans 0.0021 m x 0.001 m, all within longitude/latitude ranges",
            id="degrees read as metres",
        ),
        pytest.param(
            # beacons only, but right where the building's origin is in degrees
            feature_collection(
                _unkinded("Point", [2.1702, 41.3901], properties={"beacon": "door"}),
                _unkinded("Point", [2.1712, 41.3905], properties={"beacon": "lift"}),
            ),
            BARCELONA,
            "features.0.geometry.coordinates",
            "within 0.05 degrees of the building's origin",
            id="degrees at the building's origin",
        ),
        pytest.param(
            feature_collection(feature("walkable", "Polygon", box(41.39, 2.17, 41.392, 2.171))),
            BARCELONA,
            "features.0.geometry.coordinates",
            "these are longitude/latitude",
            id="latitude first",
        ),
        pytest.param(
            feature_collection(feature("walkable", "Polygon", box(0, 0, 3000, 10))),
            None,
            "features.0.geometry.coordinates",
            "spans 3000 m x 10 m",
            id="a city, not a floor",
        ),
        pytest.param(
            feature_collection(feature("wall", "LineString", [[0, 0], [10, 0]])),
            None,
            "features",
            "walls and doors but no walkable area",
            id="walls only",
        ),
        pytest.param(
            feature_collection(FLOOR, feature("obstacle", "Polygon", box(-1, -1, 21, 11))),
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
    anchors = feature_collection(
        _unkinded("Point", [17.5, 2.5], properties={"anchor": "elevator", "beacon": "lift-a"}),
        _unkinded("Point", {"x": 1, "y": 2}, properties={"beacon": "lift-b"}),
        {"type": "Feature", "properties": {"note": "fire exit"}, "geometry": None},
    )
    assert validate_plan(anchors, BARCELONA) == anchors
    # a small plan far from its frame's origin is metres, not degrees
    small = feature_collection(feature("walkable", "Polygon", box(1000.0, 500.0, 1001.5, 501.0)))
    assert validate_plan(small) == small


def test_the_ilc_sample_plans_pass_validation() -> None:
    from lab.datasets.ilc import read_site
    from tests.support.datasets import dataset_dir

    site = read_site(dataset_dir("ilc20-sample") / "site2")
    for floor in site.floors:
        assert floor.plan is not None
        assert validate_plan(floor.plan) == floor.plan


# an IMDF-style floor in metres: a corridor unit (y 0-4), an office unit above it with an
# opening at x 4-6, a column fixture, an elevator unit, and the level (informational)
IMDF_FLOOR = feature_collection(
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
