"""Zones read from GeoJSON: which features count, ids and names, the errors that name the
field at fault, and which zones hold a point."""

from __future__ import annotations

from typing import Any

import pytest
import shapely

from server.positioning.plan.geojson_format import PlanError
from server.positioning.plan.zones import Zone, ZoneIndex, as_feature, zones_from_geojson
from tests.support.toy_plans import feature_collection as collection
from tests.support.toy_plans import square


def feature(geometry: dict[str, Any] | None, **members: Any) -> dict[str, Any]:
    properties = members.pop("properties", {})
    return {"type": "Feature", "geometry": geometry, "properties": properties, **members}


def test_plain_polygons_imdf_zone_types_and_kind_zone_are_zones_the_rest_is_skipped() -> None:
    read = zones_from_geojson(
        collection(
            feature(square(0, 0, 2), id="plain", properties={"name": "Plain"}),
            feature(square(3, 0, 2), id="fence", feature_type="geofence"),
            feature(
                square(6, 0, 2), id="shop", feature_type="unit", properties={"category": "shop"}
            ),
            feature(square(9, 0, 2), id="sec", properties={"feature_type": "section"}),
            feature(square(12, 0, 2), id="k", properties={"kind": "zone", "name": "K"}),
            feature(square(0, 5, 10), properties={"kind": "walkable"}),
            feature(
                {"type": "LineString", "coordinates": [[0, 0], [1, 0]]}, properties={"kind": "wall"}
            ),
            feature(square(0, 5, 1), feature_type="opening"),
            feature(square(0, 5, 1), feature_type="level"),
            feature({"type": "Point", "coordinates": [1, 1]}, properties={"name": "entrance"}),
            feature(square(0, 5, 1), feature_type="unit", properties={"category": "column"}),
        )
    )
    assert [z.id for z in read.zones] == ["plain", "fence", "shop", "sec", "k"]
    assert read.skipped == 6
    # without a name the id names it
    assert [z.name for z in read.zones] == ["Plain", "fence", "shop", "sec", "K"]


def test_names_come_from_imdf_labels_english_first() -> None:
    labels = {"fr": "Boutique", "en": "Shop"}
    read = zones_from_geojson(
        collection(feature(square(0, 0, 1), id=7, properties={"name": labels}))
    )
    assert read.zones[0].id == "7"  # an integer id as text
    assert read.zones[0].name == "Shop"
    other = {"alt_name": {"de": "Laden"}}
    read = zones_from_geojson(collection(feature(square(0, 0, 1), id="a", properties=other)))
    assert read.zones[0].name == "Laden"


def test_a_zone_without_an_id_gets_one_from_its_name_and_geometry_the_same_each_time() -> None:
    one = zones_from_geojson(collection(feature(square(0, 0, 1), properties={"name": "A"})))
    again = zones_from_geojson(collection(feature(square(0, 0, 1), properties={"name": "A"})))
    moved = zones_from_geojson(collection(feature(square(0, 0, 2), properties={"name": "A"})))
    assert one.zones[0].id == again.zones[0].id
    assert one.zones[0].id != moved.zones[0].id


def test_as_feature_reads_back_as_the_same_zone_its_properties_as_sent() -> None:
    labels = {"name": {"en": "A", "fr": "Un"}, "floor": "shop"}
    read = zones_from_geojson(collection(feature(square(0, 0, 1), id="a", properties=labels)))
    shown = as_feature(read.zones[0])
    assert shown["name"] == "A"
    assert shown["properties"] == labels
    again = zones_from_geojson(collection(shown))
    assert again.zones == read.zones


@pytest.mark.parametrize(
    ("bad", "field"),
    [
        ({"type": "Feature", "features": []}, "type"),
        ({"type": "FeatureCollection", "features": {}}, "features"),
        (collection({"type": "Point"}), "features.0"),
        (collection(feature(None, id="a")), "features.0.geometry"),
        (
            collection(
                feature(
                    {"type": "Point", "coordinates": [0, 0]}, id="a", properties={"kind": "zone"}
                )
            ),
            "features.0.geometry.type",
        ),
        (
            collection(
                feature({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [0, 0]]]}, id="a")
            ),
            "features.0.geometry.coordinates.0",
        ),
        (
            collection(
                feature(
                    {"type": "Polygon", "coordinates": [[[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]]]},
                    id="a",
                )
            ),
            "features.0.geometry",
        ),
        (collection(feature(square(0, 0, 1), id="a b")), "features.0.id"),
        (collection(feature(square(0, 0, 1), id=True)), "features.0.id"),
        (
            collection(feature(square(0, 0, 1), id="a"), feature(square(2, 0, 1), id="a")),
            "features.1.id",
        ),
        (
            collection(feature(square(0, 0, 1), id="a", properties={"name": "x" * 201})),
            "features.0.properties.name",
        ),
        (collection(feature(square(0, 0, 1), id="a", properties=[1])), "features.0.properties"),
    ],
)
def test_what_is_not_a_zone_is_refused_naming_the_field(bad: dict[str, Any], field: str) -> None:
    with pytest.raises(PlanError) as caught:
        zones_from_geojson(bad)
    assert caught.value.field == field


def zone(floor: int, zone_id: str, geometry: dict[str, Any]) -> Zone:
    return Zone(floor, f"floor{floor}", zone_id, zone_id.upper(), shapely.geometry.shape(geometry))


def test_the_index_finds_the_zones_of_the_point_s_floor_only() -> None:
    index = ZoneIndex(
        [
            zone(0, "a", square(0, 0, 4)),
            zone(0, "b", square(2, 2, 4)),
            zone(1, "c", square(0, 0, 4)),
        ]
    )
    assert [z.id for z in index.at(0, 1, 1)] == ["a"]
    assert [z.id for z in index.at(0, 3, 3)] == ["a", "b"]
    assert [z.id for z in index.at(0, 5, 5)] == ["b"]
    assert index.at(0, 7, 7) == ()
    assert [z.id for z in index.at(1, 1, 1)] == ["c"]
    assert index.at(2, 1, 1) == ()
    assert [z.id for z in index.at(0, 4, 1)] == ["a"]  # on the border: in
    assert index.by_key["floor1/c"].name == "C"


def test_a_zone_with_a_hole_does_not_hold_the_hole() -> None:
    outer = [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]
    hole = [[4, 4], [6, 4], [6, 6], [4, 6], [4, 4]]
    index = ZoneIndex([zone(0, "ring", {"type": "Polygon", "coordinates": [outer, hole]})])
    assert index.at(0, 5, 5) == ()
    assert [z.id for z in index.at(0, 2, 2)] == ["ring"]
